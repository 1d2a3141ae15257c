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
from swarmd.core.errors import EventRecordError
from swarmd.core.events import EVENTS, Event, Fault, Refute, Stopped, Takeover, Vote, event_of

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
