"""Fuzz targets for every parser that reads untrusted bytes: the frame decoder, the state
file loader, the config loader and the robot link's line parser.

Each `target_*` takes arbitrary bytes and fails (raises AssertionError or any unexpected
exception) only when the parser misbehaves: an exception other than its documented one,
or a result outside the ranges it promises. `tests/test_fuzz.py` runs them under
hypothesis in CI (bounded, derandomized); for long runs use atheris (docs/testing.md):

    pip install atheris
    python fuzz/fuzz_swarmd.py decoder -max_total_time=600
    python fuzz/fuzz_swarmd.py state|config|link [libFuzzer options...]
"""

from __future__ import annotations

import logging
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run as a script

from swarmd.config.errors import ConfigError, ConfigUnreadable
from swarmd.config.source import parse_source
from swarmd.config.swarm_rules import inspect_swarm
from swarmd.core import wire
from swarmd.core.limits import EPOCH_MAX
from swarmd.core.plan import RobotPlan, SwarmPlan
from swarmd.link.socket import SocketLink
from swarmd.services import state

KEY = bytes(range(32))

PLAN = SwarmPlan(
    swarm_id=1543,
    functions=("f1", "f2"),
    robots={1: RobotPlan(1, "f1", ()), 2: RobotPlan(2, "f2", ()),
            3: RobotPlan(3, None, ("f1", "f2"))},
    watches={"f1": ("f2",), "f2": ("f1",)},
)


def target_decoder(data: bytes) -> None:
    """`wire.decode` raises only CodecError; what it returns re-encodes to itself."""
    for keys in ((), (KEY,)):
        try:
            frame = wire.decode(data, keys)
        except wire.CodecError:
            continue
        assert 0 <= frame.seq <= wire.SEQ_MAX
        assert wire.decode(wire.encode(frame, keys[0] if keys else None), keys) == frame


def target_state(data: bytes) -> None:
    """The state loader returns a state inside the wire's ranges or raises StateError."""
    with tempfile.TemporaryDirectory() as tmp:
        path = state.state_path(Path(tmp), 1543, 2)
        path.write_bytes(data)
        try:
            loaded = state.StateFile(path, robot=2, swarm=1543, plan=PLAN).load()
        except state.StateError:
            return
    assert loaded is not None
    for holder, epoch in loaded.known.values():
        assert holder == 0 or holder in PLAN.robots
        assert 0 <= epoch <= EPOCH_MAX
    if loaded.held is not None:
        assert isinstance(loaded.held[0], str) and 0 <= loaded.held[1] <= EPOCH_MAX
    assert 0 <= loaded.seq_reserved <= wire.SEQ_MAX


def target_state_json(data: bytes) -> None:
    """Like `target_state`, with the bytes wrapped in a plausible state object, so the
    fuzzer spends its time on field values rather than on JSON syntax."""
    text = data.decode("utf-8", "replace")
    target_state(('{"version": 1, "robot": 2, "swarm": 1543, ' + text).encode())


def target_config(data: bytes) -> None:
    """The swarm loader returns a config or problems; it never raises anything else."""
    text = data.decode("utf-8", "replace")
    try:
        source = parse_source(text, "<fuzz>")
        cfg, problems = inspect_swarm(source)
    except (ConfigError, ConfigUnreadable):
        return
    if cfg is not None and not any(p.severity == "error" for p in problems):
        cfg.coverage()
        cfg.to_plan()


class _Link(SocketLink):
    def _arm(self) -> None:  # no event loop here: the health timer is not under test
        pass


def target_link_line(data: bytes) -> None:
    """A robot-link line is a health report or one counted bad line, never an exception."""
    link = _Link("/nonexistent/fuzz.sock")
    before = dict(link.counters)
    link._line(data)
    counted = (link.counters["bad_lines"] - before["bad_lines"]) + (
        link.counters["health"] - before["health"])
    assert counted == (1 if data.strip() else 0)


TARGETS: dict[str, Callable[[bytes], None]] = {
    "decoder": target_decoder,
    "state": target_state,
    "state-json": target_state_json,
    "config": target_config,
    "link": target_link_line,
}


def main(argv: list[str]) -> None:  # pragma: no cover - long runs only, needs atheris
    if len(argv) < 2 or argv[1] not in TARGETS:
        raise SystemExit(f"usage: {argv[0]} {{{'|'.join(TARGETS)}}} [libFuzzer options]")
    import atheris

    target = TARGETS[argv[1]]
    logging.disable(logging.CRITICAL)  # a bad line logs a warning; millions of them
    atheris.Setup([argv[0], *argv[2:]], target)
    atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv)
