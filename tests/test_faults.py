"""`sim.shared.faults`: the --fault SPEC grammar of DESIGN section 3 (CLI) and its checks."""

from __future__ import annotations

import itertools
import re

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.shared.faults import (
    ATTACKS,
    KINDS,
    Fault,
    FaultKind,
    FaultSpecError,
    check_faults,
    fault_record,
    fault_records,
    parse_fault,
)
from sim.virtual.simulator import run_virtual
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

PAPER_IDS = {1, 2, 3, 4, 5, 6}


@pytest.mark.parametrize(("spec", "fault"), [
    ("crash:2@3", Fault(FaultKind.CRASH, 3.0, (2,))),
    ("restart:2@7.5", Fault(FaultKind.RESTART, 7.5, (2,))),
    ("restart:2@7.5:wiped", Fault(FaultKind.RESTART, 7.5, (2,), wiped=True)),
    ("restart:2,3@1: wiped", Fault(FaultKind.RESTART, 1.0, (2, 3), wiped=True)),
    ("pause:3@2+1.5", Fault(FaultKind.PAUSE, 2.0, (3,), 1.5)),
    ("partition:1,2|3,4@2+3",
     Fault(FaultKind.PARTITION, 2.0, (1, 2, 3, 4), 3.0, ((1, 2), (3, 4)))),
    ("partition:1|2|3,4@0+1",
     Fault(FaultKind.PARTITION, 0.0, (1, 2, 3, 4), 1.0, ((1,), (2,), (3, 4)))),
    ("liar:4@0", Fault(FaultKind.LIAR, 0.0, (4,))),
    ("leave:1@5", Fault(FaultKind.LEAVE, 5.0, (1,))),
    ("unhealthy:6@4", Fault(FaultKind.UNHEALTHY, 4.0, (6,))),
    ("motor:2@5", Fault(FaultKind.MOTOR, 5.0, (2,))),
    ("collide:1,2@5", Fault(FaultKind.COLLIDE, 5.0, (1, 2))),
    ("collide:3,1,2@5", Fault(FaultKind.COLLIDE, 5.0, (3, 1, 2))),
    ("crash:1,2@3", Fault(FaultKind.CRASH, 3.0, (1, 2))),
    ("pause:1,4@2+1", Fault(FaultKind.PAUSE, 2.0, (1, 4), 1.0)),
    ("leave:2,3@1", Fault(FaultKind.LEAVE, 1.0, (2, 3))),
    ("unhealthy:5,6@1", Fault(FaultKind.UNHEALTHY, 1.0, (5, 6))),
    ("crash:35@.5", Fault(FaultKind.CRASH, 0.5, (35,))),
    ("crash:2@3.", Fault(FaultKind.CRASH, 3.0, (2,))),
    ("crash:65535@1", Fault(FaultKind.CRASH, 1.0, (65535,))),
])
def test_parse_fault_every_kind(spec: str, fault: Fault) -> None:
    assert parse_fault(spec) == fault


def test_parse_fault_covers_every_kind_of_the_cli() -> None:
    assert set(KINDS) == {"crash", "restart", "pause", "partition", "fade", "deaf", "liar",
                          "leave", "unhealthy", "motor", "collide", "forge"}


@pytest.mark.parametrize("spec", [
    " crash : 2 @ 3 ", "crash:2@3\n", "\tcrash:2 @3", "partition: 1, 2 | 3 ,4 @ 2 + 3",
    "collide: 1 , 2 @ 5",
])
def test_parse_fault_ignores_blanks_around_parts(spec: str) -> None:
    assert parse_fault(spec) == parse_fault(spec.replace(" ", "").strip())


