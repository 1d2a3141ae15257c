"""Virtual-time swarm simulator: N protocol cores on one clock.

Every robot is a `swarmd.core.node.Node`, the same object the daemon drives; only time
and the channel are simulated. The channel is a broadcast medium with per-receiver
loss, delay and jitter (which reorders), duplication and partitions, all drawn from one
seeded `random.Random`: a run is a pure function of (plan, params, faults, seed).

Speed: a broadcast is encoded by the sender's node and decoded once here, then handed
to each receiver with `Node.receive_frame`. With `interest=True` a frame reaches only
the robots whose plan makes it relevant (`SwarmPlan.relevant`, the sets a `Node` drops
irrelevant frames by before verifying them): everything else the receiver would drop.
`tests/test_scenarios.py` checks that this changes no outcome.
"""

from __future__ import annotations

import collections
import heapq
import itertools
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, assert_never

from sim.shared.channel import LOSS_MODELS, GilbertElliott, LinkCut
from sim.shared.fakeid import fake_identities
from sim.shared.faults import Fault, FaultKind, fault_record
from sim.shared.forge import CAPTURE, REPEATING, forged_frames
from sim.shared.invariants import Checker, Violation
from sim.shared.liar import liar_warnings
from sim.virtual.agenda import (
    Boot,
    Deliver,
    DeliverRaw,
    Entry,
    FaultPhase,
    Forge,
    Input,
    Lie,
    Report,
    Say,
    Stop,
    Tick,
)
from sim.virtual.judge import muted, views
from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Broadcast, Release
from swarmd.core.auth import Identity
from swarmd.core.events import Event, name_of
from swarmd.core.node import Node, Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Health, Role

AUTH_MODES = ("none", "shared", "per-robot")
"""`none`: unsigned; `shared`: one swarm key (HMAC); `per-robot`: each robot its own
key for WARN, CLAIM and LEAVE, the swarm key on heartbeats (DESIGN section 2)."""


@dataclass(frozen=True, slots=True)
class Channel:
    """The simulated medium. Loss is drawn per receiver (a broadcast heard by some)."""

    loss: float = 0.0
    delay: float = 0.002  # s, one-way latency
    jitter: float = 0.002  # s, uniform extra delay: reorders frames closer than this
    duplicate: float = 0.0  # probability that a delivery happens twice
    loss_model: str = "bernoulli"
    """`bernoulli` (each frame lost with `loss`, independently) or `burst` (Gilbert-Elliott
    per directed link, sim/shared/channel.py)."""
    burst_len: float = 4.0
    """Mean frames of a loss burst (`burst` model)."""


@dataclass(slots=True)
class VirtualResult:
    events: list[dict[str, Any]]
    violations: list[Violation]
    duration: float
    frames_sent: int
    deliveries: int
    robot_seconds: float
    drops: dict[int, dict[str, int]] = field(default_factory=dict)
    final: dict[int, tuple[str, str | None, int]] = field(default_factory=dict)
    """robot -> (role, function, epoch) at the end, for alive robots."""

    def holders(self) -> dict[str, list[int]]:
        """function -> robots executing it at the end (alive, ACTIVE)."""
        out: dict[str, list[int]] = {}
        for r, (role, f, _) in sorted(self.final.items()):
            if role == "active" and f is not None:
                out.setdefault(f, []).append(r)
        return out


@dataclass(slots=True)
class _Robot:
    node: Node | None
    alive: bool = True
    paused: bool = False
    buffered: list[wire.Frame] = field(default_factory=list)
    timer_gen: int = 0
    timer_at: float | None = None
    persisted: Restored | None = None
    seq_high: int = 0
    dropped: collections.Counter[str] = field(default_factory=collections.Counter)
    """Drops of this robot's earlier nodes (before a crash or a leave)."""


