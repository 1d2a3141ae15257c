"""Invariants of a swarm run, checked from the event log.

The checker reads the same JSON Lines records users get (DESIGN section 3) plus the
injected faults, so the virtual simulator and the multi-process `swarmd sim` are judged
by one piece of code. What a robot executes is reconstructed from its events
(sim/shared/holders.py): `started{role: active}` and `takeover` start a function; `fenced`,
`leave`, `stopped`, a `started` as standby and a crash stop it; a paused robot executes
nothing until it resumes.

Invariants (each violation names the time, robot and what went wrong):
1. takeover: an ACTIVE robot that crashes (or collides, leaves, reports a fault, or stays
   paused long enough) is replaced within the takeover bound (`bounds.takeover`;
   `bounds.takeover_faded` once a link fault or a pause may have taught the watchers a
   longer patience, or while their links to the holder are not measured yet, DESIGN
   "Detection"), whatever else fails at the same time, whenever
   its slot keeps a live covering standby and (for a silent failure: crash, collide,
   pause) at least one live watcher. "Live" means not failed at any
   moment between the failure and the deadline. A robot back on the slot by the
   deadline answers the failure as a takeover does, unless it is fenced there by then:
   the plan's holder restarted without its state file, a holder that rejoined it, the
   paused holder itself. Not a violation:
   - every standby that could have come was consumed by another failure (it took over
     another slot by the deadline, or failed itself): a standby takes one slot, the
     other slot is rightly left to an alert (rule 8);
   - no watcher of the slot is live: the standby alone would be one robot's word, which
     never replaces a robot (rule 3);
   - a partition overlaps the window, the failed robot is restarted in it, or the run
     ends before the deadline.
   Another failure of a robot of the slot's neighbourhood (its watchers and covering
   standbys) within the window moves the deadline to one bound after it; a restart, to
   `bounds.takeover_restarted` after it (its new node never heard the failed holder and
   waits its start-up grace, DESIGN rule 5). A missed
   takeover is `no_takeover` when the failure came alone (a quorum of live watchers,
   no other failure in the neighbourhood) and `no_takeover_correlated` when other
   robots of the neighbourhood failed with it: the paper handles one failure at a time,
   and its quorum of two distinct witnesses cannot be met when a witness fails too;
2. single holder: outside partitions and link faults (`partition`, `fade`, `deaf`), no
   slot is executed by two running robots for longer than `bounds.dual`; after the
   fault heals, within `bounds.converge`. The channel can fade a link too: a directed
   link between two of the robots that lost every frame for `t_max` or longer (a loss
   burst, or a run of independent losses; the simulator reports it through `outage`)
   is judged as a fade of that link, since no protocol converges over a link that
   carries nothing, and `t_max` of silence is what the protocol itself calls gone;
3. liars: a takeover of a healthy, reachable robot is a false takeover; without loss it
   is a violation (a single liar can never get a healthy robot replaced), unless two
   liars or more were at work by then: two witnesses are a quorum, DESIGN's two-insider
   case, which the protocol does not claim to stop (counted, not judged). A robot is
   healthy only once its node has logged `started`: a process the machine could not
   start within the start-up grace is, to the swarm, a dead robot, and replacing it is
   the protocol working (the real-time summary warns about such a slow start);
4. warnings: every `warn` episode ends in a takeover of the slot, a refutation, or an
   alert (the paper's verified property, generalised); one about a holder a takeover
   had already replaced (it resumed that slot after a restart, say) ends when that
   holder stops holding it: fenced, crashed, restarted or gone;
5. no node raises on any input (virtual simulator: exceptions are reported here);
6. epochs come from takeovers: a robot fenced at an epoch that no takeover of its slot
   produced (`fenced_without_takeover`) was fenced by a forged or invented epoch, and
   its slot is orphaned (every robot now believes a holder that executes nothing); one
   epoch above a takeover or a claim is allowed: the reassertion of the holder it
   replaces, whose refute voided it (DESIGN "Convergence"); so is a claim's own epoch
   once two liars were at work, whose warnings certify it (the two-insider case of
   invariant 3: the claim fences the holder, and if its claimant gives it up the slot
   waits for its watchers to suspect that claimant);
7. nobody is muted (`muted`, virtual simulator: `VirtualSwarm` judges it from the
   nodes, see `sim.virtual.simulator`): a live, healthy robot whose current frames some
   robot that should hear them has not accepted for ten heartbeat periods;
8. one answer everywhere (virtual simulator, judged from the nodes at the end of a run
   that ended `Bounds.settle` or more after its last fault; DESIGN, "Convergence"):
   every live robot that hears a slot holds the same (holder, epoch) for it
   (`views_disagree`), and a live, healthy holder they all name executes it
   (`orphaned`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from sim.shared.faults import LINK_KINDS, Fault, FaultKind
from sim.shared.holders import HolderFold
from swarmd.core.actions import Assign, Release
from swarmd.core.events import Fault as EventFault
from swarmd.core.events import name_of
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.proofs import RELAY_EVERY

_STOPPING_FAULTS = (FaultKind.CRASH, FaultKind.COLLIDE, FaultKind.LEAVE, FaultKind.UNHEALTHY,
                    FaultKind.MOTOR)
_SILENT = (FaultKind.CRASH, FaultKind.COLLIDE, FaultKind.PAUSE)
"""Failures the swarm learns of only from silence (the others hand over by LEAVE)."""


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
    settle: float
    """After the last fault, by when every view of every slot is one (invariant 8): a
    takeover, then the holders' unasked certificate relay (`RELAY_EVERY` T_max)."""
    takeover_faded: float = 0.0
    """The takeover bound for a failure after a link fault or a pause, or on links not
    measured yet: the watchers may have measured that silence as a fade of the link, or
    not measured the link enough to act on it, and wait up to `t_max_bursty`."""
    takeover_restarted: float = 0.0
    """The takeover bound counted from the restart of a robot of the failed slot's
    neighbourhood, after the failure: its new node never heard the failed holder, so as
    a watcher it warns after its start-up grace (DESIGN rule 5), and as a standby it
    counts its own ears only after it (rule 9)."""

    @classmethod
    def of(cls, p: Params, loss: float) -> Bounds:
        # Crash -> every watcher suspects within its patience for the link (DESIGN
        # "Detection": t_max on a clean link, up to t_max_bursty on one its belief
        # measured losing heartbeats in bursts); two warnings reach the standby within
        # the vote window; then claim_hold. Loss also delays the warnings, which repeat
        # every warn_interval: allow two more vote windows under loss.
        takeover = p.takeover_bound(lossy=bool(loss))
        faded = p.takeover_bound(lossy=bool(loss), patience=p.t_max_bursty)
        # A stale holder heartbeats on resume; the new holder answers at once (rule 2).
        dual = p.t_max + 2 * p.heartbeat_interval + (p.t_max if loss else 0.0)
        converge = 2 * p.t_max + 2 * p.heartbeat_interval + (p.t_max if loss else 0.0)
        settle = faded + converge + RELAY_EVERY * p.t_max
        restarted = faded - p.t_max_bursty + max(p.t_max_bursty, p.startup_grace)
        return cls(takeover, dual, converge, settle, faded, restarted)


