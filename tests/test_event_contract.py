"""The event log is an outside contract (DESIGN section 3): clients parse it by name.

Every record is `{"t", "robot", "event", ...}` with a DESIGN name and at least that
name's fields (`swarmd.core.events`, one class a name). Checked on virtual runs that make
every event happen; the daemon's own log and the flown sim are checked in test_start.py
and test_sim_report.py.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from sim.shared.faults import parse_fault
from sim.virtual.simulator import VirtualResult, run_virtual
from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.errors import EventRecordError
from swarmd.core.events import (
    EVENTS,
    Alert,
    AlertCause,
    Event,
    Fault,
    Leave,
    LeaveCause,
    Refute,
    RoleName,
    Started,
    Stopped,
    Takeover,
    Vote,
    event_of,
)
from swarmd.core.roles import Role

ROOT = Path(__file__).resolve().parent.parent


def check_records(records: Iterable[Mapping[str, Any]]) -> set[str]:
    """Assert the contract on every record; the names seen."""
    seen = set()
    for r in records:
        json.dumps(r)  # a record is plain JSON
        assert isinstance(r["t"], float | int) and isinstance(r["robot"], int), r
        assert r["event"] in EVENTS, r
        missing = set(EVENTS[r["event"]].contract()) - r.keys()
        assert not missing, (r, missing)
        seen.add(r["event"])
    return seen


SCENARIOS = [
    # crash: suspect, warn, vote, claim, takeover; restart of the crashed one: fenced
    ("paper", ["crash:2@3", "restart:2@6"]),
    # a pause shorter than T_max + the claim: refute; leave; unhealthy
    ("paper", ["pause:2@3+0.55", "leave:4@5", "unhealthy:1@7"]),
    # both standbys gone, then an active robot: alert
    ("paper", ["crash:5@2", "crash:6@2", "crash:3@5"]),
    ("paper", ["liar:1@3", "partition:1,2|3,4,5,6@5+2"]),
    # standbys 5 and 6 both cover f2: a race, 6 backs off
    ("race", ["crash:2@3"]),
]


def _run(swarm: str, specs: list[str], seed: int, tmp_path: Path) -> VirtualResult:
    doc = yaml.safe_load((ROOT / "configs" / "paper.yaml").read_text())
    if swarm == "race":
        five = next(r for r in doc["robots"] if r["id"] == 5)
        five["subs"] = [*five["subs"], 2]
    path = tmp_path / f"{swarm}.yaml"
    path.write_text(yaml.safe_dump(doc))
    cfg = load_swarm(path)
    return run_virtual(cfg.to_plan(), cfg.params(), duration=12,
                       faults=[parse_fault(s) for s in specs], seed=seed)


@pytest.mark.parametrize(("swarm", "specs"), SCENARIOS, ids=lambda s: str(s))
def test_virtual_event_logs_follow_the_contract(swarm: str, specs: list[str],
                                                tmp_path: Path) -> None:
    seen = check_records(_run(swarm, specs, 1, tmp_path).events)
    assert {"started", "fault"} <= seen


def test_every_event_name_happens_in_some_scenario(tmp_path: Path) -> None:
    # So that the contract above is checked on every name, not only the common ones.
    seen: set[str] = set()
    for swarm, specs in SCENARIOS:
        seen |= {r["event"] for r in _run(swarm, specs, 1, tmp_path).events}
    assert set(EVENTS) <= seen, set(EVENTS) - seen


def test_the_event_types_are_design_section_3() -> None:
    # DESIGN section 3 lists `name{field,...}`; each type's contract() must say the same.
    text = (ROOT / "docs" / "DESIGN.md").read_text()
    section = text[text.index("### Event log"):text.index("## 4.")]
    listed = {name: tuple(f for f in fields.split(",") if f)
              for name, fields in re.findall(r"`(\w+)\{([\w,]*)\}`", section)}
    assert listed == {name: cls.contract() for name, cls in EVENTS.items()}


def test_a_record_is_the_json_object_in_contract_order() -> None:
    vote = Vote(subject=2, function="f2", from_=4, count=1)
    assert json.dumps(vote.record(1.5, 5)) == (
        '{"t": 1.5, "robot": 5, "event": "vote", "subject": 2, "function": "f2", '
        '"from": 4, "count": 1}')
    assert Refute(subject=2, function="f2").record(0.0, 1) == {
        "t": 0.0, "robot": 1, "event": "refute", "subject": 2, "function": "f2"}
    assert Stopped().record(2.0, 3) == {"t": 2.0, "robot": 3, "event": "stopped"}
    # a simulator's fault: the optional fields only when the fault has them
    assert Fault("crash", "crash:2@3").record(3.0, 2) == {
        "t": 3.0, "robot": 2, "event": "fault", "kind": "crash", "spec": "crash:2@3"}
    assert Fault("partition", "p", 2.0, [[1], [2]]).fields() == {
        "kind": "partition", "spec": "p", "duration": 2.0, "groups": [[1], [2]]}


@pytest.mark.parametrize(("swarm", "specs"), SCENARIOS[:2], ids=lambda s: str(s))
def test_every_record_reads_back_as_its_typed_event(swarm: str, specs: list[str],
                                                    tmp_path: Path) -> None:
    # Event.from_record is the inverse of record(): readers (holders, summary, the live
    # view) match on the classes and nothing of the log is lost on the way.
    for r in _run(swarm, specs, 1, tmp_path).events:
        event = Event.from_record(r)
        assert type(event) is EVENTS[r["event"]]
        assert json.dumps(event.record(r["t"], r["robot"])) == json.dumps(r)


def test_a_record_that_is_no_event_is_refused_clearly() -> None:
    with pytest.raises(EventRecordError, match="unknown event 'crashed'; known: started"):
        Event.from_record({"t": 1.0, "robot": 2, "event": "crashed"})
    with pytest.raises(EventRecordError, match="'claim' record without epoch"):
        Event.from_record({"event": "claim", "subject": 2, "function": "f2"})
    with pytest.raises(EventRecordError, match="no Takeover"):
        Takeover.from_record({"event": "stopped"})
    assert event_of({"event": "nope"}) is None
    assert event_of({"event": "stopped", "t": 0.0}) == Stopped()


def test_roles_and_reasons_are_enums_written_as_their_names() -> None:
    # The wire carries a role and a LEAVE's reason as enums; the log spells them by name.
    assert [n.value for n in RoleName] == [r.name.lower() for r in Role]
    assert {r.name.lower() for r in wire.LeaveReason} <= {c.value for c in LeaveCause}
    records = [Started(RoleName.ACTIVE, "f1").record(0.0, 1),
               Leave("f2", LeaveCause.FAULT).record(1.0, 2),
               Alert("f3", AlertCause.NO_STANDBY).record(2.0, 6)]
    # A StrEnum: the JSON is the plain name, byte for byte.
    assert json.dumps(records) == (
        '[{"t": 0.0, "robot": 1, "event": "started", "role": "active", "function": "f1"}, '
        '{"t": 1.0, "robot": 2, "event": "leave", "function": "f2", "reason": "fault"}, '
        '{"t": 2.0, "robot": 6, "event": "alert", "function": "f3", '
        '"reason": "no standby left"}]')
    # Read back from JSON (plain strings), each is its enum member again.
    read = [Event.from_record(r) for r in json.loads(json.dumps(records))]
    assert read == [Started(RoleName.ACTIVE, "f1"), Leave("f2", LeaveCause.FAULT),
                    Alert("f3", AlertCause.NO_STANDBY)]
    assert [type(getattr(e, f)) for e, f in zip(read, ("role", "reason", "reason"),
                                                 strict=True)] == [
        RoleName, LeaveCause, AlertCause]


def test_a_role_or_reason_no_enum_names_is_no_event() -> None:
    with pytest.raises(EventRecordError, match="'leave' record: 'faulty' is not a valid"):
        Event.from_record({"event": "leave", "function": "f2", "reason": "faulty"})
    assert event_of({"event": "alert", "function": "f2", "reason": "no standby"}) is None
    assert event_of({"event": "started", "role": "leader", "function": None}) is None
    # How `Role` prints a role, and the paper's name for a standby (Fig. 5), read as it.
    for spelling, role in (("ACTIVE", RoleName.ACTIVE), ("Role.STANDBY", RoleName.STANDBY),
                           ("inactive", RoleName.STANDBY)):
        assert event_of({"event": "started", "role": spelling, "function": None}) == \
            Started(role, None)
