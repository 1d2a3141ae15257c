"""The persisted state file: atomic writes, validation, corrupt files, seq reservation."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from swarmd.core.node import Restored, Snapshot
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Health, Role
from swarmd.core.wire import SEQ_MAX
from swarmd.services import state


def snap(role: Role, function: str | None, epoch: int, seq: int) -> Snapshot:
    return Snapshot(robot_id=2, role=role, function=function, epoch=epoch, health=Health.OK,
                    known={"f1": (1, 0), "f2": (2, epoch)}, suspects={}, votes={}, drops={},
                    seq=seq)


def test_state_round_trip_and_restored(tmp_path: Path) -> None:
    path = state.state_path(tmp_path, 1543, 2)
    st = state.PersistedState(robot=2, swarm=1543, known={"f2": (6, 3)}, held=("f2", 2),
                              seq_reserved=99)
    state.save(path, st)
    back = state.load(path, robot=2, swarm=1543)
    assert back == st
    assert back.restored() == Restored(known={"f2": (6, 3)}, held=("f2", 2))
    # Atomic write leaves no temporary file behind.
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


def test_state_missing_file_is_a_first_start(tmp_path: Path) -> None:
    assert state.load(tmp_path / "none.json", robot=1, swarm=1) is None


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{not json", "not valid JSON"),
        ("[]", "not a JSON object"),
        ('{"version": 9}', "version 9"),
        ('{"version": 1, "robot": 3, "swarm": 1543}', "robot 3 of swarm 1543"),
        ('{"version": 1, "robot": 2, "swarm": 1543, "known": {"f1": [1]}}',
         "not \\[holder, epoch\\]"),
        ('{"version": 1, "robot": 2, "swarm": 1543, "held": ["f1", -1]}', "held epoch"),
        ('{"version": 1, "robot": 2, "swarm": 1543, "seq_reserved": "x"}', "seq_reserved"),
    ],
)
def test_state_corrupt_file_gives_a_clear_error(tmp_path: Path, content: str,
                                                 message: str) -> None:
    path = tmp_path / "s.json"
    path.write_text(content)
    with pytest.raises(state.StateError, match=message) as info:
        state.load(path, robot=2, swarm=1543)
    assert str(path) in str(info.value)


def test_state_set_aside_moves_the_corrupt_file(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    path.write_text("garbage")
    moved = state.set_aside(path)
    assert moved is not None and moved.read_text() == "garbage" and not path.exists()


def test_state_replace_is_atomic_under_a_failing_write(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "s.json"
    good = state.PersistedState(robot=2, swarm=1, known={"f1": (1, 0)})
    state.save(path, good)

    def broken_fsync(fd: int) -> None:
        raise OSError("disk on fire")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError, match="disk on fire"):
        state.save(path, state.PersistedState(robot=2, swarm=1, known={"f1": (9, 9)}))
    monkeypatch.undo()
    assert state.load(path, robot=2, swarm=1) == good  # old content intact
    assert [p.name for p in tmp_path.iterdir()] == ["s.json"]  # temp file removed


def test_state_file_held_only_while_active_and_seq_reservation(tmp_path: Path) -> None:
    sf = state.StateFile(tmp_path / "s.json", robot=2, swarm=1543)
    write_at = sf.write_initial(None, seq_start=1_000)
    assert sf.load() == state.PersistedState(robot=2, swarm=1543,
                                             seq_reserved=1_000 + state.SEQ_RESERVE)
    assert write_at == 1_000 + state.SEQ_RESERVE // 2
    sf.write_snapshot(snap(Role.ACTIVE, "f2", 1, 1_010))
    loaded = sf.load()
    assert loaded is not None and loaded.held == ("f2", 1)
    assert loaded.seq_reserved == 1_000 + state.SEQ_RESERVE  # far from it: unchanged
    sf.write_snapshot(snap(Role.FENCED, None, 0, 1_000 + state.SEQ_RESERVE // 2))
    loaded = sf.load()
    assert loaded is not None and loaded.held is None
    assert loaded.seq_reserved == 1_000 + state.SEQ_RESERVE // 2 + state.SEQ_RESERVE
    assert json.loads((tmp_path / "s.json").read_text())["known"]["f2"] == [2, 0]


def test_state_initial_seq_survives_a_clock_that_went_backwards() -> None:
    persisted = state.PersistedState(robot=1, swarm=1, seq_reserved=5_000)
    assert state.initial_seq(4_000, persisted) == 5_000  # clock behind: reservation wins
    assert state.initial_seq(6_000, persisted) == 6_000
    assert state.initial_seq(10, None) == 10


# -- validation against the plan and the wire's ranges ---------------------------------

GOOD = {"version": 1, "robot": 2, "swarm": 1543, "known": {"f2": [2, 3]}, "held": None,
        "seq_reserved": 10}


@pytest.mark.parametrize(("content", "message"), [
    (json.dumps({**GOOD, "held": ["f2", 70000]}), "held epoch 70000 is not in 0..65535"),
    (json.dumps({**GOOD, "known": {"f2": [2, 70000]}}), "epoch 70000 is not in 0..65535"),
    (json.dumps({**GOOD, "known": {"f2": [99, 1]}}), "holder 99 is not a robot"),
    (json.dumps({**GOOD, "known": {"f2": [70000, 1]}}), "holder 70000 is not in 0..65535"),
    (json.dumps({**GOOD, "seq_reserved": 1 << 48}), "no room below the 48-bit maximum"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
    (json.dumps(GOOD).replace('"seq_reserved": 10', '"seq_reserved": ' + "7" * 5000),
     "not usable JSON"),
    (b"\xff\xfe".decode("latin-1"), "not UTF-8|not valid JSON"),
])
def test_state_out_of_range_or_hostile_is_refused(tmp_path: Path, paper_plan: SwarmPlan,
                                                  content: str, message: str) -> None:
    path = state.state_path(tmp_path, 1543, 2)
    path.write_text(content, encoding="latin-1" if content.startswith("\xff") else "utf-8")
    sf = state.StateFile(path, robot=2, swarm=1543, plan=paper_plan)
    with pytest.raises(state.StateError, match=message):
        sf.load()


def test_state_in_range_loads_with_the_plan(tmp_path: Path, paper_plan: SwarmPlan) -> None:
    path = state.state_path(tmp_path, 1543, 2)
    # f9: the swarm file dropped it since; the node ignores such entries (rule 2 kept)
    path.write_text(json.dumps({**GOOD, "known": {"f2": [6, 0xFFFF], "f1": [0, 0],
                                                  "f9": [2, 4]}, "held": ["f9", 4]}))
    loaded = state.StateFile(path, robot=2, swarm=1543, plan=paper_plan).load()
    assert loaded is not None and loaded.held == ("f9", 4)
    assert loaded.known["f2"] == (6, 0xFFFF)


def test_state_file_that_is_not_a_regular_file_is_refused_at_once(tmp_path: Path) -> None:
    path = state.state_path(tmp_path, 1543, 2)
    os.mkfifo(path)  # opened non-blocking: no writer needed, no hang
    with pytest.raises(state.StateError, match="is a FIFO, not a regular file"):
        state.load(path, robot=2, swarm=1543)


def test_state_any_exception_while_reading_is_a_state_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = state.state_path(tmp_path, 1543, 2)
    path.write_text(json.dumps(GOOD))

    def boom(*_: object, **__: object) -> object:
        raise MemoryError("out of memory")

    monkeypatch.setattr(json, "loads", boom)
    with pytest.raises(state.StateError, match="MemoryError"):
        state.StateFile(path, robot=2, swarm=1543).load()


def test_state_stale_tmp_files_of_this_robot_are_removed(tmp_path: Path) -> None:
    path = state.state_path(tmp_path, 1543, 2)
    mine = [tmp_path / f".{path.name}.abc{i}.tmp" for i in range(5)]
    theirs = tmp_path / ".swarm1543-robot3.json.abc0.tmp"
    for p in [*mine, theirs]:
        p.write_text("{")
    assert state.StateFile(path, robot=2, swarm=1543).load() is None
    assert not any(p.exists() for p in mine)
    assert theirs.exists()


def test_state_seq_reservation_never_passes_the_wire_maximum(tmp_path: Path) -> None:
    sf = state.StateFile(state.state_path(tmp_path, 1543, 2), robot=2, swarm=1543)
    sf.write_initial(None, 0)
    sf.write_snapshot(snap(Role.STANDBY, None, 0, SEQ_MAX - 10))
    assert sf.seq_reserved == SEQ_MAX


def test_peer_sequences_and_certificate_survive_a_restart(tmp_path: Path) -> None:
    # What a robot knows of its peers' sequences, and the signed frames that certify
    # what it held, come back after a restart (a replayed old frame stays old).
    from swarmd.services.state import PersistedState, load, save

    path = tmp_path / "s.json"
    state = PersistedState(robot=2, swarm=9, known={"f2": (2, 3)}, held=("f2", 3),
                           seq_reserved=1000, peer_seq={1: 4711, 3: 99},
                           certificate=(b"\x01\x02", b"\xff"))
    save(path, state)
    back = load(path, robot=2, swarm=9)
    assert back is not None
    assert dict(back.peer_seq) == {1: 4711, 3: 99}
    assert back.certificate == (b"\x01\x02", b"\xff")
    restored = back.restored()
    assert dict(restored.peer_seq) == {1: 4711, 3: 99}
    assert restored.certificate == (b"\x01\x02", b"\xff")


def test_out_of_range_peer_sequences_make_the_file_unusable(tmp_path: Path) -> None:
    import json

    from swarmd.services.state import StateError, load

    path = tmp_path / "s.json"
    path.write_text(json.dumps({"robot": 2, "swarm": 9, "known": {}, "held": None,
                                "seq_reserved": 0, "peer_seq": {"1": 2 ** 49}}))
    with pytest.raises(StateError):
        load(path, robot=2, swarm=9)
