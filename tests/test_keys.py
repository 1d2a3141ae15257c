"""swarmd.base.keys and `swarmd keygen`: file modes, refusals, and the rotation window.

The rotation procedure tested here is the one docs/operations.md gives: (1) every
robot accepts the new key, (2) every robot signs with the new key and still accepts
the old, (3) the old key is dropped. Done one robot at a time, no frame is refused
at any point; skipping step 1 cuts the first switched robot off.
"""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest
from typer.testing import CliRunner

from swarmd.base.keys import KEY_LEN, KeyFileError, generate_key, load_key, load_keys, parse_key
from swarmd.core import wire
from swarmd.core.actions import Action, Broadcast
from swarmd.core.events import Event
from swarmd.core.node import Node
from swarmd.core.params import udp
from swarmd.core.plan import RobotPlan, SwarmPlan


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


# -- generate / load -----------------------------------------------------------------
def test_generate_key_writes_32_private_bytes(tmp_path: Path) -> None:
    path = tmp_path / "swarm.key"
    old_umask = os.umask(0)  # even the most permissive umask must not widen the file
    try:
        key = generate_key(path)
    finally:
        os.umask(old_umask)
    assert len(key) == KEY_LEN and path.read_bytes() == key
    assert _mode(path) == 0o600
    assert load_key(path) == key
    assert [p.name for p in tmp_path.iterdir()] == ["swarm.key"]  # no temp file left


def test_generate_key_refuses_to_overwrite_without_force(tmp_path: Path) -> None:
    path = tmp_path / "swarm.key"
    first = generate_key(path)
    with pytest.raises(KeyFileError, match="already exists"):
        generate_key(path)
    assert path.read_bytes() == first
    second = generate_key(path, force=True)
    assert second != first and load_key(path) == second


def test_hex_key_files_are_accepted(tmp_path: Path) -> None:
    path = tmp_path / "swarm.key"
    key = generate_key(path, hex_format=True)
    assert path.read_text() == key.hex() + "\n"
    assert load_key(path) == key
    assert parse_key(b"  " + key.hex().upper().encode() + b"\r\n") == key


@pytest.mark.parametrize(("mode", "who"), [
    (0o640, "its group"), (0o604, "other users"), (0o660, "its group"), (0o602, "other users"),
    (0o644, "its group and other users"),
])
def test_load_key_refuses_a_file_others_can_access(tmp_path: Path, mode: int, who: str) -> None:
    path = tmp_path / "swarm.key"
    generate_key(path)
    path.chmod(mode)
    with pytest.raises(KeyFileError) as info:
        load_key(path)
    message = str(info.value)
    assert f"mode {mode:04o}" in message
    assert who in message
    assert f"chmod 600 {path}" in message  # says how to fix it


