"""Invariants of a swarm run, checked from the event log (issue 2, point 5).

The checker reads the same JSON Lines records users get (DESIGN section 3) plus the
injected faults, so the virtual simulator and the multi-process `swarmd sim` are judged
by one piece of code. What a robot executes is reconstructed from its events
(sim/shared/holders.py): `started{role: active}` and `takeover` start a function; `fenced`,
`leave`, `stopped`, a `started` as standby and a crash stop it; a paused robot executes
nothing until it resumes.

Invariants (each violation names the time, robot and what went wrong):
1. takeover: an ACTIVE robot that crashes (or leaves, reports a fault, or stays paused
   long enough) is replaced within `bounds.takeover`, whenever a live standby covers its
   slot and its live watchers reach the quorum, and no other fault hits in between;
2. single holder: outside partitions, no slot is executed by two running robots for
   longer than `bounds.dual`; after a partition heals, within `bounds.converge`;
3. liars: a takeover of a healthy, reachable robot is a false takeover; without loss it
   is a violation (a single liar can never get a healthy robot replaced). A robot is
   healthy only once its node has logged `started`: a process the machine could not
   start within the start-up grace is, to the swarm, a dead robot, and replacing it is
   the protocol working (the real-time summary warns about such a slow start);
4. warnings: every `warn` episode ends in a takeover of the slot, a refutation, or an
   alert (the paper's verified property, generalised);
5. no node raises on any input (virtual simulator: exceptions are reported here).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from sim.shared.faults import Fault
from sim.shared.holders import HolderFold
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

_STOPPING_FAULTS = ("crash", "leave", "unhealthy", "motor")


@dataclass(frozen=True, slots=True)
class Violation:
    t: float
    kind: str
    robot: int | None
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return {"t": round(self.t, 3), "kind": self.kind, "robot": self.robot,
                "detail": self.detail}


@dataclass(frozen=True, slots=True)
class Bounds:
    """Stated bounds (seconds) derived from the timing parameters."""

    takeover: float
    dual: float
    converge: float

    @classmethod
    def of(cls, p: Params, loss: float) -> Bounds:
        # Crash -> every watcher suspects within t_max; two warnings reach the standby
        # within the vote window; then claim_hold. Loss only delays the warnings, which
        # repeat every warn_interval: allow two more vote windows under loss.
        takeover = p.t_max + p.vote_window + p.claim_hold + (2 * p.vote_window if loss else 0.0)
        # A stale holder heartbeats on resume; the new holder answers at once (rule 2).
        dual = p.t_max + 2 * p.heartbeat_interval + (p.t_max if loss else 0.0)
        converge = 2 * p.t_max + 2 * p.heartbeat_interval + (p.t_max if loss else 0.0)
        return cls(takeover, dual, converge)


@dataclass(slots=True)
class _Expect:
    t: float
    robot: int
    function: str
    kind: str
    standbys: tuple[int, ...] = ()


@dataclass(slots=True)
class Checker:
    plan: SwarmPlan
    params: Params
    loss: float = 0.0
    bounds: Bounds = field(init=False)
    violations: list[Violation] = field(default_factory=list)
    # Who executes what comes from the shared fold of the log (sim/shared/holders.py), built
    # so that it can judge: it is per robot, so two robots on one slot both show (the
    # dual-execution check needs them); and with no `down` faults it counts every event
    # a robot logs, even one after its injected crash. Deaths, pauses and health come
    # from the injected faults below, never from the log the nodes write.
    holding: HolderFold = field(default_factory=lambda: HolderFold(down=()))
    dead: set[int] = field(default_factory=set)
    paused: set[int] = field(default_factory=set)
    unhealthy: dict[int, float] = field(default_factory=dict)
    faults: list[tuple[float, Fault]] = field(default_factory=list)
    partitions: list[tuple[float, float]] = field(default_factory=list)  # [start, heal)
    in_partition: bool = False
    dual_since: dict[str, float] = field(default_factory=dict)
    episodes: dict[tuple[int, str], tuple[float, int]] = field(default_factory=dict)
    expects: list[_Expect] = field(default_factory=list)
    takeovers: list[dict[str, Any]] = field(default_factory=list)
    false_takeovers: list[dict[str, Any]] = field(default_factory=list)
    last_fault_at: list[float] = field(default_factory=list)
    paused_until: dict[int, float] = field(default_factory=dict)
    false_suspicions: int = 0
    """`suspect` events about a healthy, reachable robot: loss, or a late machine."""
    started: set[int] = field(default_factory=set)
    """Robots whose node has logged `started` (since their last crash or restart)."""

    def __post_init__(self) -> None:
        self.bounds = Bounds.of(self.params, self.loss)

    @property
    def executing(self) -> dict[int, str]:
        """robot -> the function it executes, as its own events tell."""
        return self.holding.executing()

    # ------------------------------------------------------------------ inputs
    def fault(self, t: float, fault: Fault, phase: str) -> None:
        if phase == "begin":
            self.faults.append((t, fault))
            self.last_fault_at.append(t)
        if fault.kind == "partition":
            if phase == "begin":
                self.in_partition = True
                self.partitions.append((t, float("inf")))
            else:
                self.in_partition = False
                start, _ = self.partitions[-1]
                self.partitions[-1] = (start, t)
            return
        r = fault.robot
        if fault.kind in ("crash", "pause") and phase == "begin":
            self._close_watcher(r)  # a dead or frozen watcher's warnings end with it
        if fault.kind in _STOPPING_FAULTS and phase == "begin":
            f = self.executing.get(r)
            if fault.kind == "crash":
                self.dead.add(r)
                self.started.discard(r)
                self.holding.forget(r)
                self.paused.discard(r)
            else:
                self.unhealthy[r] = t
            if f is not None:
                self._expect_takeover(t, r, f, fault.kind)
        elif fault.kind == "restart" and phase == "begin":
            # A restart kills the process first (both simulators): the robot executes
            # nothing until its new node logs `started` (at once in --virtual, after a
            # process start in real time, during which the slot may be taken over).
            self._close_watcher(r)
            self.dead.discard(r)
            self.started.discard(r)
            self.holding.forget(r)
            self.paused.discard(r)
        elif fault.kind == "pause":
            if phase == "begin":
                self.paused.add(r)
                self.paused_until[r] = fault.end or t
                f = self.executing.get(r)
                if f is not None and (fault.duration or 0.0) > 2 * self.bounds.takeover:
                    self._expect_takeover(t, r, f, "pause")
            else:
                self.paused.discard(r)
        self._dual_update(t)

    def raised(self, t: float, robot: int, exc: BaseException) -> None:
        self.violations.append(Violation(t, "raised", robot,
                                         f"node raised {type(exc).__name__}: {exc}"))

    def robot_output(self, t: float, robot: int, action: object) -> None:
        """Assign/Release as the node produced them (virtual simulator). The event log
        carries the same facts; this hook exists for cross-checks in tests."""

    def event(self, rec: dict[str, Any]) -> None:
        t, r, name = float(rec["t"]), int(rec["robot"]), rec["event"]
        self.holding.feed(rec)
        if name == "takeover":
            f = rec["function"]
            for key in [k for k in self.episodes if k[1] == f]:
                del self.episodes[key]  # the warning ended in a takeover
            self._takeover(t, r, f, int(rec.get("replaced", 0)))
        elif name == "started":
            self.started.add(r)
        elif name == "suspect":
            if self._healthy_and_reachable(int(rec["subject"]), t):
                self.false_suspicions += 1
        elif name in ("fenced", "leave", "stopped"):
            self._close_watcher(r)
        elif name == "warn":
            key = (r, rec["function"])
            if key not in self.episodes:
                self.episodes[key] = (t, int(rec["subject"]))
        elif name in ("refute", "alert"):
            f = rec.get("function")
            if f is not None:
                self.episodes.pop((r, f), None)
                if name == "refute":
                    subject = rec.get("subject")
                    if subject == r:  # the suspect itself answered: its watchers' too
                        for key in [k for k, v in self.episodes.items()
                                    if k[1] == f and v[1] == r]:
                            self.episodes.pop(key, None)
        self._dual_update(t)

    # ------------------------------------------------------------------ rules
    def _close_watcher(self, r: int) -> None:
        for key in [k for k in self.episodes if k[0] == r]:
            del self.episodes[key]

    def _running(self) -> dict[int, str]:
        return {r: f for r, f in self.executing.items()
                if r not in self.dead and r not in self.paused}

    def _dual_update(self, t: float) -> None:
        by_function: dict[str, list[int]] = {}
        for r, f in self._running().items():
            by_function.setdefault(f, []).append(r)
        for f, robots in by_function.items():
            if len(robots) > 1:
                self.dual_since.setdefault(f, t)
            else:
                self._dual_end(f, t)
        for f in [f for f in self.dual_since if f not in by_function]:
            self._dual_end(f, t)

    def _dual_end(self, f: str, t: float) -> None:
        since = self.dual_since.pop(f, None)
        if since is not None:
            self._judge_dual(f, since, t)

    def _judge_dual(self, f: str, since: float, until: float) -> None:
        allowed = self.bounds.dual
        for start, heal in self.partitions:
            if start <= until and since <= heal + self.bounds.converge:
                allowed = max(allowed, heal + self.bounds.converge - since)
        if until - since > allowed:
            self.violations.append(Violation(
                since, "dual_execution", None,
                f"{f} executed by two robots for {until - since:.2f} s "
                f"(bound {allowed:.2f} s)"))

    def _expect_takeover(self, t: float, robot: int, f: str, kind: str) -> None:
        running = self._running()
        q = self.params.quorum
        watchers = {r for r, g in running.items() if g in self.plan.watched_by(f) and r != robot
                    and r not in self.unhealthy}
        standbys = [r for r in self.plan.covered_by(f)
                    if r != robot and r not in self.dead and r not in self.paused
                    and r not in running and r not in self.executing and r not in self.unhealthy]
        needs_watchers = kind in ("crash", "pause")  # leave / fault hand over by LEAVE
        if standbys and (len(watchers) >= q or not needs_watchers) and not self.in_partition:
            self.expects.append(_Expect(t, robot, f, kind, tuple(standbys)))

    def _takeover(self, t: float, r: int, f: str, replaced: int) -> None:
        rec = {"t": t, "robot": r, "function": f, "replaced": replaced}
        self.takeovers.append(rec)
        for e in list(self.expects):
            if e.function == f and t >= e.t:
                self.expects.remove(e)
        if not self._healthy_and_reachable(replaced, t):
            return
        self.false_takeovers.append(rec)
        liar = any(fl.kind == "liar" and ft <= t for ft, fl in self.faults)
        if not self.loss:
            what = "a liar got" if liar else "false takeover without loss:"
            self.violations.append(Violation(
                t, "false_takeover", r, f"{what} healthy robot {replaced} replaced on {f}"))

    def _healthy_and_reachable(self, robot: int, t: float) -> bool:
        if robot in self.dead or robot in self.unhealthy or robot in self.paused:
            return False
        if robot not in self.started:
            return False  # not (yet) running: to the swarm, a dead robot
        window = self.bounds.takeover + self.params.t_max
        for ft, fault in self.faults:
            if robot not in fault.robots and fault.kind != "partition":
                continue
            end = fault.end if fault.end is not None else float("inf")
            if fault.kind in ("crash", "leave", "unhealthy", "motor", "restart"):
                if ft <= t:
                    return False
            elif ft <= t <= end + window:
                return False
        return True

    # ------------------------------------------------------------------ end
    def finish(self, events: Iterable[dict[str, Any]], duration: float) -> list[Violation]:
        """Close the run at `duration` and return every violation, oldest first."""
        for f, since in list(self.dual_since.items()):
            self._judge_dual(f, since, duration)
        self.dual_since.clear()
        for e in self.expects:
            later_fault = any(e.t < ft <= e.t + self.bounds.takeover for ft in self.last_fault_at)
            if later_fault or duration - e.t < self.bounds.takeover:
                continue  # another fault interfered, or the run ended too soon to tell
            # A standby takes one slot: if every standby that could have come was taken
            # by another failure at about the same time, the slot is rightly left (and
            # alerted, rule 8) — two faults at once are beyond "whenever a live standby
            # covers it".
            busy = {tk["robot"] for tk in self.takeovers
                    if tk["function"] != e.function
                    and abs(tk["t"] - e.t) <= self.bounds.takeover}
            if e.standbys and set(e.standbys) <= busy:
                continue
            self.violations.append(Violation(
                e.t, "no_takeover", e.robot,
                f"{e.kind} of robot {e.robot} holding {e.function}: no takeover within "
                f"{self.bounds.takeover:.2f} s although a standby and a quorum of watchers "
                "were alive"))
        self.expects = []
        grace = self.params.alert_after + self.bounds.takeover
        for (w, f), (t, subject) in sorted(self.episodes.items(), key=lambda kv: kv[1][0]):
            if duration - t > grace:
                self.violations.append(Violation(
                    t, "warning_unresolved", w,
                    f"robot {w} warned about robot {subject} on {f}; no takeover, "
                    f"refutation or alert followed within {grace:.1f} s"))
        self.violations.sort(key=lambda v: v.t)
        return self.violations


def check_events(
    events: list[dict[str, Any]],
    faults: list[Fault],
    plan: SwarmPlan,
    params: Params,
    *,
    loss: float,
    duration: float,
) -> Checker:
    """Replay a finished run's events (e.g. the multi-process sim's merged log) and its
    faults through the checker; `.violations` and `.false_takeovers` hold the results."""
    checker = Checker(plan, params, loss=loss)
    timeline: list[tuple[float, int, Any]] = []
    for i, rec in enumerate(events):
        if rec.get("event") != "fault":
            timeline.append((float(rec["t"]), 1, (i, rec)))
    for i, fault in enumerate(faults):
        timeline.append((fault.at, 0, (i, fault, "begin")))
        if fault.end is not None:
            timeline.append((fault.end, 0, (i, fault, "end")))
    timeline.sort(key=lambda x: (x[0], x[1], x[2][0]))
    for t, kind, payload in timeline:
        if kind == 0:
            checker.fault(t, payload[1], payload[2])
        else:
            checker.event(payload[1])
    checker.finish(events, duration)
    return checker
