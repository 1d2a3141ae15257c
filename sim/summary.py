"""The end-of-run summary of `swarmd sim` (DESIGN section 3), from the event log.

Both simulators end here, so `--virtual` and the multi-process run print the same
thing: per injected fault the detection latency (fault -> first `suspect` of the robot,
or its own `leave` when it handed over), the takeover latency (fault -> `takeover` of
its slot), who took over; the counts of false takeovers and invariant violations.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console
from rich.table import Table

from sim.faults import Fault
from sim.holders import HolderFold
from sim.invariants import Violation, check_events
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

_REPLACEABLE = ("crash", "restart", "pause", "leave", "unhealthy", "motor")
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

    @property
    def ok(self) -> bool:
        return not self.violations

    def as_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "duration": self.duration,
            "robots": self.robots,
            "faults": [f.as_dict() for f in self.faults],
            "takeovers": self.takeovers,
            "false_takeovers": len(self.false_takeovers),
            "false_takeover_details": self.false_takeovers,
            "alerts": self.alerts,
            "violations": [v.as_dict() for v in self.violations],
            "holders": self.holders,
            "ok": self.ok,
            **self.extra,
        }

    def to_json(self) -> str:
        return json.dumps(self.as_dict(), indent=2, sort_keys=False)


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
) -> Summary:
    events = sorted(events, key=lambda e: e["t"])
    checker = check_events(events, faults, plan, params, loss=loss, duration=duration)
    violations = list(checker.violations) + list(extra_violations or [])
    # Checker and a simulator may both report a raise; keep one of each.
    seen: set[tuple[float, str, int | None]] = set()
    unique = []
    for v in sorted(violations, key=lambda v: v.t):
        key = (round(v.t, 6), v.kind, v.robot)
        if key not in seen:
            seen.add(key)
            unique.append(v)
    outcomes = []
    credited: set[int] = set()  # takeovers already explained by an earlier fault
    for fault in sorted(faults, key=lambda f: f.at):
        if fault.kind not in _REPLACEABLE:
            outcomes.append(FaultOutcome(fault.spec(), fault.kind, None if fault.kind ==
                                         "partition" else fault.robot, fault.at, None,
                                         None, None, None, None))
            continue
        r = fault.robot
        f, down = _state_at(events, r, fault.at)
        detected = taken = by = epoch = None
        for i, e in enumerate(events):
            if down:
                break  # a fault on a robot already dead explains nothing
            if e["t"] < fault.at:
                continue
            name = e["event"]
            if detected is None and (
                (name == "suspect" and e.get("subject") == r)
                or (name == "leave" and e["robot"] == r)
            ):
                detected = e["t"] - fault.at
            if taken is None and name == "takeover" and e.get("replaced") == r \
                    and (f is None or e.get("function") == f) and i not in credited:
                credited.add(i)
                taken, by, epoch = e["t"] - fault.at, e["robot"], e.get("epoch")
        outcomes.append(FaultOutcome(fault.spec(), fault.kind, r, fault.at, f, detected,
                                     taken, by, epoch))
    dead = set(checker.dead)
    return Summary(
        mode=mode,
        duration=duration,
        robots=len(plan.robots),
        faults=outcomes,
        takeovers=sum(1 for e in events if e["event"] == "takeover"),
        false_takeovers=[{k: (round(v, 3) if isinstance(v, float) else v)
                          for k, v in ft.items()} for ft in checker.false_takeovers],
        violations=unique,
        alerts=sum(1 for e in events if e["event"] == "alert"),
        holders=holders_at_end(events, dead),
    )


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
                  f"invariant violations: {len(summary.violations)}")
    for v in summary.violations:
        console.print(f"[red]VIOLATION[/red] t={v.t:.3f} {v.kind}: {v.detail}")
    for k, v in summary.extra.items():
        console.print(f"{k}: {v}")