class VirtualSwarm:
    """Run a swarm on virtual time. `run()` returns events, violations and figures."""

    def __init__(
        self,
        plan: SwarmPlan,
        params: Params,
        *,
        duration: float,
        faults: Sequence[Fault] = (),
        channel: Channel | None = None,
        seed: int = 0,
        keys: Sequence[bytes] = (),
        auth: str = "none",
        identities: dict[int, Identity] | None = None,
        interest: bool = True,
        start_spread: float = 0.05,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ) -> None:
        self.plan = plan
        self.params = params
        self.duration = duration
        # A fault on several robots is one fault a robot at the same instant.
        self.faults = sorted((part for f in faults for part in f.split()), key=lambda f: f.at)
        self.channel = channel or Channel()
        self.rng = random.Random(seed)
        self._init_auth(auth, keys, identities, seed)
        self.on_event = on_event
        self.now = 0.0
        self._heap: list[tuple[float, int, Entry]] = []
        self._counter = itertools.count()
        self.events: list[dict[str, Any]] = []
        self.frames_sent = 0
        self.deliveries = 0
        self._init_links()
        self._changed: dict[int, float] = {}
        self.checker = Checker(plan, params, loss=self.channel.loss)
        self.robots: dict[int, _Robot] = {}
        self._relevant_to = self._interest()
        self._receivers = self._relevant_to if interest else None
        self._all = tuple(sorted(plan.robots))
        self._init_recorders()
        self._schedule(start_spread)

    # ------------------------------------------------------------------ set-up
    def _init_auth(self, auth: str, keys: Sequence[bytes],
                   identities: dict[int, Identity] | None, seed: int) -> None:
        """The run's keys, authentication mode, identities and verifier."""
        if auth not in AUTH_MODES:
            raise ValueError(f"auth must be one of {', '.join(AUTH_MODES)}, not {auth!r}")
        if auth != "none" and not keys:
            keys = (bytes(range(32)),)  # a throwaway swarm key for this run
        self.keys = tuple(keys) if auth != "none" or keys else ()
        self.auth = "shared" if auth == "none" and self.keys else auth
        # Per-robot mode: throwaway identities (`sim.shared.fakeid`) unless given.
        self.identities: dict[int, Identity] = {}
        if self.auth == "per-robot":
            self.identities = identities if identities is not None else \
                fake_identities(self.plan.robots, seed)
        self.verifier = self.identities[min(self.identities)].verifier \
            if self.identities else None

    def _init_links(self) -> None:
        """The link faults in force and the channel's losses, per link."""
        self.partition: dict[int, int] | None = None  # robot -> group while partitioned
        self.cuts: list[LinkCut] = []  # one-way link faults in force (fade, deaf, A>B)
        self.cuts_seen: list[LinkCut] = []
        self._losing: dict[tuple[int, int], tuple[float, float]] = {}
        """(sender, receiver) -> the first and last frame the channel lost in the link's
        current run of losses: a run spanning `t_max` or more is an outage to the checker."""
        self._arrived: dict[tuple[int, int], float] = {}
        """(sender, receiver) -> when the latest frame the channel carried on that link
        reached the receiver (`last_arrival`)."""
        if self.channel.loss_model not in LOSS_MODELS:
            raise ValueError(f"loss model must be one of {', '.join(LOSS_MODELS)}")
        self._burst = GilbertElliott(self.channel.loss, self.channel.burst_len, self.rng) \
            if self.channel.loss_model == "burst" else None

    def _init_recorders(self) -> None:
        # `forge:R@T:replay`: R's radio records the channel until T (`sim.shared.forge`).
        self._recording: dict[int, collections.deque[bytes]] = {
            r: collections.deque(maxlen=CAPTURE) for f in self.faults
            if f.kind is FaultKind.FORGE and f.attack == "replay" for r in f.robots}
        self._tapes: dict[int, tuple[bytes, ...]] = {}

    def _schedule(self, start_spread: float) -> None:
        """Each robot's boot at a spread time, then each fault's begin and end."""
        for rid in self._all:
            start = self.rng.uniform(0.0, start_spread)
            self.robots[rid] = _Robot(node=None)
            self._push(start, Boot(rid))  # at a spread time
        for i, fault in enumerate(self.faults):
            self._push(fault.at, FaultPhase(i, "begin"))
            if fault.end is not None:
                self._push(fault.end, FaultPhase(i, "end"))

    def _interest(self) -> dict[int, tuple[int, ...]]:
        """slot -> robots to which a frame about it matters, from `SwarmPlan.relevant`
        (the same sets `Node` drops irrelevant frames by); standby heartbeats go by
        sender (`_standby_targets`)."""
        plan = self.plan
        by_slot: dict[int, list[int]] = {}
        by_standby: dict[int, list[int]] = {}
        for rid in sorted(plan.robots):
            rel = plan.relevant(rid)
            for slot in rel.slots:
                by_slot.setdefault(slot, []).append(rid)
            for sb in rel.standbys:
                by_standby.setdefault(sb, []).append(rid)
        self._standby_targets = {r: tuple(v) for r, v in by_standby.items()}
        return {slot: tuple(v) for slot, v in by_slot.items()}

    def _targets(self, sender: int, msg: wire.Message) -> Sequence[int]:
        if self._receivers is None:
            return self._all
        slot = msg.function
        if slot and self.plan.function_at(slot) is not None:
            return self._receivers.get(slot, ())
        if slot == 0 and isinstance(msg, wire.Heartbeat):
            # A standby's heartbeat matters to whoever watches a slot it may take over.
            return self._standby_targets.get(sender, ())
        return self._all  # garbage: every receiver counts it as it would

    def _push(self, t: float, entry: Entry) -> None:
        heapq.heappush(self._heap, (t, next(self._counter), entry))

    # ------------------------------------------------------------------ main loop
    def run(self) -> VirtualResult:
        heap = self._heap
        while heap and heap[0][0] <= self.duration:
            t, _, entry = heapq.heappop(heap)
            self.now = t
            self._step(entry)
        self.now = self.duration
        for link, run in self._losing.items():
            self._outage(link, run, self.duration)
        violations = self.checker.finish(self.events, self.duration) + muted(self) \
            + views(self)
        violations.sort(key=lambda v: v.t)
        final, drops = self._final_states()
        return VirtualResult(
            events=self.events,
            violations=violations,
            duration=self.duration,
            frames_sent=self.frames_sent,
            deliveries=self.deliveries,
            robot_seconds=self.duration * len(self.robots),
            drops=drops,
            final=final,
        )

    def _step(self, entry: Entry) -> None:
        """Handle one entry popped off the heap at `self.now`."""
        match entry:
            case Tick(rid, gen):
                r = self.robots[rid]
                if gen != r.timer_gen or not r.alive or r.paused or r.node is None:
                    return
                r.timer_at = None
                self._call(entry)
            case Deliver(rid, frame):
                r = self.robots[rid]
                if not r.alive or r.node is None:
                    return
                if r.paused:
                    if len(r.buffered) < 512:  # a socket buffer holds a few hundred frames
                        r.buffered.append(frame)
                    return
                self.deliveries += 1
                self._call(entry)
            case Boot(rid):
                self._boot(rid)
            case FaultPhase(index, phase):
                self._fault(self.faults[index], phase)
            case Lie(rid):
                self._lie(rid)
            case Forge(rid, attack, round_):
                self._forge(rid, attack, round_)
            case DeliverRaw(rid, _):
                r = self.robots[rid]
                if r.alive and r.node is not None and not r.paused:
                    self.deliveries += 1
                    self._call(entry)

    def _final_states(self) -> tuple[dict[int, tuple[str, str | None, int]],
                                     dict[int, dict[str, int]]]:
        """Each live robot's (role, function, epoch) at the end, and every robot's
        drops by reason over all its nodes."""
        final = {}
        drops = {}
        for rid, r in self.robots.items():
            total = collections.Counter(r.dropped)
            if r.alive and r.node is not None:
                snap = r.node.snapshot()
                final[rid] = (snap.role.name.lower(), snap.function, snap.epoch)
                total.update(snap.drops)
            drops[rid] = dict(total)
        return final, drops

    def audience(self, sender: int, slot: int) -> tuple[int, ...]:
        """Who should hear `sender`'s heartbeat for `slot` (0: its standby heartbeat)."""
        return self._relevant_to.get(slot, ()) if slot else \
            self._standby_targets.get(sender, ())

    def last_arrival(self, sender: int, receiver: int) -> float | None:
        """When the latest frame of `sender` the channel carried reached `receiver`
        (None: none ever did)."""
        return self._arrived.get((sender, receiver))

    def checker_last_change(self, rid: int) -> float:
        """When robot `rid` last started, took over or was fenced (its heartbeat's
        audience changes then)."""
        return self._changed.get(rid, 0.0)

    def _call(self, given: Input) -> None:
        """Hand `given` to its robot's node now, then carry out what the node asks."""
        rid = given.robot
        r = self.robots[rid]
        node = r.node
        assert node is not None
        now = self.now
        try:
            match given:
                case Tick():
                    actions = node.tick(now)
                case Deliver(_, frame):
                    actions = node.receive_frame(frame, now)
                case DeliverRaw(_, data):
                    actions = node.receive(data, now)
                case Report(_, health):
                    actions = node.robot_health(health, now)
                case Stop():
                    actions = node.stop(now, handover=True)
                case Say(_, msg):
                    actions = node.send_message(msg, now)
                case _:
                    assert_never(given)
        except Exception as exc:  # the invariant "no node raises on any input"
            self.checker.raised(self.now, rid, exc)
            r.alive = False
            return
        self._execute(rid, actions)
        self._arm(rid)

    def _arm(self, rid: int) -> None:
        r = self.robots[rid]
        if r.node is None or not r.alive:
            return
        deadline = r.node.next_deadline()
        if deadline == r.timer_at:
            return
        r.timer_gen += 1
        r.timer_at = deadline
        if deadline is not None:
            self._push(max(deadline, self.now), Tick(rid, r.timer_gen))

    def _execute(self, rid: int, actions: list[Action]) -> None:
        for action in actions:
            match action:
                case Broadcast(frame):
                    self._broadcast(rid, frame)
                case Event() as ev:
                    self._record(ev.record(round(self.now, 6), rid))
                case Assign() | Release():
                    self.checker.robot_output(self.now, rid, action)

    def _record(self, rec: dict[str, Any]) -> None:
        self.events.append(rec)
        if name_of(rec) in ("started", "takeover", "fenced", "leave", "stopped", "fault"):
            self._changed[int(rec["robot"])] = float(rec["t"])
        self.checker.event(rec)
        if self.on_event is not None:
            self.on_event(rec)

    def _broadcast(self, sender: int, data: bytes) -> None:
        self.frames_sent += 1
        frame = wire.decode(data, self.keys, self.verifier)  # our own nodes': valid
        for rid, tape in self._recording.items():
            if self.partition is None or self.partition.get(rid, 0) == \
                    self.partition.get(sender, 0):
                tape.append(data)
        ch = self.channel
        rng = self.rng
        part = self.partition
        for rid in self._targets(sender, frame.msg):
            if rid == sender:
                continue
            if part is not None and part.get(rid, 0) != part.get(sender, 0):
                continue
            if self._lost(sender, rid):
                continue
            at = self.now + ch.delay + (rng.random() * ch.jitter if ch.jitter else 0.0)
            self._push(at, Deliver(rid, frame))
            if at > self._arrived.get((sender, rid), 0.0):
                self._arrived[(sender, rid)] = at
            if ch.duplicate and rng.random() < ch.duplicate:
                self._push(at + rng.random() * ch.jitter, Deliver(rid, frame))

    def _lost(self, sender: int, receiver: int) -> bool:
        """Is this frame lost on the link sender -> receiver (a cut, or the channel)?
        Draws from the run's random stream exactly as before when neither link faults
        nor bursts are in use, so older runs replay byte for byte."""
        if self.cuts and any(c.cuts(sender, receiver, self.now) for c in self.cuts):
            return True
        if not self.channel.loss:
            return False  # a clean channel: nothing drawn, no run of losses to follow
        if self._burst is not None:
            lost = self._burst.lost(sender, receiver)
        else:
            lost = self.rng.random() < self.channel.loss
        link = (sender, receiver)
        if lost:
            self._losing[link] = (self._losing.get(link, (self.now, 0.0))[0], self.now)
        elif (run := self._losing.pop(link, None)) is not None:
            self._outage(link, run, self.now)
        return lost

    def _outage(self, link: tuple[int, int], run: tuple[float, float], heal: float) -> None:
        """The channel alone lost every frame on `link` from `run[0]` to `run[1]`, the
        next one came through at `heal`: a run spanning `t_max` or more, the checker judges
        as a fade of that link (invariant 2)."""
        if run[1] - run[0] >= self.params.t_max:
            self.checker.outage(*link, run[0], heal)

    # ------------------------------------------------------------------ faults
    def _boot(self, rid: int) -> None:
        r = self.robots[rid]
        r.node = Node(rid, self.plan, self.params, self.now, keys=self.keys,
                      identity=self.identities.get(rid),
                      seq_start=self.rng.randrange(1 << 20))
        self._arm(rid)

    def _fault(self, fault: Fault, phase: str) -> None:
        t = self.now
        if phase == "begin":
            # One record per injected fault, as the real-time sim logs it; the end of a
            # pause or partition is `duration` after it, not a record of its own.
            self._record(fault_record(fault, t))
        self.checker.fault(t, fault, phase)
        cut = fault.cut()
        if cut is not None:
            link = LinkCut(fault.at, fault.end or fault.at, *cut)
            if phase == "begin":
                self.cuts.append(link)
                self.cuts_seen.append(link)
            elif link in self.cuts:
                self.cuts.remove(link)
            return
        if fault.kind is FaultKind.PARTITION:
            self.partition = {r: i for i, g in enumerate(fault.groups) for r in g} \
                if phase == "begin" else None
            return
        self._robot_fault(fault, phase, t)

    def _robot_fault(self, fault: Fault, phase: str, t: float) -> None:
        """A fault's `phase` on its one robot (not a link fault)."""
        rid = fault.robot
        r = self.robots[rid]
        node = r.node
        if fault.kind is FaultKind.RESTART and r.alive:
            # A restart of a live robot is a crash first, as in real time (docs/sim.md):
            # the new node starts at once from what the old one persisted.
            self._kill(r)
        match fault.kind, phase:
            case FaultKind.CRASH | FaultKind.COLLIDE, _:
                # Without physics a collision is two crashes at one instant (docs/sim.md).
                self._kill(r)
            case FaultKind.RESTART, _:
                r.alive, r.paused, r.buffered = True, False, []
                # Wiped: no state file, as at a first start (the daemon passes no
                # `restored`); its seq still starts above the old run's, as the real
                # daemon's does from the wall clock ("Sequence numbers").
                restored = None if fault.wiped else (r.persisted or Restored())
                r.node = Node(rid, self.plan, self.params, t, keys=self.keys,
                              identity=self.identities.get(rid),
                              seq_start=r.seq_high + 1_000_000, restored=restored)
                r.timer_at = None
                self._arm(rid)
            case FaultKind.PAUSE, "begin":
                r.paused = True
            case FaultKind.PAUSE, "end":
                self._unpause(rid, r)
            case FaultKind.LEAVE, _:
                if node is not None and r.alive:
                    self._call(Stop(rid))
                    # What the daemon writes on a graceful stop (swarmd.services.state): a robot
                    # that left and comes back starts above its last seq, or every peer
                    # drops its frames as replays (it would be muted).
                    self._persist(r, node, left=True)
                r.alive = False
            case FaultKind.UNHEALTHY | FaultKind.MOTOR, _:
                if node is not None and r.alive:
                    self._call(Report(rid, Health.FAULTY))
            case FaultKind.LIAR, _:
                self._push(t, Lie(rid))
            case FaultKind.FORGE, _:
                self._push(t, Forge(rid, fault.attack, 0))

    def _unpause(self, rid: int, r: _Robot) -> None:
        """The end of a pause: what the robot missed arrives at once, then its timers."""
        r.paused = False
        frames, r.buffered = r.buffered, []
        for frame in frames:
            if r.alive and r.node is not None:
                self._call(Deliver(rid, frame))
        if r.alive and r.node is not None:
            self._call(Tick(rid, r.timer_gen))  # now, not a queued timer: no generation check

    def _kill(self, r: _Robot) -> None:
        """A crash: the node's persisted state is kept (DESIGN rule 2), the rest is gone."""
        if r.node is not None and r.alive:
            self._persist(r, r.node)
        r.alive = False
        r.timer_gen += 1
        r.timer_at = None

    @staticmethod
    def _persist(r: _Robot, node: Node, *, left: bool = False) -> None:
        """What a robot's state file holds when it stops (crash: its last write; a
        robot that left handed its function over and holds nothing)."""
        snap = node.snapshot()
        held = (snap.function, snap.epoch) if snap.function and not left and \
            snap.role == Role.ACTIVE else None
        r.persisted = Restored(known=dict(snap.known), held=held,
                               peer_seq=dict(snap.peer_seq),
                               certificate=snap.certificate if held else ())
        r.seq_high = snap.seq
        r.dropped.update(snap.drops)

    def _forge(self, rid: int, attack: str, round_: int) -> None:
        """`forge:R@T:ATTACK`: R's forged frames (`sim.shared.forge`), delivered to every
        robot, R's own node and the ones it names included, as raw bytes (they go
        through `Node.receive`: decoding and verifying are what is attacked)."""
        r = self.robots[rid]
        if not r.alive or r.paused or r.node is None:
            return
        identity = self.identities.get(rid)
        tape = self._recording.pop(rid, None) if attack == "replay" else None
        if tape is not None:  # recorded until the attack began (the insider's capture)
            self._tapes[rid] = tuple(tape)
        frames = forged_frames(attack, self.plan, r.node.snapshot(), keys=self.keys,
                               signer=identity.signer if identity is not None else None,
                               round_=round_, sniffed={
                                   x: rr.node.snapshot().seq for x, rr in self.robots.items()
                                   if rr.node is not None},
                               recorded=self._tapes.get(rid, ()))
        ch, part = self.channel, self.partition
        for data in frames:
            self.frames_sent += 1
            for target in self._all:
                if part is not None and part.get(target, 0) != part.get(rid, 0):
                    continue
                if self._lost(rid, target):
                    continue
                self._push(self.now + ch.delay, DeliverRaw(target, data))
        if attack in REPEATING:
            self._push(self.now + self.params.warn_interval, Forge(rid, attack, round_ + 1))

    def _lie(self, rid: int) -> None:
        """`liar:R@T`: every warn interval while R is alive, the WARN frames
        `sim.shared.liar.liar_warnings` names."""
        r = self.robots[rid]
        if not r.alive or r.paused or r.node is None:
            return
        for msg in liar_warnings(self.plan, r.node.snapshot()):
            self._call(Say(rid, msg))
        self._push(self.now + self.params.warn_interval, Lie(rid))


def run_virtual(
    plan: SwarmPlan,
    params: Params,
    *,
    duration: float,
    faults: Sequence[Fault] = (),
    loss: float = 0.0,
    seed: int = 0,
    keys: Sequence[bytes] = (),
    auth: str = "none",
    interest: bool = True,
    channel: Channel | None = None,
    on_event: Callable[[dict[str, Any]], None] | None = None,
    loss_model: str = "bernoulli",
    burst_len: float = 4.0,
) -> VirtualResult:
    """Convenience wrapper: one run, default channel with the given loss."""
    ch = channel or Channel(loss=loss, loss_model=loss_model, burst_len=burst_len)
    return VirtualSwarm(plan, params, duration=duration, faults=faults, channel=ch, seed=seed,
                        keys=keys, auth=auth, interest=interest, on_event=on_event).run()
