"""Large swarms: more than 255 functions on the wire, and the receiver's early drop of
frames about slots it does not care about (DESIGN section 2, "What a robot hears")."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest
from typer.testing import CliRunner

from sim.shared.faults import parse_fault
from sim.shared.invariants import Bounds
from sim.virtual.simulator import VirtualResult, run_virtual
from swarmd.cli import app
from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.node import Node
from swarmd.core.params import udp
from swarmd.core.plan import SwarmPlan

ROOT = Path(__file__).resolve().parent.parent
KEY = b"s" * 32
runner = CliRunner()


def _make_grid() -> ModuleType:
    spec = importlib.util.spec_from_file_location("make_grid", ROOT / "configs" / "make_grid.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _grid_plan(rows: int, cols: int, tmp_path: Path) -> SwarmPlan:
    path = tmp_path / f"grid{rows}x{cols}.yaml"
    path.write_text(_make_grid().grid_yaml(rows, cols))
    return load_swarm(path).to_plan()


def _takeovers(res: VirtualResult) -> list[tuple[int, str, int, int]]:
    return [(e["robot"], e["function"], e["epoch"], e["replaced"])
            for e in res.events if e["event"] == "takeover"]


@pytest.mark.parametrize(("rows", "cols"), [(20, 19), (100, 9)], ids=["380-actives", "1000"])
def test_swarms_beyond_255_functions_pass_check(rows: int, cols: int, tmp_path: Path) -> None:
    path = tmp_path / "grid.yaml"
    path.write_text(_make_grid().grid_yaml(rows, cols))
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 0, result.output
    assert len(load_swarm(path).functions) == rows * cols > 255


def test_a_1000_robot_swarm_takes_a_crash_over_within_the_bound(tmp_path: Path) -> None:
    path = _make_grid().write_grid(1000, tmp_path)
    cfg = load_swarm(path)
    plan, params = cfg.to_plan(), cfg.params()
    assert len(plan.robots) == 1000
    victim = 850  # slot f850: a three-digit slot two bytes wide on the wire
    assert wire.slot_size(plan.slot(f"f{victim}")) == 2
    # A start-up grace in: the links are measured (DESIGN "Detection"), the clean bound.
    res = run_virtual(plan, params, duration=5.0, faults=[parse_fault(f"crash:{victim}@3")])
    assert res.violations == []
    ((robot, function, epoch, replaced),) = _takeovers(res)
    assert (function, epoch, replaced) == (f"f{victim}", 1, victim)
    assert robot in plan.covered_by(function) and plan.robots[robot].function is None
    took = next(e["t"] for e in res.events if e["event"] == "takeover")
    assert 3.0 < took <= 3.0 + Bounds.of(params, 0.0).takeover


def _frame(sender: int, msg: wire.Message, seq: int = 1, key: bytes | None = KEY) -> bytes:
    return wire.encode(wire.Frame(4100, sender, seq, msg), key)


def test_an_irrelevant_frame_is_dropped_before_its_tag_is_checked(tmp_path: Path) -> None:
    plan = _grid_plan(6, 6, tmp_path)  # robot r at row (r-1)//6, column (r-1)%6
    node = Node(1, plan, udp(), 0.0, keys=[KEY])
    far = plan.slot("f36")  # the opposite corner: neither watched by nor watching f1
    forged = _frame(36, wire.Heartbeat(far, 0, 1, 0))[:-1] + b"\0"
    node.receive(forged, 0.01)
    assert node.drops["irrelevant"] == 1 and node.drops["auth"] == 0
    # The same forgery about a neighbour's slot is verified, and fails verification.
    near = _frame(2, wire.Heartbeat(plan.slot("f2"), 0, 1, 0))[:-1] + b"\0"
    node.receive(near, 0.02)
    assert node.drops["auth"] == 1 and node.drops["irrelevant"] == 1


def test_what_a_robot_still_hears(tmp_path: Path) -> None:
    plan = _grid_plan(6, 6, tmp_path)
    standby_far = 36 + 6  # covers row 5, far from robot 1
    standby_own = 36 + 1  # covers row 0, f1 included
    node = Node(1, plan, udp(), 0.0, keys=[KEY])
    slot = plan.slot
    frames = [
        # A standby that took f2 over (rule 1: judged by slot, not by who sends it).
        _frame(standby_own, wire.Heartbeat(slot("f2"), 1, 1, 0), seq=1),
        # Our own slot at a higher epoch (fencing, rule 2).
        _frame(standby_own, wire.Heartbeat(slot("f1"), 3, 1, 0), seq=2),
        # A warning about ourselves from a far robot (rule 4: answer it).
        _frame(30, wire.Warn(1, slot("f1"), 3)),
        # Liveness of the standby that covers our watched slots (rules 6, 8).
        _frame(standby_own, wire.Heartbeat(0, 0, 2, 0), seq=3),
        # A LEAVE and a CLAIM about a watched slot.
        _frame(7, wire.Leave(slot("f7"), 0, 0)),
        _frame(standby_own, wire.Claim(2, slot("f2"), 2), seq=4),
    ]
    # After the start-up grace: every sender's word is heard (`words.py`).
    start = udp().startup_grace
    for i, data in enumerate(frames):
        node.receive(data, start + 0.01 * (i + 1))
    assert node.drops["irrelevant"] == 0
    assert node.snapshot().frames_in == len(frames)
    node.receive(_frame(standby_far, wire.Heartbeat(0, 0, 2, 0)), start + 0.5)
    node.receive(_frame(35, wire.Claim(36, slot("f36"), 1)), start + 0.5)
    assert node.drops["irrelevant"] == 2


def test_relevance_follows_slots_of_every_role(tmp_path: Path) -> None:
    plan = _grid_plan(4, 4, tmp_path)
    standby = 16 + 2  # covers row 1: f5..f8
    rel = plan.relevant(standby)
    names = {plan.function_at(s) for s in rel.slots}
    # Each covered slot, what its holder would watch, and its witnesses.
    assert {"f5", "f6", "f7", "f8", "f1", "f4", "f9", "f12"} <= names
    assert "f16" not in names and "f13" not in names
    assert 16 + 1 in rel.standbys and 16 + 4 not in rel.standbys


@pytest.mark.parametrize(
    ("faults", "loss"),
    [(("crash:8@2",), 0.0), (("crash:1@2", "pause:14@3+2"), 0.0), (("crash:19@2",), 0.2),
     (("leave:10@2", "liar:3@2.5"), 0.1)],
)
def test_the_early_drop_changes_no_outcome(faults: tuple[str, ...], loss: float,
                                           tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                           ) -> None:
    """Every robot gets every frame (no simulator filter); with the early drop and with
    it disabled, the runs are the same run."""
    plan, params = _grid_plan(5, 5, tmp_path), udp()

    def go() -> VirtualResult:
        return run_virtual(plan, params, duration=8.0, faults=[parse_fault(f) for f in faults],
                           loss=loss, seed=3, interest=False)

    with_drop = go()
    monkeypatch.setattr(Node, "_irrelevant", lambda *a, **k: False)
    without = go()
    assert with_drop.violations == [] and without.violations == []
    assert _takeovers(with_drop) == _takeovers(without)
    assert _takeovers(with_drop), "each case must make somebody take over"
    assert with_drop.holders() == without.holders()
    assert [(e["t"], e["robot"], e["event"]) for e in with_drop.events] == \
        [(e["t"], e["robot"], e["event"]) for e in without.events]
    assert sum(d.get("irrelevant", 0) for d in with_drop.drops.values()) > 0
    assert sum(d.get("irrelevant", 0) for d in without.drops.values()) == 0
