"""The end of a simulated run stops every robot still up: its log ends with `stopped`.

The rest of a virtual run's log is what it was, byte for byte (the records are appended
after the run, its checker and its summary)."""

from __future__ import annotations

import json
from pathlib import Path

from sim.run import SimOptions, run_sim
from sim.shared.eventlog import stops_at_end
from sim.shared.faults import parse_fault
from sim.virtual.simulator import run_virtual
from swarmd.config import load_swarm

PAPER = Path(__file__).resolve().parent.parent / "configs" / "paper.yaml"


def test_a_virtual_run_ends_with_a_stop_for_each_live_robot(tmp_path: Path) -> None:
    path = tmp_path / "events.jsonl"
    result = run_sim(SimOptions(swarm=PAPER, virtual=True, duration=8.0, seed=1,
                                faults=("crash:2@5",), events=path, live=False))
    lines = path.read_text().splitlines()
    stops = [json.loads(x) for x in lines if '"event":"stopped"' in x]
    assert [(e["t"], e["robot"]) for e in stops] == [(8.0, r) for r in (1, 3, 4, 5, 6)]
    assert lines[-len(stops):] == [json.dumps(e, separators=(",", ":")) for e in stops]
    # Everything before them is the simulator's own log, unchanged.
    cfg = load_swarm(PAPER)
    plain = run_virtual(cfg.to_plan(), cfg.params(), duration=8.0, seed=1, auth="per-robot",
                        faults=[parse_fault("crash:2@5")])
    assert lines[:-len(stops)] == [json.dumps(e, separators=(",", ":"))
                                   for e in plain.events]
    assert result.summary.ok and result.summary.holders == {"f1": [1], "f2": [6],
                                                            "f3": [3], "f4": [4]}


def test_no_stop_for_a_robot_that_went_down_or_stopped_already() -> None:
    events = [
        {"t": 0.0, "robot": 1, "event": "started", "role": "active", "function": "f1"},
        {"t": 0.0, "robot": 2, "event": "started", "role": "active", "function": "f2"},
        {"t": 0.0, "robot": 3, "event": "started", "role": "standby", "function": None},
        {"t": 0.0, "robot": 4, "event": "started", "role": "standby", "function": None},
        {"t": 1.0, "robot": 2, "event": "fault", "kind": "crash", "spec": "crash:2@1"},
        {"t": 2.0, "robot": 3, "event": "stopped"},
        {"t": 5.25, "robot": 1, "event": "suspect", "subject": 2, "function": "f2"},
    ]
    stops = stops_at_end(events, 5.0, dead={4})
    assert stops == [{"t": 5.25, "robot": 1, "event": "stopped"}]
