"""The end-of-run summary of `swarmd sim` (DESIGN section 3), from the event log.

Both simulators end here, so `--virtual` and the multi-process run print the same
thing: per injected fault the detection latency (fault -> first `suspect` of the robot,
or its own `leave` when it handed over), the takeover latency (fault -> `takeover` of
its slot), who took over; the counts of false takeovers and invariant violations.

A real-time run adds what only processes on a real machine have (`sim.realtime.summary`):
robot processes that failed or ended on their own (`problems`: the run is not ok, the
command exits non-zero), and how late the robots' event loops ran. When they were late
enough to be suspected, `warnings` says so first, so that false suspicions and takeovers
caused by a machine that could not keep up are not read as protocol failures.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console
from rich.table import Table
from rich.text import Text

from sim.shared.faults import Fault, FaultKind
from sim.shared.holders import HolderFold
from sim.shared.invariants import Violation, check_events
from swarmd.core.events import Alert, Event, Leave, Started, Suspect, Takeover, event_of
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.services.runtime import QUIET_DROPS

_REPLACEABLE = (FaultKind.CRASH, FaultKind.RESTART, FaultKind.PAUSE, FaultKind.LEAVE,
                FaultKind.UNHEALTHY, FaultKind.MOTOR, FaultKind.COLLIDE)
"""Faults whose row says who took the robot's slot over. In real time `restart` kills the
process first, so its slot can be taken over like a crash's (or kept, if the robot is
back before T_max: then the row shows no takeover)."""


@dataclass(frozen=True, slots=True)
class FaultOutcome:
    spec: str
    kind: str
    robot: int | None
    at: float
    function: str | None
    """The slot the robot executed when the fault hit (None: it held none)."""
    detected: float | None
    """s from the fault to the first suspicion (or the robot's own LEAVE)."""
    taken_over: float | None
    """s from the fault to the takeover of its slot."""
    by: int | None
    epoch: int | None

    def as_dict(self) -> dict[str, Any]:
        return {
            "fault": self.spec, "kind": self.kind, "robot": self.robot, "at": self.at,
            "function": self.function,
            "detection_latency": _r(self.detected), "takeover_latency": _r(self.taken_over),
            "taken_over_by": self.by, "epoch": self.epoch,
        }


@dataclass(slots=True)
class Summary:
    mode: str
    duration: float
    robots: int
    faults: list[FaultOutcome]
    takeovers: int
    false_takeovers: list[dict[str, Any]]
    violations: list[Violation]
    alerts: int
    holders: dict[str, list[int]]
    """function -> robots executing it at the end, from the event log."""
    extra: dict[str, Any] = field(default_factory=dict)
    false_suspicions: int = 0
    """Watchdogs that fired on a healthy, reachable robot (not an invariant: loss and a
    late machine cause them; the protocol refutes them, rule 5)."""
    problems: list[str] = field(default_factory=list)
    """Robot processes that failed or ended on their own (real time): not ok."""
    warnings: list[str] = field(default_factory=list)
    """What makes the figures less telling without making the run wrong (lateness)."""
    drops: dict[int, dict[str, int]] = field(default_factory=dict)
    """robot -> frames its core dropped, by reason (DESIGN section 2: every frame
    refused is a counted drop), summed over its processes; reasons logged by the daemon
    only (`swarmd.services.runtime.QUIET_DROPS` left out: its own echo, other robots' traffic)."""

    @property
    def ok(self) -> bool:
        """No invariant violated and no robot process lost along the way."""
        return not self.violations and not self.problems

    def as_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "duration": self.duration,
            "robots": self.robots,
            "faults": [f.as_dict() for f in self.faults],
            "takeovers": self.takeovers,
            "false_takeovers": len(self.false_takeovers),
            "false_takeover_details": self.false_takeovers,
            "false_suspicions": self.false_suspicions,
            "alerts": self.alerts,
            "violations": [v.as_dict() for v in self.violations],
            "holders": self.holders,
            "process_problems": self.problems,
            "warnings": self.warnings,
            "drops": {str(r): d for r, d in sorted(self.drops.items())},
            "ok": self.ok,
            **self.extra,
        }

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), indent=2, sort_keys=False)