@pytest.mark.parametrize("content", [b"", b"short", b"x" * 33, b"g" * 64, b"ab" * 31])
def test_load_key_refuses_wrong_content(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "swarm.key"
    path.write_bytes(content)
    path.chmod(0o600)
    with pytest.raises(KeyFileError, match="exactly 32 raw bytes or 64 hex digits"):
        load_key(path)


def test_load_key_says_what_is_missing(tmp_path: Path) -> None:
    with pytest.raises(KeyFileError, match=r"does not exist.*swarmd keygen"):
        load_key(tmp_path / "nope.key")
    with pytest.raises(KeyFileError, match="not a regular file"):
        (tmp_path / "dir").mkdir(mode=0o700)
        load_key(tmp_path / "dir")


def test_load_keys_puts_the_signing_key_first(tmp_path: Path) -> None:
    old, new = tmp_path / "old.key", tmp_path / "new.key"
    k_old, k_new = generate_key(old), generate_key(new)
    assert load_keys(new, [old]) == [k_new, k_old]
    assert load_keys(old, [new, old]) == [k_old, k_new]  # a duplicate is listed once
    assert load_keys(None, []) == []
    with pytest.raises(KeyFileError, match="no signing key"):
        load_keys(None, [old])


def test_keygen_command(tmp_path: Path) -> None:
    from swarmd.cli import app

    path = tmp_path / "swarm.key"
    runner = CliRunner()
    result = runner.invoke(app, ["keygen", str(path)])
    assert result.exit_code == 0, result.output
    assert _mode(path) == 0o600 and len(path.read_bytes()) == KEY_LEN
    again = runner.invoke(app, ["keygen", str(path)])
    assert again.exit_code == 1
    assert "already exists" in again.output


# -- rotation on the wire ------------------------------------------------------------
def test_rotation_window_on_the_wire() -> None:
    old, new = b"o" * KEY_LEN, b"n" * KEY_LEN
    frame = wire.Frame(swarm_id=7, sender=1, seq=1, msg=wire.Heartbeat(1, 0, 1, 0))
    by_old, by_new = wire.encode(frame, old), wire.encode(frame, new)
    # In the window a robot accepts both, whichever it signs with.
    for keys in ([old, new], [new, old]):
        assert wire.decode(by_old, keys) == frame
        assert wire.decode(by_new, keys) == frame
    # Outside it, the other key's frames are refused as unauthenticated.
    with pytest.raises(wire.CodecError) as info:
        wire.decode(by_old, [new])
    assert info.value.reason == "auth"


# -- rotation between live core nodes ------------------------------------------------
OLD, NEW = b"\x01" * KEY_LEN, b"\x02" * KEY_LEN
STEP = 0.02


class _Swarm:
    """Three ACTIVE robots watching each other, wired through a perfect channel, on
    virtual time. `restart(rid, keys)` models `systemctl restart` with a new config."""

    def __init__(self, keys: Sequence[bytes]) -> None:
        ids = (1, 2, 3)
        self.plan = SwarmPlan(
            swarm_id=7,
            functions=tuple(f"f{i}" for i in ids),
            robots={i: RobotPlan(i, f"f{i}") for i in ids},
            watches={f"f{i}": tuple(f"f{j}" for j in ids if j != i) for i in ids},
        )
        self.now = 0.0
        self.events: list[tuple[int, Event]] = []
        self.nodes = {i: self._node(i, keys, seq_start=0) for i in ids}

    def _node(self, rid: int, keys: Sequence[bytes], seq_start: int) -> Node:
        return Node(rid, self.plan, udp(), self.now, keys=keys, seq_start=seq_start)

    def restart(self, rid: int, keys: Sequence[bytes]) -> None:
        # A restarted daemon seeds seq from the clock, above what it sent before.
        self.nodes[rid] = self._node(rid, keys, seq_start=self.nodes[rid].snapshot().seq + 1_000)

    def _handle(self, rid: int, actions: list[Action]) -> None:
        queue = [(rid, a) for a in actions]
        while queue:
            src, action = queue.pop(0)
            if isinstance(action, Event):
                self.events.append((src, action))
            elif isinstance(action, Broadcast):
                for dst, node in self.nodes.items():
                    if dst != src:
                        queue.extend((dst, a) for a in node.receive(action.frame, self.now))

    def run(self, seconds: float) -> None:
        end = self.now + seconds
        while self.now < end:
            self.now += STEP
            for rid, node in self.nodes.items():
                deadline = node.next_deadline()
                if deadline is not None and deadline <= self.now:
                    self._handle(rid, node.tick(self.now))

    def auth_drops(self) -> int:
        return sum(n.snapshot().drops.get("auth", 0) for n in self.nodes.values())

    def suspicions(self) -> list[tuple[int, Event]]:
        return [(r, e) for r, e in self.events if e.name in ("suspect", "takeover", "fenced")]


def test_three_step_rotation_never_refuses_a_frame() -> None:
    swarm = _Swarm([OLD])
    swarm.run(2.5)  # a start-up grace and more: the links are measured (DESIGN "Detection")
    stages = ([OLD, NEW], [NEW, OLD], [NEW])  # docs/operations.md, steps 1-3
    for keys in stages:
        for rid in (1, 2, 3):  # a rolling restart, robot by robot
            swarm.restart(rid, keys)
            swarm.run(1.0)  # > t_max: a cut-off robot would be suspected by now
    assert swarm.auth_drops() == 0
    assert swarm.suspicions() == []
    assert all(n.keys == (NEW,) for n in swarm.nodes.values())
    assert all(n.snapshot().role.name == "ACTIVE" for n in swarm.nodes.values())


def test_switching_without_the_window_cuts_the_robot_off() -> None:
    swarm = _Swarm([OLD])
    swarm.run(2.5)  # the links measured: a silence is suspected after t_max
    swarm.restart(1, [NEW])  # step 1 skipped
    swarm.run(1.0)
    assert swarm.auth_drops() > 0
    suspected = {e.fields().get("subject") for r, e in swarm.suspicions() if e.name == "suspect"}
    assert 1 in suspected


# -- the daemon refuses a key others can read ------------------------------------------
def test_swarmd_start_refuses_a_key_readable_by_others(tmp_path: Path) -> None:
    pytest.importorskip("swarmd.daemon.daemon", reason="daemon runtime not in this tree")
    repo = Path(__file__).resolve().parent.parent
    swarm = (repo / "configs" / "paper.yaml").read_text()
    swarm, n = re.subn(r"(?m)^auth:.*$", "key_file: swarm.key", swarm)
    assert n == 1
    (tmp_path / "swarm.yaml").write_text(swarm)
    key = tmp_path / "swarm.key"
    generate_key(key)
    key.chmod(0o644)
    robot = tmp_path / "robot.yaml"
    robot.write_text("robot: 2\nswarm: swarm.yaml\nstate_dir: state\n"
                     "transport: {kind: udp, port: 9, interface: 127.0.0.1, ttl: 1}\n")
    result = subprocess.run(
        [sys.executable, "-m", "swarmd.cli", "start", "--config", str(robot)],
        capture_output=True, text=True, timeout=30, cwd=tmp_path,
    )
    assert result.returncode != 0
    said = result.stdout + result.stderr
    assert "mode 0644" in said and "chmod 600" in said, said
    assert not (tmp_path / "state").exists() or not any((tmp_path / "state").iterdir())