@pytest.mark.parametrize(("spec", "what"), [
    ("", "unknown kind ''"),
    ("bogus:2@3", "unknown kind 'bogus'"),
    ("CRASH:2@3", "did you mean 'crash'"),
    ("crsh:2@3", "did you mean 'crash'"),
    ("crash", "no ':'"),
    ("crash:2", "no '@T'"),
    ("crash:@3", "robot id is missing"),
    ("crash:2@", "time T is missing"),
    ("crash:2@-3", "must not be negative"),
    ("crash:2@abc", "must be a number of seconds"),
    ("crash:2@1e3", "must be a number of seconds"),
    ("crash:2@nan", "must be a number of seconds"),
    ("crash:2@3@4", "must be a number of seconds"),
    ("crash:2@1" + "0" * 400, "too large"),
    # blanks inside a number are an error, never robot 23 or 12
    ("crash:2 3@3", "'2 3' is not a robot id"),
    ("partition:1 2|3@2+1", "'1 2' is not a robot id"),
    ("crash:x@3", "'x' is not a robot id"),
    ("crash:-1@3", "'-1' is not a robot id"),
    ("crash:0@3", "robot id 0 is out of range"),
    ("crash:65536@3", "out of range"),
    ("crash:2|3@3", "has no groups"),
    ("crash:2,2@3", "robot 2 is named twice"),
    ("crash:2,@3", "robot id is missing"),
    ("collide:2@3", "needs two or more robots"),
    ("collide:2,3@3+1", "takes no duration"),
    ("collide:2,3", "no '@T'"),
    ("crash:2@3+1", "takes no duration"),
    ("pause:2@3", "missing '+D'"),
    ("pause:2@3+0", "must be positive"),
    ("pause:2@3+", "duration D is missing"),
    ("partition:1,2|3,4@2", "missing '+D'"),
    ("partition:1,2@2+3", "two or more groups"),
    ("partition:1,,2|3@2+3", "robot id is missing"),
    ("partition:1,2|@1+1", "robot id is missing"),
    ("partition:1|1@2+3", "robot 1 is named twice"),
    ("restart:2@3:wipe", "a restart takes only ':wiped' after its time"),
    ("crash:2@3:wiped", "a crash takes no ':' after its time"),
    ("restart:2@3+1:wiped", "takes no duration"),
])
def test_parse_fault_names_what_is_wrong(spec: str, what: str) -> None:
    with pytest.raises(FaultSpecError) as info:
        parse_fault(spec)
    message = str(info.value)
    assert what in message
    # The user sees which of several --fault it was (a long one shortened: one line).
    assert repr(spec) in message if len(spec) < 50 else repr(spec)[:40] in message
    assert len(message) < 300


def test_parse_fault_error_shows_the_expected_form() -> None:
    with pytest.raises(FaultSpecError, match=r"expected pause:R@T\+D"):
        parse_fault("pause:2@3")
    with pytest.raises(FaultSpecError, match="kinds: crash, restart"):
        parse_fault("boom:2@3")


def test_check_faults_rejects_unknown_robots() -> None:
    faults = [parse_fault("crash:7@1"), parse_fault("partition:1,2|3,9@1+1"),
              parse_fault("crash:2@1")]
    problems = check_faults(faults, PAPER_IDS, physics=False)
    assert problems == [
        "crash:7@1: robot 7 is not in the swarm (robots: 1-6)",
        "partition:1,2|3,9@1+1: robot 9 is not in the swarm (robots: 1-6)",
    ]


def test_check_faults_lists_non_contiguous_ids() -> None:
    problems = check_faults([parse_fault("crash:1@1")], {10, 20, 21, 22, 35}, physics=True)
    assert problems == ["crash:1@1: robot 1 is not in the swarm (robots: 10, 20-22, 35)"]


def test_check_faults_motor_needs_physics() -> None:
    motor = [parse_fault("motor:2@5")]
    assert check_faults(motor, PAPER_IDS, physics=True) == []
    assert check_faults(motor, PAPER_IDS, physics=False) == [
        "motor:2@5: motor faults need physics (not with --virtual or --no-physics); "
        "unhealthy:2@5 is what a failed motor does to the protocol"]


def test_check_faults_after_the_end_of_the_run() -> None:
    faults = [parse_fault("crash:2@3"), parse_fault("crash:1@10"), parse_fault("crash:3@12")]
    problems = check_faults(faults, PAPER_IDS, physics=False, duration=10)
    assert problems == [
        "crash:1@10: starts at 10 s, not before the end of the run (--duration 10)",
        "crash:3@12: starts at 12 s, not before the end of the run (--duration 10)",
    ]
    assert check_faults(faults, PAPER_IDS, physics=False) == []  # no duration, no check


def test_fault_robot_of_a_partition_is_an_error() -> None:
    with pytest.raises(ValueError, match="groups"):
        _ = parse_fault("partition:1|2@1+1").robot
    assert parse_fault("pause:2@1+2").end == 3.0
    assert parse_fault("crash:2@1").end is None