def counted_drops(drops: Mapping[str, int]) -> dict[str, int]:
    """The reasons of `Summary.drops`: non-zero, not quiet."""
    return {k: int(n) for k, n in sorted(drops.items()) if n and k not in QUIET_DROPS}


def _typed(events: Iterable[Mapping[str, Any]]) -> list[tuple[float, int, Event | None]]:
    """(t, robot, the typed event) for each record, in order; None for a record that is
    no event (`Event.from_record` refuses it), which no count or row reads."""
    return [(float(rec["t"]), int(rec["robot"]), event_of(rec)) for rec in events]


def _r(x: float | None) -> float | None:
    return None if x is None else round(x, 3)


def _state_at(events: list[dict[str, Any]], robot: int, t: float) -> tuple[str | None, bool]:
    """(the function `robot` executed, whether it was down) when a fault hit it at `t`.
    Records from `t` on are left out: the fault being explained has not acted yet, and
    what it caused may carry the same t (`--virtual` logs the robot's own `leave` at the
    fault's instant); an earlier crash has acted (a dead robot holds nothing)."""
    fold = HolderFold()
    for e in events:
        if e["t"] >= t:
            break
        if e["robot"] == robot:
            fold.feed(e)
    holding = fold.robots.get(robot)
    return fold.executing().get(robot), holding is not None and holding.role == "crashed"


def holders_at_end(events: list[dict[str, Any]], dead: set[int]) -> dict[str, list[int]]:
    """function -> the robots executing it when the run ended (robots in `dead` left
    out), from the event log."""
    return HolderFold().feed_all(events).holders(exclude=dead)


def summarize(
    events: list[dict[str, Any]],
    faults: list[Fault],
    plan: SwarmPlan,
    params: Params,
    *,
    loss: float,
    duration: float,
    mode: str,
    extra_violations: list[Violation] | None = None,
    deaths: Mapping[int, float] | None = None,
) -> Summary:
    """The summary of a run from its events and injected faults. `deaths`: robot -> time
    its process ended on its own (real time); the checker treats each as a crash (its
    replacement is no false takeover) and the fault table shows it as one."""
    events = sorted(events, key=lambda e: e["t"])
    typed = _typed(events)
    died = [Fault(FaultKind.CRASH, t, (r,)) for r, t in sorted((deaths or {}).items())]
    checker = check_events(events, [*faults, *died], plan, params, loss=loss,
                           duration=duration)
    violations = list(checker.violations) + list(extra_violations or [])
    unique = _unique(violations)
    outcomes = _outcomes(faults, died, events, typed)
    dead = set(checker.dead)
    return Summary(
        mode=mode,
        duration=duration,
        robots=len(plan.robots),
        faults=outcomes,
        takeovers=sum(1 for _, _, e in typed if isinstance(e, Takeover)),
        false_takeovers=[{k: (round(v, 3) if isinstance(v, float) else v)
                          for k, v in ft.items()} for ft in checker.false_takeovers],
        violations=unique,
        alerts=sum(1 for _, _, e in typed if isinstance(e, Alert)),
        holders=holders_at_end(events, dead),
        false_suspicions=checker.false_suspicions,
    )


def _unique(violations: list[Violation]) -> list[Violation]:
    """The violations oldest first, each reported once."""
    # Checker and a simulator may both report a raise; keep one of each.
    seen: set[tuple[float, str, int | None]] = set()
    unique = []
    for v in sorted(violations, key=lambda v: v.t):
        key = (round(v.t, 6), v.kind, v.robot)
        if key not in seen:
            seen.add(key)
            unique.append(v)
    return unique


