"""Every small schedule, exhaustively, in virtual time (docs/sim.md "schedules").

Two swarms: the paper's (configs/paper.yaml) and a ring of eight actives, each watching
its two ring neighbours, with three standbys covering all eight (configs/ring8.yaml).
On each: every pair of robots failing the same way (crash, leave, pause, unhealthy), the
second T_max/2, T_max or 2 T_max after the first (either robot first) or at the same
instant, each at four phases of the heartbeat grid; on the paper's swarm also every
triple of crashes, at once and staggered by T_max/2. Every run is judged by the
invariant checker (sim.shared.invariants) and must have no violation. A run lasts until
one takeover bound and a second after the last failure (a pause: until it has ended and
the stale holder was fenced).

Both swarms have symmetries that map the plan onto itself (`SYMMETRIES`: the paper's
square reflected; the ring turned by four or mirrored, standbys 9 and 10 swapped): a
schedule is run once per orbit, in the form with the smallest robot ids. The suite runs
the ring's pairs and the link faults at one phase of the four
(`SUITE_RING8_PHASES`, `SUITE_LINK_PHASES`), the paper's pairs and triples at two
(`SUITE_PAPER_PHASES`), and the ring's link faults for every other
pair of robots (`SUITE_RING8_LINK_PAIRS`), to stay within CI's time;
`python bench/bench_schedules.py` runs every phase and every pair.

Link faults (DESIGN, "Convergence"), on both swarms at two phases of the grid: every
robot's transmissions fading (`fade`) for 0.8, 1.8 or 5 T_max; every robot deaf to every
other (`deaf`) as long; every robot fading while another stays deaf to it 0, 0.4 or 0.8
T_max longer (the shape that left two holders of one slot in per-robot mode); every two
robots fading together (the suite at one phase, `python bench/bench_schedules.py` at
two). After the last heal the run lasts `Bounds.settle` and more, so the
checker judges one view of every slot (invariant 8) as well.

Every run is signed per robot, the mode users run; every SAMPLE-th schedule runs again
unsigned and with a shared key.

The paper handles one failure at a time: its quorum of two distinct witnesses cannot
be met when a witness fails with the robot it watches. DESIGN rule 9 (the standby's own
ears) closes that gap: every schedule here, correlated ones included, must pass.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

from sim.shared.faults import Fault, FaultKind
from sim.shared.invariants import Bounds
from sim.virtual.simulator import run_virtual
from swarmd.config import load_swarm
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
KINDS = ("crash", "leave", "pause", "unhealthy")
START = 2.0  # s: every robot has started and heard its neighbours (startup_grace 2 s)
PHASES = 4  # fault instants per heartbeat interval
PAUSE = 3.5  # s: longer than two takeover bounds, so a paused holder must be replaced
SILENT = ("crash", "pause")  # failures the swarm learns of only from silence

SYMMETRIES: dict[str, list[dict[int, int]]] = {
    # paper: ring 1-2-3-4, 5 covers f1/f4, 6 covers f2/f3
    "paper": [{1: 2, 2: 1, 3: 4, 4: 3, 5: 6, 6: 5}, {1: 4, 4: 1, 2: 3, 3: 2},
              {1: 3, 3: 1, 2: 4, 4: 2, 5: 6, 6: 5}],
    # ring8: 9 covers f1-f4, 10 covers f5-f8, 11 covers all eight
    "ring8": [{**{i: (i + 3) % 8 + 1 for i in range(1, 9)}, 9: 10, 10: 9},
              {**{i: 9 - i for i in range(1, 9)}, 9: 10, 10: 9},
              {**{i: (12 - i) % 8 + 1 for i in range(1, 9)}}],
}


@cache
def swarm(name: str) -> tuple[SwarmPlan, Params]:
    cfg = load_swarm(CONFIGS / f"{name}.yaml")
    return cfg.to_plan(), cfg.params()


@dataclass(frozen=True)
class Schedule:
    swarm: str
    kind: str
    robots: tuple[int, ...]
    """Robots in the order they fail."""
    gap: float
    """s between one failure and the next."""
    phase: int
    length: float = 0.0
    """Link faults: how long the first one lasts, in T_max."""
    extra: float = 0.0
    """`fade+deaf`: how much longer (T_max) the second robot stays deaf to the first."""

    def faults(self) -> list[Fault]:
        _, params = swarm(self.swarm)
        t0 = START + self.phase * params.heartbeat_interval / PHASES
        if self.kind in LINK:
            return self._link_faults(t0, params)
        dur = PAUSE if self.kind == "pause" else None
        return [Fault(FaultKind(self.kind), round(t0 + i * self.gap, 6), (r,), dur)
                for i, r in enumerate(self.robots)]

    def _link_faults(self, t0: float, params: Params) -> list[Fault]:
        d = round(self.length * params.t_max, 6)
        a, b = self.robots
        if self.kind == "deaf":
            return [Fault(FaultKind.DEAF, t0, (a,), d, ((b,),))]
        if self.kind == "fade2":
            return [Fault(FaultKind.FADE, t0, (a,), d), Fault(FaultKind.FADE, t0, (b,), d)]
        return [Fault(FaultKind.FADE, t0, (a,), d),
                Fault(FaultKind.DEAF, t0, (b,), round(d + self.extra * params.t_max, 6), ((a,),))]

    def duration(self) -> float:
        _, params = swarm(self.swarm)
        if self.kind in LINK:
            heal = max((f.end or f.at) for f in self.faults())
            return round(heal + Bounds.of(params, 0.0).settle + 0.5, 3)
        last = self.faults()[-1]
        bound = params.takeover_bound()
        tail = PAUSE + 2 * params.t_max if self.kind == "pause" else 0.0
        return round(last.at + max(bound + 1.0, tail), 3)

    def canonical(self) -> bool:
        """Whether this is the form of its orbit under SYMMETRIES that is run."""
        return all(self.robots <= tuple(m.get(r, r) for r in self.robots)
                   for m in SYMMETRIES[self.swarm])

    def id(self) -> str:
        specs = ",".join(f.spec() for f in self.faults())
        return f"{self.swarm}-{specs}"


def _gaps(params: Params) -> tuple[float, ...]:
    t = params.t_max
    return (t / 2, t, 2 * t)


SUITE_RING8_PHASES = range(0, 1)
"""Phases of the ring of eight's pair schedules in the suite: the first of the four, as
for the link faults, so the suite stays within CI's time (the ring's pairs at every
phase were half of the suite's CPU time); the paper's swarm runs at all four, and
`bench/bench_schedules.py` runs every phase on both."""


SUITE_PAPER_PHASES = range(0, PHASES, 2)
"""Phases of the paper swarm's pair and triple schedules in the suite: every other one
of the four (the first and third: on the grid and half a period off it), for CI's time;
`bench/bench_schedules.py` runs all four."""


def schedules(ring8_phases: range = range(PHASES),
              paper_phases: range = range(PHASES)) -> list[Schedule]:
    out = []
    for name in ("paper", "ring8"):
        plan, params = swarm(name)
        ids = sorted(plan.robots)
        phases = ring8_phases if name == "ring8" else paper_phases
        for kind, (a, b), phase in itertools.product(KINDS, itertools.combinations(ids, 2),
                                                     phases):
            out.append(Schedule(name, kind, (a, b), 0.0, phase))
            for gap in _gaps(params):
                out.append(Schedule(name, kind, (a, b), gap, phase))
                out.append(Schedule(name, kind, (b, a), gap, phase))
    plan, params = swarm("paper")
    for trio, phase in itertools.product(itertools.combinations(sorted(plan.robots), 3),
                                         paper_phases):
        out.append(Schedule("paper", "crash", trio, 0.0, phase))
        out.append(Schedule("paper", "crash", trio, params.t_max / 2, phase))
    return [s for s in out if s.canonical()]


def every_schedule() -> list[Schedule]:
    """The whole set (`bench/bench_schedules.py`): the suite's, with every phase."""
    return schedules() + [s for s in link_schedules() if s.canonical()]