@dataclass(frozen=True, slots=True)
class _Failure:
    """An injected failure of one robot: crash, collide, leave, unhealthy and motor never
    end; a pause ends when it is over; a restart is a crash at that instant."""

    start: float
    end: float
    robot: int
    kind: str
    function: str | None
    """What the robot executed when it failed (None: a standby)."""


@dataclass(slots=True)
class _Expect:
    t: float
    robot: int
    function: str
    kind: str
    standbys: tuple[int, ...] = ()
    """Covering standbys alive and idle when the holder failed (judged again at the end:
    one may fail at the same instant, or be consumed by another slot)."""
    watchers: tuple[int, ...] = ()
    """Robots executing a slot that watches `function`, alive at the failure."""
    done: float | None = None
    """When the slot was taken over (judged at the end: a late takeover is a miss)."""
    backs: list[tuple[float, int]] = field(default_factory=list)
    """(when, robot): a robot back on the slot without a takeover (the plan's holder
    restarted without its state file, a holder that rejoined it or came back from its
    pause); it answers the failure if it is not fenced on the slot before the deadline."""


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
    _open_links: dict[str, int] = field(default_factory=dict)
    """SPEC of a link fault in force -> its index in `partitions`."""
    dual_since: dict[str, float] = field(default_factory=dict)
    dual_robots: dict[str, set[int]] = field(default_factory=dict)
    """function -> every robot that executed it during its current dual episode."""
    outages: list[tuple[int, int, float, float]] = field(default_factory=list)
    """(sender, receiver, start, heal) of a link the channel faded (`outage`)."""
    duals: list[tuple[str, float, float, set[int]]] = field(default_factory=list)
    """Ended dual episodes (function, since, until, robots), judged at `finish`: an
    outage is known only once its link heals, which may come after the episode ended."""
    episodes: dict[tuple[int, str], tuple[float, int]] = field(default_factory=dict)
    held_since: dict[tuple[str, int], float] = field(default_factory=dict)
    """(function, robot) -> when the robot last began to execute the function."""
    replaced_at: dict[tuple[str, int], float] = field(default_factory=dict)
    """(function, robot) -> when a takeover last replaced the robot on the function, or
    the robot was fenced on it (a greater entry outranked its hold)."""
    superseded: set[tuple[str, int]] = field(default_factory=set)
    """(function, robot): the robot resumed the function (a restart on its state file)
    after a takeover had replaced it there, so it holds an entry already outranked; its
    own new takeover of the function ends that."""
    expects: list[_Expect] = field(default_factory=list)
    takeovers: list[dict[str, Any]] = field(default_factory=list)
    false_takeovers: list[dict[str, Any]] = field(default_factory=list)
    last_fault_at: list[float] = field(default_factory=list)
    failures: list[_Failure] = field(default_factory=list)
    """Every injected failure of one robot, in time order."""
    paused_until: dict[int, float] = field(default_factory=dict)
    faded_at: float | None = None
    """When the first link fault or pause began: from then on a watcher's belief may
    have learnt a long silence as a fade, and `Bounds.takeover_faded` holds."""
    false_suspicions: int = 0
    """`suspect` events about a healthy, reachable robot: loss, or a late machine."""
    started: set[int] = field(default_factory=set)
    """Robots whose node has logged `started` (since their last crash or restart)."""
    started_at: dict[int, list[float]] = field(default_factory=dict)
    """robot -> the times its node logged `started`, and the times it was restarted (its
    node listens from then on, before a rejoin's `started`)."""
    fenced_on: dict[tuple[str, int], list[float]] = field(default_factory=dict)
    """(function, robot) -> the times the robot was fenced on it (invariant 1: a robot
    back on a slot answers its failure only if it stays)."""
    epochs: set[tuple[str, int]] = field(default_factory=set)
    """(function, epoch) pairs some takeover produced (invariant 6)."""
    claimed: set[tuple[str, int]] = field(default_factory=set)
    """(function, epoch) pairs some claim named (invariant 6: a reassertion outranks
    a claim refuted in its wait state as well as a takeover)."""
    released: dict[int, str] = field(default_factory=dict)
    """robot -> the slot it still holds by its events but was told to release, with no
    event: its hold paused while a frame held at its start that would fence it waits to
    be judged (DESIGN "Every proof is bound to its run"). The robot link's `Release`
    and `Assign` say what a robot executes; the log shows only role changes, so only
    the virtual simulator, which hands the checker both, sees the pause."""

    def __post_init__(self) -> None:
        self.bounds = Bounds.of(self.params, self.loss)

    @property
    def executing(self) -> dict[int, str]:
        """robot -> the function it executes, as its own events tell."""
        return self.holding.executing()

    # ------------------------------------------------------------------ inputs
    def fault(self, t: float, fault: Fault, phase: str) -> None:
        parts = fault.split()
        if len(parts) > 1:  # several robots at one instant: one fault each
            for part in parts:
                self.fault(t, part, phase)
            return
        if phase == "begin":
            self.faults.append((t, fault))
            self.last_fault_at.append(t)
            if self.faded_at is None and (fault.kind in LINK_KINDS
                                          or fault.kind is FaultKind.PAUSE):
                self.faded_at = t
            if fault.kind in (*_STOPPING_FAULTS, FaultKind.PAUSE, FaultKind.RESTART):
                end = fault.end if fault.kind is FaultKind.PAUSE \
                    else t if fault.kind is FaultKind.RESTART else float("inf")
                self.failures.append(_Failure(t, end if end is not None else t, fault.robot,
                                              fault.kind, self.executing.get(fault.robot)))
        if fault.kind in LINK_KINDS:
            self._link_fault(t, fault, phase)
            return
        self._robot_fault(t, fault, phase)
        self._dual_update(t)

    def _link_fault(self, t: float, fault: Fault, phase: str) -> None:
        """Partitions and one-way link faults (fade, deaf) may overlap: each is a window
        after whose heal the swarm must converge (invariant 2)."""
        key = fault.spec()
        if phase == "begin":
            self._open_links[key] = len(self.partitions)
            self.partitions.append((t, float("inf")))
        elif (i := self._open_links.pop(key, None)) is not None:
            self.partitions[i] = (self.partitions[i][0], t)
        self.in_partition = bool(self._open_links)

    def _robot_fault(self, t: float, fault: Fault, phase: str) -> None:
        """What a fault on one robot changes of what the checker expects."""
        r = fault.robot
        if phase == "begin" and fault.kind in (*_STOPPING_FAULTS, FaultKind.RESTART):
            self._superseded_ends(r)
        if fault.kind in _SILENT and phase == "begin":
            self._close_watcher(r)  # a dead or frozen watcher's warnings end with it
        if fault.kind in _STOPPING_FAULTS and phase == "begin":
            f = self.executing.get(r)
            # A collision is judged as a crash: with physics the daemon lives on and
            # hands over by LEAVE, which needs less than a crash does (no watchers).
            if fault.kind in (FaultKind.CRASH, FaultKind.COLLIDE):
                self.dead.add(r)
                self.started.discard(r)
                self.holding.forget(r)
                self.released.pop(r, None)
                self.paused.discard(r)
            else:
                self.unhealthy[r] = t
            if f is not None:
                self._expect_takeover(t, r, f, fault.kind)
        elif fault.kind is FaultKind.RESTART and phase == "begin":
            # A restart kills the process first (both simulators): the robot executes
            # nothing until its new node logs `started` (at once in --virtual, after a
            # process start in real time, during which the slot may be taken over). Its
            # links are new from here on (`_measuring`), also while it rejoins its hold,
            # which logs `started` only at the hold's end.
            self.started_at.setdefault(r, []).append(t)
            self._close_watcher(r)
            self.dead.discard(r)
            self.started.discard(r)
            self.holding.forget(r)
            self.released.pop(r, None)
            self.paused.discard(r)
        elif fault.kind is FaultKind.PAUSE:
            if phase == "begin":
                self.paused.add(r)
                self.paused_until[r] = fault.end or t
                f = self.executing.get(r)
                if f is not None and (fault.duration or 0.0) > 2 * self.bounds.takeover:
                    self._expect_takeover(t, r, f, FaultKind.PAUSE)
            else:
                self.paused.discard(r)
                f = self.executing.get(r)
                if f is not None:
                    self._back_on(t, r, f)  # the holder itself, back from its pause

    def raised(self, t: float, robot: int, exc: BaseException) -> None:
        self.violations.append(Violation(t, "raised", robot,
                                         f"node raised {type(exc).__name__}: {exc}"))

    def robot_output(self, t: float, robot: int, action: object) -> None:
        """Assign/Release as the node produced them (virtual simulator). The log carries
        the same facts, but for a paused hold (`released`): a `Release` of the slot the
        robot's events say it executes stops it there, the next `Assign` starts it again."""
        match action:
            case Release(function=f) if self.executing.get(robot) == f:
                self.released[robot] = f
            case Assign():
                self.released.pop(robot, None)
            case _:
                return
        self._dual_update(t)

    def event(self, rec: dict[str, Any]) -> None:
        t = float(rec["t"])
        r = int(rec["robot"])
        name = name_of(rec)
        if self.holding.feed(rec) is not None:
            self.released.pop(r, None)  # a role change: the log tells it from here
        if name == "fenced":
            self._fenced(t, r, rec)
        if name == "takeover":
            self._on_takeover(t, r, rec)
        elif name == "claim":
            self.claimed.add((str(rec["function"]), int(rec["epoch"])))
        elif name == "started":
            self.started.add(r)
            self.started_at.setdefault(r, []).append(t)
            if rec.get("function") is not None:
                key = (str(rec["function"]), r)
                if self.replaced_at.get(key, -1.0) > self.held_since.get(key, -1.0):
                    self.superseded.add(key)
                self.held_since[key] = t
                # A robot back on the slot: its plan holder restarted without its state
                # file, or a holder that rejoined it.
                self._back_on(t, r, key[0])
        elif name == "suspect":
            if self._healthy_and_reachable(int(rec["subject"]), t):
                self.false_suspicions += 1
        elif name in ("fenced", "leave", "stopped"):
            self._close_watcher(r)
            self._superseded_ends(r)
        elif name == "warn":
            self._on_warn(t, r, rec)
        elif name in ("refute", "alert"):
            self._on_answer(r, name, rec)
        self._dual_update(t)

    def _fenced(self, t: float, r: int, rec: dict[str, Any]) -> None:
        """A robot fenced on an epoch no takeover produced: a forged epoch. A fence
        that a takeover did produce answers the warnings about the fenced robot on that
        slot: its watchers learn the newer holder (rule 2), whose takeover may have come
        before the warning (the suspect resumed the slot after a restart, say)."""
        f = rec["function"]
        epoch = int(rec["epoch"])
        for key in [k for k, v in self.episodes.items() if k[1] == f and v[1] == r]:
            del self.episodes[key]
        self.replaced_at[(f, r)] = t
        self.fenced_on.setdefault((f, r), []).append(t)
        if epoch and (f, epoch) not in self.epochs and (f, epoch - 1) not in self.epochs \
                and (f, epoch - 1) not in self.claimed \
                and not ((f, epoch) in self.claimed and len(self._liars_by(t)) > 1):
            # (One epoch above a takeover, or above a claim, is the reassertion of the
            # holder it would replace, whose refute voided it, DESIGN "Convergence";
            # robots other than that holder may derive it, and be fenced by it, before
            # the holder logs its `refute`. A claim's own epoch, certified by two
            # liars' warnings, is DESIGN's two-insider case, excused as invariant 3
            # excuses their false takeover: their quorum is as good as a real one, and
            # the slot, its claimant given up, is taken over again once its watchers
            # suspect that claimant. Any other epoch no takeover made is forged.)
            self.violations.append(Violation(
                t, "fenced_without_takeover", r,
                f"robot {r} fenced on {f} at epoch {epoch}, which no takeover produced: "
                f"a forged epoch; {f} is orphaned"))

    def _on_takeover(self, t: float, r: int, rec: dict[str, Any]) -> None:
        f = rec["function"]
        self.epochs.add((f, int(rec["epoch"])))
        for key in [k for k in self.episodes if k[1] == f]:
            del self.episodes[key]  # the warning ended in a takeover
        self.held_since[(f, r)] = t
        self.superseded.discard((f, r))
        self.replaced_at[(f, int(rec.get("replaced", 0)))] = t
        self._takeover(t, r, f, int(rec.get("replaced", 0)))

    def _on_warn(self, t: float, r: int, rec: dict[str, Any]) -> None:
        """A warning opens an episode, unless one is open or its subject is replaced."""
        key = (r, rec["function"])
        about = (str(rec["function"]), int(rec["subject"]))
        if self.replaced_at.get(about, -1.0) > self.held_since.get(about, -1.0):
            # About a holder already replaced or fenced: this watcher had not heard the
            # greater entry yet (a partition, loss, a start-up that cannot judge its proof
            # yet); the entry it missed resolves the warning, and invariant 8 holds its
            # view to it.
            pass
        elif key not in self.episodes:
            self.episodes[key] = (t, int(rec["subject"]))

    def _on_answer(self, r: int, name: str, rec: dict[str, Any]) -> None:
        """A refute or an alert closes the robot's warning episode on its function."""
        f = rec.get("function")
        if f is not None:
            self.episodes.pop((r, f), None)
            if name == "refute":
                subject = rec.get("subject")
                if subject == r:  # the suspect itself answered: its watchers' too
                    for key in [k for k, v in self.episodes.items()
                                if k[1] == f and v[1] == r]:
                        self.episodes.pop(key, None)

    def outage(self, sender: int, receiver: int, start: float, heal: float) -> None:
        """The channel lost every frame from `sender` to `receiver` in [start, heal)."""
        self.outages.append((sender, receiver, start, heal))

    # ------------------------------------------------------------------ rules
    def _close_watcher(self, r: int) -> None:
        for key in [k for k in self.episodes if k[0] == r]:
            del self.episodes[key]

    def _superseded_ends(self, r: int) -> None:
        """Robot r stops holding what it resumed after being replaced (it is fenced,
        crashes, restarts or leaves): the warnings about it there are answered by the
        takeover that replaced it, which their watchers had missed (they learn that
        entry, and invariant 8 holds their views to it), as a fence answers them."""
        for f, robot in [k for k in self.superseded if k[1] == r]:
            self.superseded.discard((f, robot))
            # What it held is gone: a later warning about it there is about a replaced
            # holder too (`_on_warn`).
            self.held_since.pop((f, robot), None)
            for key in [k for k, v in self.episodes.items() if k[1] == f and v[1] == r]:
                del self.episodes[key]

    def _running(self) -> dict[int, str]:
        return {r: f for r, f in self.executing.items()
                if r not in self.dead and r not in self.paused and r not in self.released}

    def _dual_update(self, t: float) -> None:
        by_function: dict[str, list[int]] = {}
        for r, f in self._running().items():
            by_function.setdefault(f, []).append(r)
        for f, robots in by_function.items():
            if len(robots) > 1:
                self.dual_since.setdefault(f, t)
                self.dual_robots.setdefault(f, set()).update(robots)
            else:
                self._dual_end(f, t)
        for f in [f for f in self.dual_since if f not in by_function]:
            self._dual_end(f, t)

    def _dual_end(self, f: str, t: float) -> None:
        since = self.dual_since.pop(f, None)
        robots = self.dual_robots.pop(f, set())
        if since is not None:
            self.duals.append((f, since, t, robots))

    def _judge_dual(self, f: str, since: float, until: float, robots: set[int]) -> None:
        allowed = self.bounds.dual
        faded = [(start, heal) for a, b, start, heal in self.outages
                 if a in robots and b in robots]
        for start, heal in self.partitions + faded:
            if start <= until and since <= heal + self.bounds.converge:
                allowed = max(allowed, heal + self.bounds.converge - since)
        if until - since > allowed:
            self.violations.append(Violation(
                since, "dual_execution", None,
                f"{f} executed by two robots for {until - since:.2f} s "
                f"(bound {allowed:.2f} s)"))

    def _expect_takeover(self, t: float, robot: int, f: str, kind: str) -> None:
        running = self._running()
        watchers = sorted(r for r, g in running.items() if g in self.plan.watched_by(f)
                          and r != robot and r not in self.unhealthy)
        standbys = [r for r in self.plan.covered_by(f)
                    if r != robot and r not in self.dead and r not in self.paused
                    and r not in running and r not in self.executing and r not in self.unhealthy]
        if any(g == f and r != robot for r, g in running.items()):
            return  # already taken over (e.g. while the robot was paused)
        if standbys and not self.in_partition:
            self.expects.append(_Expect(t, robot, f, kind, tuple(standbys), tuple(watchers)))

    def _takeover(self, t: float, r: int, f: str, replaced: int) -> None:
        rec = {"t": t, "robot": r, "function": f, "replaced": replaced}
        self.takeovers.append(rec)
        for e in self.expects:
            if e.function == f and t >= e.t and e.done is None:
                e.done = t
        if replaced == r or not self._healthy_and_reachable(replaced, t):
            return  # (a robot taking back its own slot, which it had left, replaces nobody)
        self.false_takeovers.append(rec)
        liars = self._liars_by(t)
        if len(liars) > 1:
            return  # two insiders' warnings: a quorum (rule 3 above)
        liar = bool(liars)
        if not self.loss:
            what = "a liar got" if liar else "false takeover without loss:"
            self.violations.append(Violation(
                t, "false_takeover", r, f"{what} healthy robot {replaced} replaced on {f}"))

    def _back_on(self, t: float, r: int, f: str) -> None:
        """Robot r executes f again from `t` without a takeover: a candidate answer to
        the failures of f not answered yet (invariant 1; `_Expect.backs`)."""
        for e in self.expects:
            if e.function == f and t >= e.t and e.done is None:
                e.backs.append((t, r))

    def _liars_by(self, t: float) -> set[int]:
        """The robots lying (a `liar` fault) at `t` or before."""
        return {fl.robot for ft, fl in self.faults if fl.kind is FaultKind.LIAR and ft <= t}

    def _healthy_and_reachable(self, robot: int, t: float) -> bool:
        if robot in self.dead or robot in self.unhealthy or robot in self.paused:
            return False
        if robot not in self.started:
            return False  # not (yet) running: to the swarm, a dead robot
        window = self.bounds.takeover + self.params.t_max
        for ft, fault in self.faults:
            if robot not in fault.robots and fault.kind not in LINK_KINDS:
                continue
            end = fault.end if fault.end is not None else float("inf")
            if fault.kind in (FaultKind.CRASH, FaultKind.LEAVE, FaultKind.UNHEALTHY,
                              FaultKind.MOTOR, FaultKind.RESTART):
                if ft <= t:
                    return False
            elif ft <= t <= end + window:
                return False
        return True

    # ------------------------------------------------------------------ takeover judged
    def _failed_in(self, robot: int, start: float, end: float) -> bool:
        """Whether `robot` failed (or was down) at some moment of [start, end]."""
        return any(x.robot == robot and x.start <= end and x.end >= start
                   for x in self.failures)

    def _judge_expect(self, e: _Expect, duration: float) -> Violation | None:
        """Invariant 1 for one failure whose slot was not taken over (see the module
        docstring): the violation, or None when the miss is excused."""
        bound = self._takeover_bound(e)
        near = set(self.plan.watched_by(e.function))
        hood = {*self.plan.covered_by(e.function), *e.standbys, *e.watchers}
        mates = [x for x in self.failures if x.robot != e.robot
                 and (x.robot in hood or x.function in near)]
        deadline = self._expect_deadline(e, mates)
        if self._excused(e, deadline, duration):
            return None
        watchers = [w for w in e.watchers if not self._failed_in(w, e.t, deadline)]
        silent = e.kind in _SILENT
        if silent and not watchers:
            return None  # nobody left to witness: the standby alone is one word (rule 3)
        consumed = {tk["robot"] for tk in self.takeovers
                    if tk["function"] != e.function and e.t - bound <= tk["t"] <= deadline}
        live = [r for r in e.standbys
                if r not in consumed and not self._failed_in(r, e.t, deadline)]
        if not live:
            return None  # every standby that could come took another slot or failed
        others = sorted({x.robot for x in mates if e.t - bound <= x.start <= deadline})
        alone = not others and (not silent or len(watchers) >= self.params.quorum)
        with_ = f" with robot(s) {', '.join(map(str, others))} failing" if others else ""
        return Violation(
            e.t, "no_takeover" if alone else "no_takeover_correlated", e.robot,
            f"{e.kind} of robot {e.robot} holding {e.function}{with_}: "
            f"{'no takeover' if e.done is None else f'taken over only at {e.done:.2f} s'} by "
            f"{deadline:.2f} s although standby(s) {', '.join(map(str, live))} and "
            f"watcher(s) {', '.join(map(str, watchers)) or 'none needed'} stayed alive")

    def _expect_deadline(self, e: _Expect, mates: list[_Failure]) -> float:
        """By when the failure's slot must be taken over: the takeover bound, restarted
        by each failure in its neighbourhood and stretched by a standby's grace."""
        bound = self._takeover_bound(e)
        deadline = e.t + bound
        moved = True
        while moved:  # each failure in the neighbourhood restarts the clock
            moved = False
            for x in mates:
                again = max(bound, self.bounds.takeover_restarted) \
                    if x.kind is FaultKind.RESTART else bound
                if e.t < x.start <= deadline < x.start + again:
                    deadline = x.start + again
                    moved = True
        # A covering standby that (re)started shortly before the failure still waits out
        # its start-up grace (DESIGN rule 5) before it may count silence: give it that.
        grace = self.params.startup_grace
        for r in e.standbys:
            before = [s for s in self.started_at.get(r, ()) if s <= e.t]
            if before and before[-1] > 0.5 and e.t - before[-1] < grace:
                deadline = max(deadline, before[-1] + grace + bound)
        return deadline

    def _takeover_bound(self, e: _Expect) -> float:
        """The takeover bound for a failure (DESIGN "Detection": a function of the links
        as measured): the configured one, unless a link fault or a pause came before,
        which the watchers may have learnt as a fade, or the links that judge it were
        not measured yet (`_measuring`): then their patience may be `t_max_bursty`."""
        if (self.faded_at is not None and self.faded_at < e.t) or self._measuring(e):
            return self.bounds.takeover_faded
        return self.bounds.takeover

    def _measuring(self, e: _Expect) -> bool:
        """Were the failed holder's links to its watchers and standbys heard for less
        than a start-up grace when it failed? A link is acted on only once heard for a
        start-up grace's worth of heartbeats (`witness.Ears.patience`): from the start of
        the run, of the holder's hold (a takeover), or of a watcher's or standby's node
        (a restart); `t_max` more for its first heartbeat to be heard. A watcher
        restarted on its hold rejoins it (`rejoin_hold`) before it watches again: not
        among the failure's watchers yet, it judges the holder on a new link all the
        same."""
        since = [s for r in (e.robot, *e.watchers, *e.standbys)
                 for s in self.started_at.get(r, ()) if s <= e.t]
        near = set(self.plan.watched_by(e.function))
        since += [x.start for x in self.failures if x.kind is FaultKind.RESTART
                  and x.function in near and x.start <= e.t]
        since += [tk["t"] for tk in self.takeovers
                  if tk["robot"] == e.robot and tk["function"] == e.function
                  and tk["t"] <= e.t]
        settled = self.params.startup_grace + self.params.t_max
        return bool(since) and e.t < max(since) + settled

    def _excused(self, e: _Expect, deadline: float, duration: float) -> bool:
        """Whether the slot was taken over in time, or the miss is no violation."""
        if e.done is not None and e.done <= deadline:
            return True
        for t, r in e.backs:
            fences = self.fenced_on.get((e.function, r), ())
            if t <= deadline and not any(t <= tf <= deadline for tf in fences):
                return True  # a robot back on the slot executes it (not fenced by then)
        if duration < deadline:
            return True  # the run ended too soon to tell
        if any(s <= deadline and h >= e.t for s, h in self.partitions):
            return True  # a partition is another kind of trouble (invariant 2)
        # The robot is back and may take its slot back (rule 2).
        return any(fl.kind is FaultKind.RESTART and e.robot in fl.robots
                   and e.t < ft <= deadline for ft, fl in self.faults)

    # ------------------------------------------------------------------ end
    def finish(self, events: Iterable[dict[str, Any]], duration: float) -> list[Violation]:
        """Close the run at `duration` and return every violation, oldest first."""
        for f, since in list(self.dual_since.items()):
            self.duals.append((f, since, duration, self.dual_robots.get(f, set())))
        for dual in self.duals:
            self._judge_dual(*dual)
        self.duals = []
        self.dual_since.clear()
        self.dual_robots.clear()
        for e in self.expects:
            v = self._judge_expect(e, duration)
            if v is not None:
                self.violations.append(v)
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
        if name_of(rec) != EventFault.name:
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
