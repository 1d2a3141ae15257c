"""The one fold of the event log into who executes what (sim/shared/holders.py) and its readers:
the timeline spans, the live table, the summary and the invariant checker."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from sim.physics.plots import role_spans
from sim.realtime.view import SwarmView
from sim.shared.faults import parse_fault
from sim.shared.holders import HolderFold, Holding, role_name
from sim.shared.invariants import check_events
from sim.shared.summary import holders_at_end, summarize
from sim.virtual.simulator import run_virtual
from swarmd.config import load_swarm

PAPER = Path(__file__).resolve().parent.parent / "configs" / "paper.yaml"


def ev(t: float, robot: int, event: str, **fields: Any) -> dict[str, Any]:
    return {"t": t, "robot": robot, "event": event, **fields}


START = [
    ev(0.0, 1, "started", role="active", function="f1"),
    ev(0.0, 2, "started", role="active", function="f2"),
    ev(0.0, 6, "started", role="standby", function=None),
]


def log(*after: dict[str, Any]) -> list[dict[str, Any]]:
    return [*START, *after]


# (events after START, robot, the Holding it ends with)
TABLE: list[tuple[list[dict[str, Any]], int, Holding]] = [
    ([], 2, Holding("active", "f2")),
    ([], 6, Holding("standby")),
    ([ev(1, 6, "claim", subject=2, function="f2", epoch=1)], 6, Holding("claiming", "f2", 1)),
    ([ev(1, 6, "claim", subject=2, function="f2", epoch=1),
      ev(2, 6, "backoff", subject=2, function="f2", winner=5)], 6, Holding("standby")),
    ([ev(1, 6, "claim", subject=2, function="f2", epoch=1),
      ev(2, 6, "takeover", function="f2", epoch=1, replaced=2)], 6, Holding("active", "f2", 1)),
    # REFUTED: the claimant heard the suspect alive
    ([ev(1, 6, "claim", subject=2, function="f2", epoch=1),
      ev(2, 6, "refute", subject=2, function="f2")], 6, Holding("standby")),
    # a watcher's refute changes nothing
    ([ev(2, 1, "refute", subject=2, function="f2")], 1, Holding("active", "f1")),
    # FAULT from CLAIMING drops the claim without an event
    ([ev(1, 6, "claim", subject=2, function="f2", epoch=1),
      ev(2, 6, "fault", kind="unhealthy")], 6, Holding("standby")),
    ([ev(3, 2, "fenced", function="f2", epoch=2)], 2, Holding("fenced", "f2")),
    ([ev(3, 2, "leave", function="f2", reason="fault")], 2, Holding("standby")),
    ([ev(3, 2, "stopped")], 2, Holding("stopped")),
    # crashed: a stray event does not bring it back; started does
    ([ev(3, 2, "fault", kind="crash"),
      ev(4, 2, "takeover", function="f3", epoch=1, replaced=3)], 2, Holding("crashed")),
    ([ev(3, 2, "fault", kind="crash"),
      ev(6, 2, "started", role="inactive", function=None)], 2, Holding("standby")),
    # a motor failure is not a crash by default (the process lives and leaves itself)
    ([ev(3, 2, "fault", kind="motor")], 2, Holding("active", "f2")),
]


@pytest.mark.parametrize(("after", "robot", "want"), TABLE)
def test_fold_table(after: list[dict[str, Any]], robot: int, want: Holding) -> None:
    fold = HolderFold().feed_all(START + after)
    assert fold.robots[robot] == want


def test_role_names_of_every_spelling() -> None:
    assert [role_name(v) for v in ("active", "ACTIVE", "Role.STANDBY", "inactive")] == [
        "active", "active", "standby", "standby"]


def test_two_robots_on_one_slot_are_both_holders() -> None:
    # The checker's dual-execution rule needs both; the fold must not pick one.
    fold = HolderFold().feed_all(log(ev(3, 6, "takeover", function="f2", epoch=1,
                                             replaced=2)))
    assert fold.holders() == {"f1": [1], "f2": [2, 6]}
    assert fold.holders(exclude={2}) == {"f1": [1], "f2": [6]}


def test_down_faults_are_the_callers_choice() -> None:
    events = [*START, ev(3, 2, "fault", kind="motor"), ev(3.1, 2, "leave", function="f2")]
    assert HolderFold(down={"crash", "motor"}).feed_all(events).robots[2] == Holding("crashed")
    # The checker's setting: nothing from the log takes a robot down.
    judge = HolderFold(down=()).feed_all(log(ev(3, 2, "fault", kind="crash")))
    assert judge.executing() == {1: "f1", 2: "f2"}


def test_a_refuted_claim_ends_in_the_timeline_and_the_live_table() -> None:
    # Before the shared fold both kept robot 6 "claiming" to the end of the run.
    events = log(ev(1.0, 6, "claim", subject=2, function="f2", epoch=1),
                      ev(1.1, 6, "refute", subject=2, function="f2"))
    assert [(s.role, s.start, s.end) for s in role_spans(events, end=5.0)[6]] == [
        ("standby", 0.0, 1.0), ("claiming", 1.0, 1.1), ("standby", 1.1, 5.0)]
    view = SwarmView([1, 2, 6])
    for rec in events:
        view.feed(rec)
    assert (view.robots[6].role, view.robots[6].function) == ("STANDBY", None)


def test_a_refuted_claim_in_a_virtual_run() -> None:
    # pause:2@3+0.55: robot 6 claims f2 at ~3.45 and hears robot 2 again at ~3.55.
    swarm = load_swarm(PAPER)
    events = run_virtual(swarm.to_plan(), swarm.params(), duration=5.0, seed=1,
                         faults=[parse_fault("pause:2@3+0.55")]).events
    assert any(e["event"] == "claim" and e["robot"] == 6 for e in events)
    assert not any(e["event"] == "takeover" for e in events)
    assert [s.role for s in role_spans(events, end=5.0)[6]] == [
        "standby", "claiming", "standby"]


def test_live_table_roles_functions_and_process() -> None:
    view = SwarmView([1, 2, 6])
    for rec in log(ev(3, 2, "fault", kind="crash"),
                        ev(3.7, 6, "takeover", function="f2", epoch=1, replaced=2)):
        view.feed(rec)
    two, six = view.robots[2], view.robots[6]
    assert (two.role, two.function, two.process) == ("-", None, "killed")
    assert (six.role, six.function, six.epoch, six.last_event) == ("ACTIVE", "f2", 1, "takeover")


def test_summary_holder_when_the_fault_hit_and_at_the_end() -> None:
    swarm = load_swarm(PAPER)
    events = log(ev(3.0, 2, "fault", kind="crash"),
                      ev(3.7, 6, "takeover", function="f2", epoch=1, replaced=2))
    s = summarize(events, [parse_fault("crash:2@3")], swarm.to_plan(), swarm.params(),
                  loss=0.0, duration=5.0, mode="test")
    # The crash record carries the fault's own t: the slot is the one held before it.
    assert (s.faults[0].function, s.faults[0].by) == ("f2", 6)
    assert s.holders == {"f1": [1], "f2": [6]} == holders_at_end(events, dead={2})


def test_summary_says_who_took_over_a_restarted_robots_slot() -> None:
    swarm = load_swarm(PAPER)
    events = log(ev(3.0, 2, "fault", kind="restart"),
                 ev(3.4, 1, "suspect", subject=2, function="f2"),
                 ev(3.6, 6, "takeover", function="f2", epoch=1, replaced=2),
                 ev(3.9, 2, "started", role="standby", function=None))
    s = summarize(events, [parse_fault("restart:2@3")], swarm.to_plan(), swarm.params(),
                  loss=0.0, duration=5.0, mode="test")
    row = s.faults[0]
    assert (row.function, row.by, row.epoch) == ("f2", 6, 1)
    assert row.detected is not None and abs(row.detected - 0.4) < 1e-9
    assert row.taken_over is not None and abs(row.taken_over - 0.6) < 1e-9


def test_checker_a_restarted_robot_that_starts_as_standby_executes_nothing() -> None:
    # Real time: restart of a live robot kills its process first; the new node starts
    # as standby once it hears the slot taken over. Before the shared fold the checker
    # kept robot 2 on f2 and reported a dual execution with robot 6.
    swarm = load_swarm(PAPER)
    events = log(ev(3.8, 6, "takeover", function="f2", epoch=1, replaced=2),
                      ev(3.9, 2, "started", role="standby", function=None))
    checker = check_events(events, [parse_fault("restart:2@3")], swarm.to_plan(),
                           swarm.params(), loss=0.0, duration=10.0)
    assert checker.executing == {1: "f1", 6: "f2"}
    assert [v.kind for v in checker.violations] == []


def test_checker_counts_what_a_crashed_robot_still_logs() -> None:
    # The judge does not trust the log about deaths: a takeover logged by a robot it
    # knows crashed still counts as executing (a later restart ends it).
    swarm = load_swarm(PAPER)
    checker = check_events(
        log(ev(3.0, 2, "fault", kind="crash"),
                 ev(4.0, 2, "takeover", function="f3", epoch=1, replaced=3)),
        [parse_fault("crash:2@3")], swarm.to_plan(), swarm.params(), loss=0.0, duration=5.0)
    assert checker.holding.robots[2] == Holding("active", "f3", 1)


def _virtual_summary(*specs: str, duration: float = 6.0) -> Any:
    swarm = load_swarm(PAPER)
    plan, params = swarm.to_plan(), swarm.params()
    faults = [parse_fault(s) for s in specs]
    res = run_virtual(plan, params, duration=duration, faults=faults, seed=1)
    return summarize(res.events, faults, plan, params, loss=0.0, duration=duration,
                     mode="virtual")


@pytest.mark.parametrize("kind", ["leave", "unhealthy", "motor"])
def test_summary_names_the_slot_of_a_robot_that_hands_over_at_the_faults_instant(
        kind: str) -> None:
    # --virtual logs the robot's own `leave` at the fault's t: the slot is the one it
    # held before (the row said function null, slot '-').
    row = _virtual_summary(f"{kind}:2@3").faults[0]
    assert (row.function, row.by) == ("f2", 6)


def test_summary_does_not_credit_a_fault_on_a_dead_robot_with_the_earlier_takeover() -> None:
    crash, late = _virtual_summary("crash:2@3", "unhealthy:2@3.5").faults
    assert (crash.function, crash.by) == ("f2", 6)
    assert (late.function, late.detected, late.taken_over, late.by) == (None, None, None, None)