LINK = ("deaf", "fade+deaf", "fade2")
LENGTHS = (0.8, 1.8, 5.0)  # T_max: shorter than a suspicion; past a takeover; long
EXTRAS = (0.0, 0.4, 0.8)


LINK_PHASES = range(0, PHASES, 2)
"""Phases of the link-fault schedules (`bench/bench_schedules.py`); the suite runs the
first only, to stay within CI's time (`SUITE_LINK_PHASES`)."""
SUITE_LINK_PHASES = range(0, 1)


def link_schedules(phases: range = LINK_PHASES) -> list[Schedule]:
    out = []
    for name in ("paper", "ring8"):
        plan, _ = swarm(name)
        ids = sorted(plan.robots)
        for (a, b), phase, length in itertools.product(
                itertools.permutations(ids, 2), phases, LENGTHS):
            out.append(Schedule(name, "deaf", (a, b), 0.0, phase, length))
            for extra in EXTRAS:
                out.append(Schedule(name, "fade+deaf", (a, b), 0.0, phase, length, extra))
            if a < b:
                out.append(Schedule(name, "fade2", (a, b), 0.0, phase, length))
    return out


SUITE_RING8_LINK_PAIRS = 2
"""The suite runs the ring of eight's link faults for every SUITE_RING8_LINK_PAIRS-th
pair of robots (in sorted order), each at every length and overlap: they were over half
of this module's CPU time (eleven robots, runs that last until the views settle).
The paper's swarm runs every pair; `bench/bench_schedules.py` runs every pair on both."""


def suite_link_schedules() -> list[Schedule]:
    """The link-fault schedules the suite runs (`SUITE_LINK_PHASES`,
    `SUITE_RING8_LINK_PAIRS`)."""
    links = [s for s in link_schedules(SUITE_LINK_PHASES) if s.canonical()]
    ring_pairs = sorted({s.robots for s in links if s.swarm == "ring8"})
    kept = set(ring_pairs[::SUITE_RING8_LINK_PAIRS])
    return [s for s in links if s.swarm != "ring8" or s.robots in kept]


def _params() -> list[object]:
    suite = schedules(SUITE_RING8_PHASES, SUITE_PAPER_PHASES) + suite_link_schedules()
    return [pytest.param(s, id=s.id()) for s in suite]


@pytest.mark.parametrize("schedule", _params())
def test_schedule(schedule: Schedule) -> None:
    plan, params = swarm(schedule.swarm)
    res = run_virtual(plan, params, duration=schedule.duration(), faults=schedule.faults(),
                      auth="per-robot")
    assert res.violations == [], [v.as_dict() for v in res.violations]


SAMPLE = 20
"""Every SAMPLE-th schedule runs again unsigned and with a shared key (`python
bench/bench_schedules.py --auth none|shared` runs the whole set in either)."""


@pytest.mark.parametrize("auth", ["shared", "none"])
@pytest.mark.parametrize("schedule", _params()[::SAMPLE])
def test_schedule_signed(schedule: Schedule, auth: str) -> None:
    plan, params = swarm(schedule.swarm)
    res = run_virtual(plan, params, duration=schedule.duration(), faults=schedule.faults(),
                      auth=auth)
    assert res.violations == [], [v.as_dict() for v in res.violations]