def _outcomes(faults: list[Fault], died: list[Fault], events: list[dict[str, Any]],
              typed: list[tuple[float, int, Event | None]]) -> list[FaultOutcome]:
    """A row of the fault table for each fault on each robot, and for each death."""
    outcomes = []
    credited: set[int] = set()  # takeovers already explained by an earlier fault
    # A fault on several robots gets a row a robot: `collide:1,2@5 (robot 1)`.
    labelled = [(part, f.spec() if part is f else f"{f.spec()} (robot {part.robot})")
                for f in faults for part in f.split()]
    labelled += [(f, f"died:{f.robot}@{f.at:.2f}") for f in died]
    for fault, spec in sorted(labelled, key=lambda fs: fs[0].at):
        if fault.kind not in _REPLACEABLE:
            outcomes.append(FaultOutcome(spec, fault.kind, None if fault.kind is
                                         FaultKind.PARTITION else fault.robot, fault.at, None,
                                         None, None, None, None))
        else:
            outcomes.append(_outcome(fault, spec, events, typed, credited))
    return outcomes


def _outcome(fault: Fault, spec: str, events: list[dict[str, Any]],
             typed: list[tuple[float, int, Event | None]], credited: set[int]) -> FaultOutcome:
    """How the swarm answered a fault on one robot: when it was detected, and who took
    its slot over (a takeover it explains joins `credited`)."""
    r = fault.robot
    f, down = _state_at(events, r, fault.at)
    detected = taken = by = epoch = None
    for i, (t, robot, event) in enumerate(typed):
        if down:
            break  # a fault on a robot already dead explains nothing
        if t < fault.at:
            continue
        if detected is None and (
            (isinstance(event, Suspect) and event.subject == r)
            or (isinstance(event, Leave) and robot == r)
        ):
            detected = t - fault.at
        if taken is None and isinstance(event, Takeover) and event.replaced == r \
                and (f is None or event.function == f) and i not in credited:
            credited.add(i)
            taken = t - fault.at
            by = robot
            epoch = event.epoch
    return FaultOutcome(spec, fault.kind, r, fault.at, f, detected, taken, by, epoch)


# -- real time ------------------------------------------------------------------------------

