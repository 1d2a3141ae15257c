"""Property: random fault schedules on random valid swarms never break an invariant.

A swarm is a ring of active slots, each watching `k` slots on
each side plus a few random extra edges (so every slot has >= quorum watchers, the
condition `swarmd check` enforces, DESIGN rule 3), and 1-3 standbys covering random
slots (rule 6). Faults are any of DESIGN section 3's kinds at random times, on a
channel with 0-20 % loss. The invariants are sim.shared.invariants' (takeover within its
bound, single holder, no false takeover by a liar without loss, every warning
resolved, no node raises); they are never weakened here.

CI runs the "ci" profile (a few hundred examples, see conftest.py); `bench/` or
HYPOTHESIS_PROFILE=bench runs thousands.
"""

from __future__ import annotations

from dataclasses import dataclass

from hypothesis import given, settings
from hypothesis import strategies as st

from sim.shared.faults import Fault, FaultKind, parse_fault
from sim.virtual.simulator import VirtualResult, run_virtual
from swarmd.core.params import Params, udp
from swarmd.core.plan import RobotPlan, SwarmPlan

KINDS = ("crash", "restart", "pause", "partition", "liar", "leave", "unhealthy")


@dataclass(frozen=True)
class Case:
    plan: SwarmPlan
    faults: tuple[Fault, ...]
    loss: float
    seed: int
    duration: float

    def describe(self) -> str:
        robots = {r: (p.function, p.subs) for r, p in sorted(self.plan.robots.items())}
        return (f"robots={robots} watches={dict(self.plan.watches)} "
                f"faults={[f.spec() for f in self.faults]} loss={self.loss} "
                f"seed={self.seed} duration={self.duration}")