_times = st.floats(min_value=0.0, max_value=1e7, allow_nan=False, allow_infinity=False)
_ids = st.integers(min_value=1, max_value=0xFFFF)


@st.composite
def _faults(draw: st.DrawFn) -> Fault:
    kind = draw(st.sampled_from(KINDS))
    at = draw(_times)
    if kind == "partition":
        named = draw(st.lists(_ids, min_size=2, max_size=8, unique=True))
        cut = sorted(draw(st.sets(st.integers(1, len(named) - 1), min_size=1)))
        bounds = [0, *cut, len(named)]
        groups = tuple(tuple(named[a:b]) for a, b in itertools.pairwise(bounds))
        length = draw(_times.filter(lambda d: d > 0))
        oneway = len(groups) == 2 and draw(st.booleans())
        return Fault(FaultKind(kind), at, tuple(named), length, groups, oneway=oneway)
    if kind == "deaf":
        ids = draw(st.lists(_ids, min_size=2, max_size=4, unique=True))
        return Fault(FaultKind(kind), at, (ids[0],), draw(_times.filter(lambda d: d > 0)),
                     (tuple(ids[1:]),))
    dur = draw(_times.filter(lambda d: d > 0)) if kind in ("pause", "fade") else None
    n = draw(st.integers(2 if kind == "collide" else 1, 4))
    attack = draw(st.sampled_from(ATTACKS)) if kind == "forge" else ""
    robots = tuple(draw(st.lists(_ids, min_size=n, max_size=n, unique=True)))
    wiped = kind == "restart" and draw(st.booleans())
    return Fault(FaultKind(kind), at, robots, dur, attack=attack, wiped=wiped)


@given(_faults())
def test_spec_round_trips(fault: Fault) -> None:
    """`spec()` is what the summary and the event log show; it must parse back exactly
    (tiny and large times included: no exponent, no rounding)."""
    assert parse_fault(fault.spec()) == fault


def test_spec_keeps_small_and_precise_times() -> None:
    assert Fault(FaultKind.CRASH, 1e-05, (2,)).spec() == "crash:2@0.00001"
    assert Fault(FaultKind.CRASH, 1234567.5, (2,)).spec() == "crash:2@1234567.5"
    assert Fault(FaultKind.CRASH, 0.123456789, (2,)).spec() == "crash:2@0.123456789"


def test_fault_record_form() -> None:
    assert fault_record(parse_fault("pause:2@3+1.5"), 3.0000004) == {
        "t": 3.0, "robot": 2, "event": "fault", "kind": "pause", "spec": "pause:2@3+1.5",
        "duration": 1.5}
    assert fault_record(parse_fault("partition:1,2|3@2+1"), 2.0) == {
        "t": 2.0, "robot": 0, "event": "fault", "kind": "partition",
        "spec": "partition:1,2|3@2+1", "duration": 1.0, "groups": [[1, 2], [3]]}


def test_virtual_logs_one_fault_record_per_injected_fault(
        paper: tuple[SwarmPlan, Params]) -> None:
    """The virtual log reads as the real-time one (docs/sim.md): one `fault` per injected
    fault, kinds from the CLI only (it logged `resume`/`heal` records and one partition
    record per named robot)."""
    plan, params = paper
    specs = ["pause:2@2+1", "partition:1,2|3,4@2.5+1", "crash:3@4"]
    faults = [parse_fault(s) for s in specs]
    result = run_virtual(plan, params, duration=6, faults=faults)
    records = [e for e in result.events if e["event"] == "fault"]
    assert records == [fault_record(f, f.at) for f in faults]


def test_split_gives_one_fault_a_robot_with_the_users_spec() -> None:
    collide = parse_fault("collide:1,2@5")
    parts = collide.split()
    assert parts == (Fault(FaultKind.COLLIDE, 5.0, (1,)), Fault(FaultKind.COLLIDE, 5.0, (2,)))
    assert [p.origin for p in parts] == ["collide:1,2@5"] * 2
    assert [p.robot for p in parts] == [1, 2]
    assert parse_fault("crash:2@3").split() == (parse_fault("crash:2@3"),)
    partition = parse_fault("partition:1|2@1+1")
    assert partition.split() == (partition,)
    with pytest.raises(ValueError, match="several robots"):
        _ = parse_fault("crash:1,2@3").robot