PAUSE_AFTERMATH = 1.0
"""s after a pause during which the paused robot's lateness is the pause's, not the
machine's (SIGSTOP freezes its loop; after SIGCONT it works off the backlog)."""


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile of `values` (q in [0, 100])."""
    values = sorted(values)
    return values[min(len(values) - 1, max(0, round(q / 100 * len(values) + 0.5) - 1))]


def lateness_figures(
    late: Sequence[tuple[int, float, float]], wakes: int, faults: Sequence[Fault],
) -> dict[str, Any]:
    """p50 / p99 / max of how late the robots' event loops woke up (ms), from the probes'
    late wake-ups `(robot, t, ms)` and the count of all wake-ups (the others were on time,
    under `sim.realtime.robot_proc.LATE_MS`). A paused robot's own lateness during and just after
    its pause is left out: it is the fault, not the machine."""
    frozen = [(r, f.at, (f.end or f.at) + PAUSE_AFTERMATH) for f in faults
              if f.kind is FaultKind.PAUSE for r in f.robots]
    kept = [x for x in late if not any(r == x[0] and a <= x[1] <= b for r, a, b in frozen)]
    n = max(wakes - (len(late) - len(kept)), len(kept))
    if n == 0:
        return {"wakes": 0}
    on_time = [0.0] * (n - len(kept))  # under LATE_MS: counted, not listed
    values = sorted(on_time + [ms for _, _, ms in kept])
    worst = max(kept, key=lambda x: x[2], default=None)
    return {"wakes": n, "p50_ms": percentile(values, 50), "p99_ms": percentile(values, 99),
            "max_ms": values[-1], "max_robot": worst[0] if worst else None,
            "max_t": worst[1] if worst else None}


def lateness_warning(figures: Mapping[str, Any], params: Params,
                     violations: Sequence[Violation], suspicions: int = 0) -> str | None:
    """The warning a run gets when its robots were late enough to be suspected: a
    heartbeat due every `heartbeat_interval` and late by `t_max - heartbeat_interval`
    leaves a gap of `t_max` (paper Fig. 7), and half of that margin is already more
    than a loaded machine should eat. None when they were on time."""
    margin_ms = 1000 * (params.t_max - params.heartbeat_interval)
    worst = float(figures.get("max_ms", 0.0))
    if worst < margin_ms / 2:
        return None
    text = (f"robots were late: p99 {figures['p99_ms']:g} ms, max {worst:g} ms (robot "
            f"{figures['max_robot']} at t={figures['max_t']:.2f} s), against a margin of "
            f"{margin_ms:g} ms (t_max - heartbeat_interval); this machine could not keep "
            f"up (load average {os.getloadavg()[0]:.1f}), so suspicions and takeovers of "
            "healthy robots in this run may come from the load, not from the protocol")
    if suspicions:
        text += f"; {suspicions} suspicion(s) of healthy robots"
    if violations:
        text += f"; {len(violations)} invariant violation(s) to read with that in mind"
    return text


def slow_starts(events: Sequence[Mapping[str, Any]], faults: Sequence[Fault],
                grace: float) -> dict[int, float]:
    """robot -> run time its node first logged `started`, for the robots that started
    after the start-up grace (their watchers rightly took them for dead) and had no fault
    before (a restart starts late on purpose)."""
    first = {r: ts[0] for r, ts in _starts(events).items()}
    return {r: t for r, t in sorted(first.items()) if t > grace
            and not any(f.kind is not FaultKind.PARTITION and r in f.robots and f.at <= t
                        for f in faults)}


def restart_delays(events: Sequence[Mapping[str, Any]],
                   faults: Sequence[Fault]) -> dict[int, list[float]]:
    """robot -> for each `restart` fault of it, how long after the fault its new node
    logged `started` (a real process takes its start-up time; a bound that runs from the
    robot's return runs from then)."""
    starts = _starts(events)
    out: dict[int, list[float]] = {}
    for f in faults:
        if f.kind is FaultKind.RESTART:
            r = f.robots[0]
            back = next((t for t in starts.get(r, ()) if t >= f.at), None)
            if back is not None:
                out.setdefault(r, []).append(round(back - f.at, 3))
    return out


def _starts(events: Sequence[Mapping[str, Any]]) -> dict[int, list[float]]:
    """robot -> the run times its nodes logged `started`, in log order."""
    starts: dict[int, list[float]] = {}
    for t, robot, event in _typed(events):
        if isinstance(event, Started):
            starts.setdefault(robot, []).append(t)
    return starts


def render_summary(summary: Summary, console: Console) -> None:
    """The human form of the summary (rich tables)."""
    table = Table(title=f"swarmd sim ({summary.mode}): {summary.robots} robots, "
                        f"{summary.duration:g} s", title_justify="left")
    for col in ("fault", "slot", "detected after", "taken over after", "by", "epoch"):
        table.add_column(col)
    for f in summary.faults:
        table.add_row(
            f.spec, f.function or "-",
            "-" if f.detected is None else f"{f.detected:.3f} s",
            "-" if f.taken_over is None else f"{f.taken_over:.3f} s",
            "-" if f.by is None else str(f.by),
            "-" if f.epoch is None else str(f.epoch),
        )
    if summary.faults:
        console.print(table)
    holders = ", ".join(f"{fn}: {'+'.join(map(str, rs))}" for fn, rs in summary.holders.items())
    console.print(f"holders at the end: {holders or 'none'}")
    console.print(f"takeovers: {summary.takeovers}   alerts: {summary.alerts}   "
                  f"false takeovers: {len(summary.false_takeovers)}   "
                  f"false suspicions: {summary.false_suspicions}   "
                  f"invariant violations: {len(summary.violations)}")
    totals: dict[str, int] = {}
    for per_robot in summary.drops.values():
        for reason, n in per_robot.items():
            totals[reason] = totals.get(reason, 0) + n
    if totals:
        console.print("dropped frames: " + ", ".join(
            f"{reason} {n}" for reason, n in sorted(totals.items())))
    for v in summary.violations:
        console.print(Text.assemble(("VIOLATION", "red"), f" t={v.t:.3f} {v.kind}: {v.detail}"))
    for p in summary.problems:
        console.print(f"PROCESS PROBLEM: {p}", markup=False, highlight=False, style="red")
    for w in summary.warnings:
        console.print(f"WARNING: {w}", markup=False, highlight=False, style="yellow")
    for k, v in summary.extra.items():
        console.print(f"{k}: {v}", markup=False, soft_wrap=True)