@st.composite
def swarms(draw: st.DrawFn) -> SwarmPlan:
    n = draw(st.integers(3, 8))
    k = draw(st.integers(1, min(2, (n - 1) // 2)))
    functions = tuple(f"f{i + 1}" for i in range(n))
    watches: dict[str, set[str]] = {f: set() for f in functions}
    for i, f in enumerate(functions):
        for d in range(1, k + 1):
            watches[f].add(functions[(i + d) % n])
            watches[f].add(functions[(i - d) % n])
    for _ in range(draw(st.integers(0, 3))):
        a, b = draw(st.sampled_from(functions)), draw(st.sampled_from(functions))
        if a != b:
            watches[a].add(b)
    robots = {i + 1: RobotPlan(i + 1, f) for i, f in enumerate(functions)}
    for j in range(draw(st.integers(1, 3))):
        rid = n + 1 + j
        subs = draw(st.lists(st.sampled_from(functions), min_size=1, max_size=n, unique=True))
        robots[rid] = RobotPlan(rid, None, tuple(sorted(subs, key=functions.index)))
    return SwarmPlan(1000 + n, functions,
                     robots, {f: tuple(sorted(w, key=functions.index)) for f, w in watches.items()})


@st.composite
def cases(draw: st.DrawFn, spaced: bool = False) -> Case:
    """A random swarm and schedule. `spaced`: faults at least one takeover bound apart
    (4 s > 3.7 s under loss) and a liar is hit by no other fault; this avoids the known
    problems listed at `test_random_faults_never_break_an_invariant`."""
    plan = draw(swarms())
    duration = draw(st.sampled_from((8.0, 10.0, 12.0)))
    ids = sorted(plan.robots)
    faults: list[Fault] = []
    times: set[float] = set()
    liars: set[int] = set()
    hit: set[int] = set()
    for i in range(draw(st.integers(0, 2 if spaced else 4))):
        kind = draw(st.sampled_from(KINDS))
        if spaced:
            at = round(1.0 + 4.0 * i + draw(st.floats(0.0, 1.0)), 2)
            if at > duration - 2.0:
                break
        else:
            at = round(draw(st.floats(1.0, duration - 2.0)), 2)
        # Distinct instants: sim.shared.invariants excuses a missed takeover only for a fault
        # strictly after the crash, so two faults at one instant are judged in list
        # order (reported; see the final report of this test suite).
        while at in times:
            at = round(at + 0.01, 2)
        times.add(at)
        if kind == "partition":
            group = draw(st.lists(st.sampled_from(ids), min_size=1, max_size=len(ids) - 1,
                                  unique=True))
            rest = tuple(r for r in ids if r not in group)
            dur = round(draw(st.floats(0.5, 4.0)), 2)
            faults.append(Fault(FaultKind(kind), at, (*sorted(group), *rest), dur,
                                (tuple(sorted(group)), rest)))
        elif kind == "pause":
            dur = round(draw(st.floats(0.3, 4.0)), 2)
            faults.append(Fault(FaultKind(kind), at, (draw(st.sampled_from(ids)),), dur))
        else:
            faults.append(Fault(FaultKind(kind), at, (draw(st.sampled_from(ids)),)))
        if spaced:
            targets = set(faults[-1].robots)
            if targets & (hit if kind == "liar" else liars):
                faults.pop()  # a liar is hit by no other fault
            else:
                (liars if kind == "liar" else hit).update(targets)
    loss = draw(st.sampled_from((0.0, 0.0, 0.05, 0.1, 0.2)))
    seed = draw(st.integers(0, 2**32 - 1))
    return Case(plan, tuple(faults), loss, seed, duration)


def run_case(case: Case) -> VirtualResult:
    # Signed per robot, the mode users run (DESIGN, "Convergence").
    return run_virtual(case.plan, udp(), duration=case.duration, faults=case.faults,
                       loss=case.loss, seed=case.seed, auth="per-robot")


def check(case: Case, allow: frozenset[str] = frozenset()) -> None:
    res = run_case(case)
    bad = [v for v in res.violations if v.kind not in allow]
    assert bad == [], f"{[v.as_dict() for v in bad]}\n{case.describe()}"


@settings(max_examples=40)
@given(cases(spaced=True))
def test_spaced_random_faults_never_break_an_invariant(case: Case) -> None:
    check(case)


@settings(max_examples=40)
@given(cases())
def test_random_faults_never_break_an_invariant(case: Case) -> None:
    """Any schedule, overlapping faults included: correlated failures too (DESIGN
    rule 9)."""
    check(case)


# ------------------------------------------- regressions: core bugs the properties found
def _full_mesh(n: int) -> SwarmPlan:
    fs = tuple(f"f{i + 1}" for i in range(n))
    robots = {i + 1: RobotPlan(i + 1, f) for i, f in enumerate(fs)}
    robots[n + 1] = RobotPlan(n + 1, None, fs)
    return SwarmPlan(1000 + n, fs, robots, {f: tuple(g for g in fs if g != f) for f in fs})


def test_faulty_liar_cannot_block_its_own_replacement(
        paper: tuple[SwarmPlan, Params]) -> None:
    plan, params = paper
    res = run_virtual(plan, params, duration=10.0, loss=0.1, seed=13,
                      faults=[parse_fault("liar:2@2"), parse_fault("unhealthy:2@4")])
    assert res.holders().get("f2") == [6]
    assert res.violations == []


def test_standby_behind_on_epoch_still_replaces_a_dead_new_holder() -> None:
    fs = tuple(f"f{i + 1}" for i in range(5))
    robots = {i + 1: RobotPlan(i + 1, f) for i, f in enumerate(fs)}
    robots |= {6: RobotPlan(6, None, ("f1",)), 7: RobotPlan(7, None, ("f1", "f2")),
               8: RobotPlan(8, None, ("f1",))}
    ring = {f: (fs[i - 1], fs[(i + 1) % 5]) for i, f in enumerate(fs)}
    plan = SwarmPlan(1005, fs, robots, ring)
    faults = ["crash:1@1", "partition:1,2,3,4,5,6,7|8@1.38+2.69", "crash:2@2", "crash:6@4.12"]
    res = run_virtual(plan, udp(), duration=10.0, seed=0,
                      faults=[parse_fault(f) for f in faults])
    assert res.holders().get("f1") == [8]
    assert res.violations == []


def test_one_standby_two_overlapping_failures() -> None:
    """Regression (sim.shared.invariants f9266fa): one standby, two failures 0.5 s apart; the
    standby takes one slot, the other raises an alert and is no violation."""
    res = run_virtual(_full_mesh(5), udp(), duration=8.0, seed=0,
                      faults=[parse_fault("crash:3@1.01"), parse_fault("crash:1@1.5")])
    assert [e["function"] for e in res.events if e["event"] == "takeover"] == ["f3"]
    assert {e["function"] for e in res.events if e["event"] == "alert"} == {"f1"}
    assert res.violations == []