def test_fault_records_one_a_robot() -> None:
    assert fault_records(parse_fault("collide:1,2@5"), 5.0) == [
        {"t": 5.0, "robot": 1, "event": "fault", "kind": "collide", "spec": "collide:1,2@5"},
        {"t": 5.0, "robot": 2, "event": "fault", "kind": "collide", "spec": "collide:1,2@5"}]


def test_check_faults_names_the_unknown_robot_of_several() -> None:
    assert check_faults([parse_fault("collide:1,9@5")], PAPER_IDS, physics=False) == [
        "collide:1,9@5: robot 9 is not in the swarm (robots: 1-6)"]
    assert check_faults([parse_fault("collide:1,2@5")], PAPER_IDS, physics=False) == []


def test_virtual_collide_is_two_crashes_at_one_instant(
        paper: tuple[SwarmPlan, Params]) -> None:
    """In --virtual a collision kills both robots at once: the same run as two crash
    faults at that instant, logged once a robot with the spec given."""
    plan, params = paper
    collide = run_virtual(plan, params, duration=8, faults=[parse_fault("collide:1,3@3")])
    crashes = run_virtual(plan, params, duration=8,
                          faults=[parse_fault("crash:1@3"), parse_fault("crash:3@3")])
    strip = [e for e in collide.events if e["event"] != "fault"]
    assert strip == [e for e in crashes.events if e["event"] != "fault"]
    assert [(e["robot"], e["spec"]) for e in collide.events if e["event"] == "fault"] == [
        (1, "collide:1,3@3"), (3, "collide:1,3@3")]
    assert collide.holders() == {"f2": [2], "f4": [4], "f1": [5], "f3": [6]}
    assert 1 not in collide.final and 3 not in collide.final


@pytest.mark.parametrize(("spec", "senders", "receivers"), [
    ("fade:2@5+0.46", {2}, None),
    ("deaf:6:2@5+0.86", {2}, {6}),
    ("deaf:6:2,3@1+1", {2, 3}, {6}),
    ("partition:1,2>3,4@3+2", {1, 2}, {3, 4}),
])
def test_link_faults_cut_one_way(spec: str, senders: set[int],
                                 receivers: set[int] | None) -> None:
    cut = parse_fault(spec).cut()
    assert cut is not None
    assert cut[0] == frozenset(senders) and cut[1] == (None if receivers is None else receivers)
    assert parse_fault("partition:1,2|3,4@3+2").cut() is None


@pytest.mark.parametrize(("spec", "what"), [
    ("fade:2@5", "missing '+D'"),
    ("deaf:6@5+1", "no ':S'"),
    ("deaf:6:6@5+1", "hears itself"),
    ("deaf:6,5:2@5+1", "one robot"),
    ("partition:1>2>3@1+1", "two groups"),
    ("partition:1,2>3|4@1+1", "not both"),
])
def test_bad_link_faults_say_what_is_wrong(spec: str, what: str) -> None:
    with pytest.raises(FaultSpecError, match=re.escape(what)):
        parse_fault(spec)


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_virtual_wiped_restart_starts_without_the_state_file(
        paper: tuple[SwarmPlan, Params], auth: str) -> None:
    """`restart:2@T:wiped`: robot 2 comes back as at a first start, the plan's holder of
    f2 at epoch 0, and the takeover of its slot (by 6, after its crash) is refuted by
    its live hold (DESIGN "Every proof is bound to its run"): 2 executes f2 again at the
    reassertion's epoch, 6 is fenced, and the run breaks no invariant. Restarted on its
    state file instead, it rejoins and stays a standby beside 6."""
    plan, params = paper
    crash = parse_fault("crash:2@3")
    wiped = run_virtual(plan, params, duration=10, auth=auth,
                        faults=[crash, parse_fault("restart:2@6:wiped")])
    kept = run_virtual(plan, params, duration=10, auth=auth,
                       faults=[crash, parse_fault("restart:2@6")])
    assert wiped.violations == [] and kept.violations == []
    assert [e["spec"] for e in wiped.events if e["event"] == "fault"] == [
        "crash:2@3", "restart:2@6:wiped"]
    assert wiped.holders()["f2"] == [2] and wiped.final[2] == ("active", "f2", 2)
    assert [e["robot"] for e in wiped.events if e["event"] == "fenced"] == [6]
    assert kept.holders()["f2"] == [6] and kept.final[2][0] == "standby"
