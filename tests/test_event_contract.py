"""The event log is an outside contract (DESIGN section 3): clients parse it by name.

Every record is `{"t", "robot", "event", ...}` with a DESIGN name and at least that
name's fields (`swarmd.core.actions.EVENT_FIELDS`). Checked on virtual runs that make
every event happen; the daemon's own log and the flown sim are checked in test_start.py
and test_sim_report.py.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from sim.shared.faults import parse_fault
from sim.virtual.simulator import VirtualResult, run_virtual
from swarmd.config import load_swarm
from swarmd.core.actions import EVENT_FIELDS

ROOT = Path(__file__).resolve().parent.parent


def check_records(records: Iterable[Mapping[str, Any]]) -> set[str]:
    """Assert the contract on every record; the names seen."""
    seen = set()
    for r in records:
        json.dumps(r)  # a record is plain JSON
        assert isinstance(r["t"], float | int) and isinstance(r["robot"], int), r
        assert r["event"] in EVENT_FIELDS, r
        missing = set(EVENT_FIELDS[r["event"]]) - r.keys()
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
    assert set(EVENT_FIELDS) <= seen, set(EVENT_FIELDS) - seen
