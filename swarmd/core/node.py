"""The protocol node: one robot's failure handling, sans-IO (DESIGN section 2).

Shaped like aioquic's `QuicConnection`: every entry point takes `now` (monotonic
seconds) and returns the actions to execute; `next_deadline()` says when `tick` must
be called next. Nothing here does I/O, reads a clock or draws a random number.

What happens where:
- `receive`: decode and filter a frame (peer garbage becomes a counted drop, never an
  exception), then the per-message rules below.
- `tick`: deadlines — own heartbeat, watchdogs (Fig. 7), claim hold (the wait state),
  fence hold, rejoin hold.
- `robot_health`: the robot's single input (Fig. 4); FAULTY sends LEAVE (rule 7).
- `stop`: graceful stop, LEAVE when asked to hand over.

Roles and transitions are the table in `roles.py`; every change of role goes through
`_to()`, which enforces it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import NamedTuple

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Broadcast, Release
from swarmd.core.auth import Identity
from swarmd.core.evidence import CLAIMS_REMEMBERED, EvidenceStore, cert_says
from swarmd.core.evidence import seq_of as evidence_seq
from swarmd.core.limits import check_restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.replay import ReplayFilter
from swarmd.core.roles import Health, Role, Trigger, transition
from swarmd.core.votes import VoteCounter
from swarmd.core.watchdog import SlotWatch, WatchState


class Holder(NamedTuple):
    """Who executes a function slot, as far as a robot knows, and at which epoch (the
    fencing token of DESIGN rule 2). Robot 0: nobody."""

    robot: int
    epoch: int


@dataclass(frozen=True, slots=True)
class Restored:
    """What a restarted robot persisted (the runtime writes it atomically)."""

    known: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    """function -> (holder robot id, epoch) as last known."""
    held: tuple[str, int] | None = None
    """(function, epoch) this robot was executing when it stopped, if any."""
    peer_seq: Mapping[int, int] = field(default_factory=dict)
    """robot -> highest sequence number accepted from it (`Snapshot.peer_seq`): frames
    at or below it, captured before the restart, stay old (replays) after it."""
    certificate: tuple[bytes, ...] = ()
    """The signed frames that certify `held` (`Snapshot.certificate`), per-robot mode.
    Verified again on restore; a frame that does not verify is left out."""


@dataclass(frozen=True, slots=True)
class Snapshot:
    """Read-only view for persistence, the monitor and tests."""

    robot_id: int
    role: Role
    function: str | None
    epoch: int
    health: Health
    known: Mapping[str, tuple[int, int]]
    """function -> (holder, epoch); the node fills it with `Holder`s."""
    suspects: Mapping[str, int]
    """function -> suspected holder, for the slots this robot currently warns about."""
    votes: Mapping[str, int]
    """function -> distinct witnesses counted now (standbys)."""
    drops: Mapping[str, int]
    seq: int
    frames_in: int = 0
    """Frames accepted (past the drop filters)."""
    frames_out: int = 0
    heard: Mapping[int, float] = field(default_factory=dict)
    """robot -> time of the last frame accepted from it."""
    peer_seq: Mapping[int, int] = field(default_factory=dict)
    """robot -> highest sequence number accepted from it. Persist it with `known` and
    hand it back as `Restored.peer_seq`: a restarted robot then drops replays of frames
    sent before its restart (a dead robot's captured heartbeats cannot delay its
    takeover)."""
    certificate: tuple[bytes, ...] = ()
    """Per-robot mode: the signed WARN or LEAVE frames (raw bytes) that certify this
    robot's hold of `function`, if it took it over. Persist it with `held` and hand it
    back as `Restored.certificate`, so that after a restart it can still prove its hold
    to a robot that missed the takeover (an old holder back from a partition)."""


@dataclass(slots=True)
class _Claim:
    """The paper's wait state: this robot claims `function` from `failed`."""

    function: str
    failed: int
    old_epoch: int
    epoch: int
    until: float
    resend: float


@dataclass(frozen=True, slots=True)
class _Rejoin:
    """A restarted holder listening before it resumes `function` (DESIGN rule 2 across a
    reboot), until `until`."""

    function: str
    epoch: int
    until: float


class _SlotBeat(NamedTuple):
    """The last heartbeat heard for one slot: from `holder` at `epoch`, at time `at`."""

    holder: int
    epoch: int
    at: float


_NO_FRAME = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
"""The `inner` of a CERT this robot sends: only its `raw` bytes go on the wire."""


RELAY_EVERY = 8
"""Per-robot mode: a holder that took its slot over relays its certificate at least
once per this many T_max even unasked (4 s at udp, 16 s at radio), so every robot that
hears the slot holds the certificate of its holder within that bound."""


class NodeError(RuntimeError):
    """Misuse of the node API (a bug in the driver), never caused by peer frames."""


class Node:
    """One robot's protocol state. Its state is private: drivers read `snapshot()` and
    the few read-only properties below."""

    def __init__(
        self,
        robot_id: int,
        plan: SwarmPlan,
        params: Params,
        now: float,
        *,
        keys: Sequence[bytes] = (),
        identity: Identity | None = None,
        seq_start: int = 0,
        restored: Restored | None = None,
    ) -> None:
        if robot_id not in plan.robots:
            raise NodeError(f"robot {robot_id} is not in the swarm plan")
        check_restored(restored, seq_start)  # out-of-range state: refuse, never loop
        self._robot_id = robot_id
        self._plan = plan
        self._params = params
        self._keys = tuple(keys)
        self._identity = identity
        self._signer = identity.signer if identity is not None else None
        self._verifier = identity.verifier if identity is not None else None
        self._seq = seq_start
        self._seq_start = seq_start
        self._health = Health.OK
        self._drops: Counter[str] = Counter()
        self._frames_in = 0
        self._frames_out = 0

        # function -> (holder, epoch): whoever executes each slot, as far as we know.
        self._known: dict[str, Holder] = {}
        for f in plan.functions:
            holder = plan.initial_holder(f)
            self._known[f] = Holder(holder if holder is not None else 0, 0)
        if restored is not None:
            for f, (holder, epoch) in restored.known.items():
                if f in self._known and epoch >= self._known[f].epoch \
                        and (identity is None or epoch == 0):
                    # Per-robot mode believes a raised epoch only with its certificate,
                    # read from a file as from the air (DESIGN, "Convergence"): the
                    # holder relays it to a restarted robot that still shows the old one.
                    self._known[f] = Holder(holder, epoch)

        self._covers = frozenset(f for f in plan.functions if robot_id in plan.covered_by(f))
        self._relevant = plan.relevant(robot_id)
        self._role = Role.STANDBY
        self._function: str | None = None
        self._epoch = 0
        self._watches: dict[str, SlotWatch] = {}
        self._votes: dict[str, VoteCounter] = {f: VoteCounter(params.vote_window)
                                               for f in self._covers}
        self._claim: _Claim | None = None
        self._fenced_until: float | None = None
        self._rejoin: _Rejoin | None = None
        self._heard_at: dict[int, float] = {}  # robot -> last frame accepted from it
        # function -> (holder, epoch, time) of the last heartbeat heard *for that slot*:
        # a robot that stopped heartbeating but still sends other frames (a faulty
        # liar) must not look alive to the standby that would replace it.
        self._slot_heard: dict[str, _SlotBeat] = {}
        self._standby_at: dict[int, float] = {}  # standby robot -> last standby heartbeat
        # function -> {(claimant, epoch): first heard}: claims are believed for a
        # bounded time (rule 10); forgotten when the slot's next holder heartbeats.
        self._claims_seen: dict[str, dict[tuple[int, int], float]] = {}
        self._replay = ReplayFilter(seq_start, now)  # bounded by our own clock
        if restored is not None:
            for peer, top in restored.peer_seq.items():
                if peer != robot_id and peer in plan.robots \
                        and not self._replay.restore(peer, top):
                    self._drops["seq_jump"] += 1  # an absurd persisted value: refused
        # Per-robot mode (DESIGN section 2, "Who may say what"): signed evidence and
        # the certificates it makes, `evidence.py`.
        self._ev = EvidenceStore(robot_id, plan, params)
        self._start_time = now
        self._stalled_at = -1e18
        self._next_heartbeat = now
        self._last_heartbeat = -1e18
        # The deadline the driver was last given (`_drain`): a call far past it is
        # our own stall, not the neighbours' silence (`_advance`).
        self._armed: float | None = now
        self._stopped = False
        self._started = False
        self._pending: list[Action] = []

        own = plan.robots[robot_id].function
        held = restored.held if restored is not None else None
        if held is not None and self._verifier is not None and held[0] in self._known:
            held = self._verified_hold(held[0], held[1], restored)
        if restored is not None and held is not None:
            # Rule 2 across a reboot: listen before resuming, a takeover may have
            # happened while this robot was down.
            f, epoch = held
            if f in self._known:
                self._rejoin = _Rejoin(f, epoch, now + params.rejoin_hold)
        elif restored is None and own is not None:
            self._role = Role.ACTIVE
            self._function = own
            self._epoch = self._known[own].epoch
            self._watch_neighbours(now)

    def _verified_hold(self, f: str, epoch: int,
                       restored: Restored | None) -> tuple[str, int] | None:
        """Per-robot mode: the hold of f at `epoch` a restarted robot read from its state
        file, if it is provable as a received one would be — the plan's own holder at
        epoch 0, or a certificate that verifies and backs it; otherwise None (it rejoins
        as a standby, and the slot's watchers take it over if nobody holds it)."""
        assert self._verifier is not None and restored is not None
        if epoch == 0:
            return (f, 0) if self._plan.initial_holder(f) == self._robot_id else None
        if self._ev.restore(f, epoch, tuple(restored.certificate), self._verifier):
            self._known[f] = Holder(self._robot_id, epoch)
            return (f, epoch)
        return None

    # ------------------------------------------------------------------ read-only
    @property
    def robot_id(self) -> int:
        return self._robot_id

    @property
    def plan(self) -> SwarmPlan:
        return self._plan

    @property
    def params(self) -> Params:
        return self._params

    @property
    def keys(self) -> tuple[bytes, ...]:
        """The swarm keys: `keys[0]` signs, any of them verifies (`set_keys`)."""
        return self._keys

    @property
    def per_robot(self) -> bool:
        """Signed per robot: WARN, CLAIM and LEAVE carry their sender's own signature."""
        return self._identity is not None

    @property
    def drops(self) -> Mapping[str, int]:
        """Cumulative dropped frames by reason, live (a missing reason reads 0); cheap
        enough to read once a frame, unlike `snapshot()`."""
        return MappingProxyType(self._drops)

    # ------------------------------------------------------------------ entry points
    def receive(self, data: bytes, now: float) -> list[Action]:
        """A frame from the channel. Never raises on peer input."""
        head = wire.peek(data)
        if head is not None and self._irrelevant(
                head.swarm_id, head.sender, head.slot, head.robot,
                standby_beat=head.mtype == wire.MsgType.HEARTBEAT and head.slot == 0):
            # Before the HMAC and any state: a daemon's cost follows its neighbourhood,
            # not the swarm. No deadline moved, so there is nothing to hand back.
            self._drops["irrelevant"] += 1
            return []
        self._advance(now)
        if self._stopped:
            return self._drain()
        try:
            frame = wire.decode(data, self._keys, self._verifier)
        except wire.CodecError as exc:
            return self._drop(exc.reason)
        return self._accept(frame, now)

    def receive_frame(self, frame: wire.Frame, now: float) -> list[Action]:
        """A frame already decoded and verified with this swarm's keys. For simulators
        that deliver one broadcast to many nodes and decode it once; the runtime uses
        `receive`."""
        msg = frame.msg
        if isinstance(msg, wire.Cert) and self._verifier is None:
            return self._drop("auth")
        about = msg.suspect if isinstance(msg, wire.Warn) else \
            msg.failed if isinstance(msg, wire.Claim) else 0
        if self._irrelevant(frame.swarm_id, frame.sender, msg.function, about,
                            standby_beat=isinstance(msg, wire.Heartbeat) and msg.function == 0):
            self._drops["irrelevant"] += 1
            return []
        self._advance(now)
        if self._stopped:
            return self._drain()
        return self._accept(frame, now)

    def _irrelevant(self, swarm_id: int, sender: int, slot: int, about: int, *,
                    standby_beat: bool) -> bool:
        """A frame no rule of this robot would act on (DESIGN section 2, "What a robot
        hears"), judged by slot, not by sender: watchers follow whoever holds a slot
        (rule 1). Anything `_accept` counts under its own reason passes through."""
        if swarm_id != self._plan.swarm_id or sender == self._robot_id \
                or sender not in self._plan.robots:
            return False
        if standby_beat:
            return sender not in self._relevant.standbys  # rules 6 and 8
        if about == self._robot_id or not 1 <= slot <= len(self._plan.functions):
            return False  # a warning about us (rule 4), or a bad_function drop
        return slot not in self._relevant.slots

    def _accept(self, frame: wire.Frame, now: float) -> list[Action]:
        sender = frame.sender
        if frame.swarm_id != self._plan.swarm_id:
            return self._drop("swarm")
        if sender not in self._plan.robots:
            return self._drop("unknown_sender")
        if isinstance(frame.msg, wire.Cert):
            # Not through the replay filter: the wrapper is unauthenticated (what it
            # relays is signed and judged on its own), so it must move no counter.
            self._on_cert(frame.msg, now)
            return self._drain()
        if sender == self._robot_id:
            return self._own_frame(frame, now)
        reason = self._replay.check(sender, frame.seq, now)
        if reason is not None:
            return self._drop(reason)
        self._frames_in += 1
        self._heard_at[sender] = now
        match frame.msg:
            case wire.Heartbeat() as hb:
                self._on_heartbeat(sender, hb, now)
            case wire.Warn() as w:
                self._on_warn(sender, w, now, frame.raw, frame.seq)
            case wire.Claim() as c:
                self._on_claim(sender, c, now)
            case wire.Leave() as lv:
                self._on_leave(sender, lv, now, frame.raw)
            case wire.Refute() as rf:
                self._on_refute(sender, rf, now, frame.raw)
        return self._drain()

    def _own_frame(self, frame: wire.Frame, now: float) -> list[Action]:
        """A verified frame sent as this robot. Multicast loopback echoes our own frames
        (`own`; the runtime tells a second daemon with our id by frames it did not send).
        One from before this node started is a replay, not a duplicate robot
        (`replay`). One above our counter was sent by another daemon with our id or a
        forger holding our key: our counter moves above it, so receivers that took it
        do not drop our next frames as replays (a jump cannot mute us; DESIGN section 2,
        "Sequence numbers")."""
        if frame.seq < self._seq_start:
            return self._drop("replay")
        if self._seq < frame.seq <= (self._replay.follow_limit(now) or wire.SEQ_MAX):
            # Further ahead, every receiver drops it as `seq_jump`: nothing to follow.
            self._seq = frame.seq
        return self._drop("own")

    def tick(self, now: float) -> list[Action]:
        """Fire every deadline that is due at `now`."""
        self._advance(now)
        if self._stopped:
            return self._drain()
        if not self._started:
            self._start(now)
        p = self._params
        if self._rejoin is not None and now >= self._rejoin.until:
            self._finish_rejoin(now)
        if self._fenced_until is not None and now >= self._fenced_until:
            self._fenced_until = None
            self._to(Trigger.FENCE_DONE)
        if self._claim is not None:
            if now >= self._claim.until:
                self._take_over(now)
            elif now >= self._claim.resend:
                self._claim.resend = now + p.warn_interval
                self._send_claim(with_cert=True)
        for g, watch in self._watches.items():
            if now >= watch.deadline:
                self._watch_fired(g, watch, now)
        if self._heartbeating() and now >= self._next_heartbeat:
            self._send_heartbeat(now)
            if self._identity is not None and self._role == Role.ACTIVE and self._epoch:
                # Anti-entropy: a robot that restarted, or missed the takeover and
                # heard nothing since that would make us relay, learns it within
                # RELAY_EVERY T_max (DESIGN, "Convergence").
                self._relay_cert(f=self._function, now=now,
                                 every=RELAY_EVERY * p.t_max)
            # No drift: the next one is due one period after the *deadline*.
            period = self._heartbeat_period()
            self._next_heartbeat += period
            if self._next_heartbeat <= now:
                self._next_heartbeat = now + period
        return self._drain()

    def robot_health(self, health: Health, now: float) -> list[Action]:
        """The robot's health (paper Fig. 4's single input; DESIGN rule 7)."""
        self._advance(now)
        if self._stopped or health == self._health:
            return self._drain()
        was_faulty = self._health == Health.FAULTY
        self._health = health
        if health == Health.FAULTY:
            if self._role == Role.ACTIVE and self._function is not None:
                f = self._function
                self._emit(ev.Leave(function=f, reason="fault"))
                self._send(wire.Leave(self._plan.slot(f), self._epoch, wire.LeaveReason.FAULT),
                           evidence=True)
                self._release()
            elif self._claim is not None:
                self._claim = None
            if self._rejoin is not None:
                self._rejoin = None  # a faulty robot resumes nothing: it is a standby now
                if self._started:
                    self._emit(ev.Started(role="standby", function=None))
            self._to(Trigger.FAULT)
            self._clear_votes()
        elif was_faulty:
            self._next_heartbeat = now  # back to heartbeating as a standby at once
        return self._drain()

    def stop(self, now: float, *, handover: bool) -> list[Action]:
        """Graceful stop. With `handover`, an ACTIVE robot sends LEAVE so a standby
        takes over without waiting for a timeout."""
        self._advance(now)
        if self._stopped:
            return self._drain()
        if self._role == Role.ACTIVE and self._function is not None:
            if handover:
                self._emit(ev.Leave(function=self._function, reason="shutdown"))
                self._send(wire.Leave(self._plan.slot(self._function), self._epoch,
                                      wire.LeaveReason.SHUTDOWN), evidence=True)
            self._pending.append(Release(self._function))
        self._emit(ev.Stopped())
        self._stopped = True
        return self._drain()

    def send_message(self, msg: wire.Message, now: float) -> list[Action]:
        """Broadcast an arbitrary message under this robot's identity and sequence.
        A fault-injection hook for the simulators (`liar:R@T`); the protocol itself
        never needs it."""
        self._advance(now)
        self._send(msg)
        return self._drain()

    def set_keys(self, keys: Sequence[bytes]) -> None:
        """Replace the swarm keys live (SIGHUP reload; docs/operations.md "Rotating the
        swarm key"): from the next frame on, `keys[0]` signs and a frame tagged with any
        of them is accepted; one tagged only with a key no longer listed is dropped as
        `auth`. An empty list means unsigned, allowed only if the node is unsigned now.

        Raises `NodeError` (and changes nothing) for a key that is not `wire.KEY_LEN` bytes,
        or for an empty list while signing: a config that lost its key lines would
        otherwise turn authentication off on a running robot, which then sends frames
        every keyed robot drops and accepts forged ones (DESIGN section 2). Turning
        signing off takes a restart. Going from unsigned to signed is allowed: that
        cut-over has no window whichever way it is done (an unsigned frame cannot be
        verified)."""
        new = tuple(keys)
        for i, key in enumerate(new):
            if not isinstance(key, bytes):
                raise NodeError(f"swarm key {i} is a {type(key).__name__}, not bytes")
            if len(key) != wire.KEY_LEN:
                raise NodeError(f"swarm key {i} is {len(key)} bytes; a swarm key is "
                                f"exactly {wire.KEY_LEN} bytes")
        if not new and self._keys:
            raise NodeError("no swarm key given while frames are signed; turning signing "
                            "off needs a restart, not a key reload")
        self._keys = new

    def next_deadline(self) -> float | None:
        """When `tick` must be called next (absolute, same clock as `now`)."""
        if self._stopped:
            return None
        if not self._started:
            return self._start_time
        candidates = [w.deadline for w in self._watches.values()]
        if self._heartbeating():
            candidates.append(self._next_heartbeat)
        if self._claim is not None:
            candidates.append(min(self._claim.until, self._claim.resend))
        if self._fenced_until is not None:
            candidates.append(self._fenced_until)
        if self._rejoin is not None:
            candidates.append(self._rejoin.until)
        return min(candidates) if candidates else None

    def snapshot(self) -> Snapshot:
        return Snapshot(
            robot_id=self._robot_id,
            role=self._role,
            function=self._function,
            epoch=self._epoch,
            health=self._health,
            known=dict(self._known),
            suspects={g: self._known[g].robot for g, w in self._watches.items() if w.suspecting},
            votes={f: len(v.witnesses) for f, v in self._votes.items() if v.witnesses},
            drops=dict(self._drops),
            seq=self._seq,
            frames_in=self._frames_in,
            frames_out=self._frames_out,
            heard=dict(self._heard_at),
            peer_seq={r: st[0] for r, st in self._replay.state.items()},
            certificate=self._ev.certificate(self._function),
        )

    # ------------------------------------------------------------------ message rules
    def _on_heartbeat(self, sender: int, hb: wire.Heartbeat, now: float) -> None:
        if hb.function == 0:
            if hb.role in (Role.STANDBY, Role.CLAIMING) and hb.health != Health.FAULTY:
                self._standby_at[sender] = now
            return
        f = self._plan.function_at(hb.function)
        if f is None:
            self._drops["bad_function"] += 1
            return
        holder, epoch = self._known[f]
        newer = hb.epoch > epoch or (hb.epoch == epoch and (sender == holder or sender < holder))
        if newer and self._identity is not None and (sender, hb.epoch) != (holder, epoch) \
                and not self._ev.is_certified(f, sender, hb.epoch):
            # Per-robot mode: a heartbeat is not signed by its sender, so it never moves
            # an epoch or a holder by itself; only the certified new holder's does.
            self._drops["uncertified"] += 1
            if f == self._function and self._role == Role.ACTIVE:
                self._relay_cert(f, now)
            self._relay_refutes(f, now)  # it may act on a claim they void
            if self._rejoin is not None and self._rejoin.function == f:
                # Not believed, but enough to stay a standby rather than resume: the
                # cautious side of rule 2 across a reboot (the slot's watchers and
                # standbys take it over if nobody really holds it).
                self._rejoin_superseded(f, hb.epoch)
            return
        if not newer:
            # A stale holder (e.g. back from a pause): if it is our slot, answer at once
            # so it hears the newer epoch and fences itself (rule 2) within a frame.
            if f == self._function and self._role == Role.ACTIVE:
                self._relay_cert(f, now)
                self._heartbeat_now(now)
            return
        self._known[f] = Holder(sender, hb.epoch)
        self._slot_heard[f] = _SlotBeat(sender, hb.epoch, now)
        self._claims_seen.pop(f, None)
        # Rule 2: our own slot held at a higher epoch, or at ours by a lower id.
        if f == self._function and self._role == Role.ACTIVE and sender != self._robot_id:
            self._fence(hb.epoch, now)
            return
        watch = self._watches.get(f)
        if watch is not None:
            suspected = watch.suspecting
            if watch.heard(now) and suspected and hb.epoch == epoch and sender == holder:
                self._emit(ev.Refute(subject=sender, function=f))
        votes = self._votes.get(f)
        if votes is not None and votes.witnesses:
            votes.clear()  # rule 4: the suspect is alive, or a new holder is
        if self._claim is not None and self._claim.function == f:
            if hb.epoch >= self._claim.epoch:
                self._emit(ev.Backoff(subject=self._claim.failed, function=f, winner=sender))
                self._claim = None
                self._to(Trigger.SUPERSEDED)
            elif sender == self._claim.failed:
                self._emit(ev.Refute(subject=sender, function=f))
                self._claim = None
                self._to(Trigger.REFUTED)
        if self._rejoin is not None and self._rejoin.function == f and sender != self._robot_id:
            self._rejoin_superseded(f, self._known[f].epoch)

    def _on_warn(self, sender: int, w: wire.Warn, now: float, raw: bytes = b"",
                 seq: int = 0) -> None:
        f = self._plan.function_at(w.function)
        if f is None:
            self._drops["bad_function"] += 1
            return
        if self._identity is not None:
            self._record_evidence(f, sender, w.suspect, w.epoch, raw, now)
            if f == self._function and self._role == Role.ACTIVE \
                    and (w.epoch, w.suspect) != (self._epoch, self._robot_id):
                self._relay_cert(f, now)  # a watcher that missed our takeover
        if w.suspect == self._robot_id:
            # Rule 4: a warning about ourselves is answered with a heartbeat at once.
            if self._role == Role.ACTIVE and f == self._function:
                self._refute(f, sender, w.epoch, seq, now)
                if self._heartbeat_now(now):
                    self._emit(ev.Refute(subject=self._robot_id, function=f))
            return
        holder, epoch = self._known[f]
        if self._rejoin is not None and self._rejoin.function == f:
            self._rejoin_superseded(f, w.epoch)
        if f not in self._covers or not self._standing_by():
            return
        if w.epoch < epoch or (w.epoch == epoch and w.suspect != holder):
            return  # about an older holder: stale
        # A warning at a newer epoch than we know means we missed a takeover (we were
        # partitioned, or lost its heartbeats) and the new holder may be dead already:
        # count it, keyed by (suspect, epoch), without believing it into `known` — a
        # single liar cannot reach the quorum, and the holder's heartbeat refutes it.
        # Rule 3: only the holders of the slots that watch f are witnesses; never the
        # suspect itself.
        witnesses = {self._known[g].robot for g in self._plan.watched_by(f)}
        if sender == w.suspect or sender not in witnesses:
            self._drops["not_witness"] += 1
            return
        votes = self._votes[f]
        fresh = sender not in votes.witnesses or (w.suspect, w.epoch) != (votes.subject,
                                                                          votes.epoch)
        count = votes.add(sender, w.suspect, w.epoch, now)
        if fresh:  # repeated warnings refresh a vote; only a new witness is an event
            self._emit(ev.Vote(subject=w.suspect, function=f, from_=sender, count=count))
        if count < self._params.quorum and self._own_ears(f, now):
            # Rule 9: correlated failures took watchers of f with the suspect; this
            # standby's own ears stand in for them, as one witness.
            mine = self._robot_id in votes.witnesses
            if not mine and self._identity is not None:
                # Its own "warning" is a signed one, so the certificate can carry it.
                self._record_evidence(f, self._robot_id, w.suspect, w.epoch,
                                      self._sign_only(wire.Warn(w.suspect, w.function,
                                                                w.epoch)))
            count = votes.add(self._robot_id, w.suspect, w.epoch, now)
            if not mine:
                self._emit(ev.Vote(subject=w.suspect, function=f, from_=self._robot_id,
                                   count=count))
        if count >= self._params.quorum:
            # Rule 4 from our own ears: the channel is a broadcast, so the standby hears
            # the suspect too. Heard within T_max/2, the suspect is alive whatever the
            # witnesses missed (loss); after a real crash this is silent by the time
            # warnings come (they come T_max after the last heartbeat), so it costs no
            # latency. The next warning re-checks.
            heard = self._slot_heard.get(f)
            if heard is not None and (heard.holder, heard.epoch) == (w.suspect, w.epoch) \
                    and now - heard.at < self._params.t_max / 2:
                return
            self._start_claim(f, w.suspect, w.epoch, now)

    def _own_ears(self, f: str, now: float) -> bool:
        """DESIGN rule 9: is this standby a witness of f's holder's silence itself?

        Only when (a) it has heard no heartbeat for slot f for T_max — on a broadcast
        medium a live suspect is heard by the standby as well as by its watchers, so a
        liar's warning about a live robot finds the standby's ears against it — and
        (b) fewer than a quorum of f's watchers are alive by their own heartbeats, so
        the quorum can no longer be met by watchers alone. Never during the start-up
        grace, when silence means nothing yet."""
        p = self._params
        if now - self._start_time < p.startup_grace:
            return False
        heard = self._slot_heard.get(f)
        if heard is not None and now - heard.at < p.t_max:
            return False
        live = 0
        for g in self._plan.watched_by(f):
            beat = self._slot_heard.get(g)
            if beat is not None and beat.holder == self._known[g].robot \
                    and now - beat.at < p.t_max:
                live += 1
        return live < p.quorum

    def _claim_believed(self, f: str, sender: int, c: wire.Claim, now: float) -> bool:
        """DESIGN rule 10: a CLAIM is believed for `claim_hold + t_max` from the first
        time this (claimant, epoch) was heard for f; by then the claimant heartbeats
        at its new epoch or it is dead or stuck. Its repeats neither extend the
        watchers' silence nor clear a standby's votes again."""
        seen = self._claims_seen.setdefault(f, {})
        first = seen.get((sender, c.epoch))
        if first is None:
            if len(seen) >= CLAIMS_REMEMBERED:
                del seen[min(seen, key=seen.__getitem__)]
            seen[(sender, c.epoch)] = now
            return True
        return now - first <= self._params.claim_hold + self._params.t_max

    def _on_claim(self, sender: int, c: wire.Claim, now: float) -> None:
        f = self._plan.function_at(c.function)
        if f is None:
            self._drops["bad_function"] += 1
            return
        if self._identity is not None:
            if (sender, c.epoch) == tuple(self._known[f]):
                return  # the holder re-announcing its certificate (`_relay_cert`)
            if not self._ev.certify(f, sender, c, self._known[f].epoch):
                # Per-robot mode: a claim without a certificate this robot verified
                # silences nobody and makes nobody back off (one robot alone cannot
                # start a takeover); kept a while in case its certificate comes later.
                self._ev.hold_pending(f, sender, c, now)
                self._drops["uncertified"] += 1
                self._relay_refutes(f, now)
                return
        if not self._claim_believed(f, sender, c, now):
            self._drops["stale_claim"] += 1
            return
        if self._claim is not None and self._claim.function == f:
            # The paper's wait state: the lower id wins; a claim at a higher epoch
            # knows more than we do.
            mine = self._claim.epoch
            if c.epoch > mine or (c.epoch == mine and sender < self._robot_id):
                self._emit(ev.Backoff(subject=self._claim.failed, function=f, winner=sender))
                self._claim = None
                self._to(Trigger.BACKOFF)
            return
        if self._role == Role.ACTIVE and f == self._function:
            if c.failed == self._robot_id and c.epoch > self._epoch and self._heartbeat_now(now):
                self._emit(ev.Refute(subject=self._robot_id, function=f))
            return
        watch = self._watches.get(f)
        if watch is not None and c.epoch > self._known[f].epoch:
            watch.claim_heard(now)  # paper: a claim tells the neighbours to stop warning
        votes = self._votes.get(f)
        if votes is not None:
            votes.clear()
        if self._rejoin is not None and self._rejoin.function == f:
            self._rejoin_superseded(f, c.epoch)

    def _on_leave(self, sender: int, lv: wire.Leave, now: float, raw: bytes = b"") -> None:
        f = self._plan.function_at(lv.function)
        if f is None:
            self._drops["bad_function"] += 1
            return
        if self._identity is not None:
            # A signed LEAVE from the holder itself is evidence enough for its own slot.
            self._record_evidence(f, sender, sender, lv.epoch, raw, now)
        holder, epoch = self._known[f]
        if (sender, lv.epoch) != (holder, epoch):
            return  # not the current holder: stale
        watch = self._watches.get(f)
        if watch is not None:
            watch.claim_heard(now)
            if not self._live_standby(f, sender, now):
                watch.mark_alerted()
                self._emit(ev.Alert(function=f, reason="no standby left"))
        if f in self._covers and self._standing_by():
            self._start_claim(f, sender, epoch, now, trigger=Trigger.LEAVE_HEARD)

    # ------------------------------------------------------------------ transitions
    def _start(self, now: float) -> None:
        self._started = True
        if self._rejoin is not None:
            return  # `started` tells the outcome once the rejoin hold is over
        self._emit(ev.Started(role=self._role.name.lower(), function=self._function))
        if self._role == Role.ACTIVE and self._function is not None:
            self._pending.append(Assign(self._function, self._epoch))

    def _start_claim(self, f: str, failed: int, epoch: int, now: float,
                     trigger: Trigger = Trigger.QUORUM) -> None:
        self._to(trigger)
        new_epoch = epoch + 1
        if new_epoch > 0xFFFF:
            new_epoch = 0xFFFF  # 65535 takeovers of one slot; saturate rather than wrap
        self._claim = _Claim(f, failed, epoch, new_epoch, now + self._params.claim_hold,
                            now + self._params.warn_interval)
        self._clear_votes()
        self._emit(ev.Claim(subject=failed, function=f, epoch=new_epoch))
        self._send_claim()

    def _send_claim(self, *, with_cert: bool = True) -> None:
        assert self._claim is not None
        c = self._claim
        if with_cert and self._identity is not None:
            for raw in self._ev.cert_frames(c.function, c.failed, c.old_epoch):
                self._send_cert(c.function, raw)
        self._send(wire.Claim(c.failed, self._plan.slot(c.function), c.epoch))

    def _take_over(self, now: float) -> None:
        assert self._claim is not None
        c = self._claim
        if self._identity is not None and not self._ev.certify(
                c.function, self._robot_id,
                wire.Claim(c.failed, self._plan.slot(c.function), c.epoch),
                self._known[c.function].epoch):
            # Its certificate was refuted during the hold (or never complete): a takeover
            # no other robot would believe is none (DESIGN, "Convergence").
            self._emit(ev.Refute(subject=c.failed, function=c.function))
            self._claim = None
            self._to(Trigger.REFUTED)
            return
        self._claim = None
        self._to(Trigger.CLAIM_HELD)
        self._function, self._epoch = c.function, c.epoch
        self._known[c.function] = Holder(self._robot_id, c.epoch)
        if self._identity is not None:
            self._ev.took_over(c.function, c.failed, c.old_epoch, c.epoch)
        self._emit(ev.Takeover(function=c.function, epoch=c.epoch, replaced=c.failed))
        self._pending.append(Assign(c.function, c.epoch))
        self._watch_neighbours(now)
        self._restart_heartbeats(now)

    def _fence(self, epoch: int, now: float) -> None:
        f = self._function
        assert f is not None
        self._emit(ev.Fenced(function=f, epoch=epoch))
        self._release()
        self._to(Trigger.FENCE)
        self._fenced_until = now + self._params.heartbeat_interval

    def _release(self) -> None:
        if self._function is not None:
            self._pending.append(Release(self._function))
        self._function = None
        self._epoch = 0
        self._watches = {}

    def _finish_rejoin(self, now: float) -> None:
        assert self._rejoin is not None
        f, epoch = self._rejoin.function, self._rejoin.epoch
        self._rejoin = None
        holder, known_epoch = self._known[f]
        if known_epoch > epoch or (known_epoch == epoch and holder != self._robot_id
                                   and holder < self._robot_id):
            self._emit(ev.Started(role="standby", function=None))
            return
        self._to(Trigger.REJOIN)
        self._function, self._epoch = f, epoch
        self._known[f] = Holder(self._robot_id, epoch)
        self._emit(ev.Started(role="active", function=f))
        self._pending.append(Assign(f, epoch))
        self._watch_neighbours(now)
        self._restart_heartbeats(now)

    def _rejoin_superseded(self, f: str, seen_epoch: int) -> None:
        """Someone holds, warns about or claims our old slot at `seen_epoch`: newer than
        the one we held (or held by another robot), we stay a standby. WARN and CLAIM
        do not update `known` (a liar must not move it), so their epoch is passed in."""
        assert self._rejoin is not None
        epoch = self._rejoin.epoch
        known = self._known[f]
        if seen_epoch > epoch or known.epoch > epoch or known.robot != self._robot_id:
            self._rejoin = None
            self._emit(ev.Started(role="standby", function=None))

    def _standing_by(self) -> bool:
        """A standby that may vote and claim (Fig. 9): not faulty, and not in the rejoin
        hold, where it still means to resume its own slot (rule 2 across a reboot) and
        must not take another one meanwhile."""
        return self._role == Role.STANDBY and self._health != Health.FAULTY \
            and self._rejoin is None

    def _to(self, trigger: Trigger) -> None:
        self._role = transition(self._role, trigger)

    # ------------------------------------------------------------------ watchdogs
    def _watch_neighbours(self, now: float) -> None:
        assert self._function is not None
        self._watches = {}
        for g in self._plan.watched(self._function):
            holder = self._known[g].robot
            self._watches[g] = SlotWatch(g, self._params, now, self._heard_at.get(holder))

    def _watch_fired(self, g: str, watch: SlotWatch, now: float) -> None:
        subject, epoch = self._known[g]
        fired = watch.fire(now)
        if fired.first:
            self._emit(ev.Suspect(subject=subject, function=g))
            self._emit(ev.Warn(subject=subject, function=g))
        elif fired.alert:
            self._emit(ev.Alert(function=g, reason="no claim"))
        elif (not watch.alerted and watch.since is not None
              and now - watch.since >= self._params.t_max
              and not self._live_standby(g, subject, now)):
            # Rule 8, without waiting for alert_after: nobody can take over. Not on the
            # first fire: one more T_max of silence first, so loss alone rarely alerts.
            watch.mark_alerted()
            self._emit(ev.Alert(function=g, reason="no standby left"))
        self._send(wire.Warn(subject, self._plan.slot(g), epoch))

    def _live_standby(self, f: str, subject: int, now: float) -> bool:
        """Is any robot that may take `f` over plausibly alive (rules 6, 8)? A standby
        never heard counts as alive during the start-up grace time only."""
        in_grace = now - self._start_time < self._params.startup_grace
        for r in self._plan.covered_by(f):
            if r in (subject, self._robot_id):
                continue
            seen = self._standby_at.get(r)
            if seen is None and in_grace:
                return True
            if seen is not None and now - seen <= self._params.standby_timeout:
                return True
        return False

    # ------------------------------------------------------------------ heartbeats
    def _heartbeating(self) -> bool:
        return not self._stopped and self._health != Health.FAULTY

    def _heartbeat_period(self) -> float:
        if self._role == Role.ACTIVE:
            return self._params.heartbeat_interval
        return self._params.standby_heartbeat_interval

    def _send_heartbeat(self, now: float) -> None:
        slot = self._plan.slot(self._function) if self._function is not None else 0
        self._send(wire.Heartbeat(slot, self._epoch if slot else 0, int(self._role),
                                  int(self._health)))
        self._last_heartbeat = now

    def _restart_heartbeats(self, now: float) -> None:
        """Became ACTIVE: heartbeat now and every heartbeat_interval from now on (the
        standby period would let the new neighbours' T_max run out)."""
        if self._heartbeating():
            self._send_heartbeat(now)
            self._next_heartbeat = now + self._params.heartbeat_interval

    def _heartbeat_now(self, now: float) -> bool:
        """An extra heartbeat out of schedule (refutation, fencing a stale holder),
        at most four per heartbeat period so a flood of warnings cannot amplify."""
        if not self._heartbeating():
            return False
        if now - self._last_heartbeat < self._params.heartbeat_interval / 4:
            return False
        self._send_heartbeat(now)
        return True

    # ------------------------------------------------------------------ plumbing
    def _advance(self, now: float) -> None:
        """Notice our own stall: called much later than our deadline (SIGSTOP, a
        suspended laptop), our silence is ours, not the neighbours'."""
        armed = self._armed
        if armed is not None and self._started and now - armed > self._params.t_max / 2:
            for w in self._watches.values():
                w.refresh(now)
            self._clear_votes()
            if self._claim is not None:
                self._claim.until = max(self._claim.until, now + self._params.claim_hold)
            self._next_heartbeat = now
            self._stalled_at = now
            self._armed = None  # noticed once; `_drain` arms the next deadline

    def _clear_votes(self) -> None:
        for v in self._votes.values():
            v.clear()

    def _send(self, msg: wire.Message, *, evidence: bool = False) -> bytes:
        self._seq = min(self._seq + 1, wire.SEQ_MAX)
        frame = wire.Frame(self._plan.swarm_id, self._robot_id, self._seq, msg)
        data = wire.encode(frame, self._keys[0] if self._keys else None, self._signer)
        if evidence and self._identity is not None and isinstance(msg, wire.Leave):
            f = self._plan.function_at(msg.function)
            if f is not None:
                self._record_evidence(f, self._robot_id, self._robot_id, msg.epoch, data)
        self._pending.append(Broadcast(data))
        self._frames_out += 1
        return data

    # ------------------------------------------------------------------ evidence
    # Per-robot mode: the certificates themselves are `evidence.py`'s.

    def _sign_only(self, msg: wire.Message) -> bytes:
        """A frame signed by this robot, for a certificate, not broadcast by itself."""
        assert self._signer is not None
        self._seq = min(self._seq + 1, wire.SEQ_MAX)
        frame = wire.Frame(self._plan.swarm_id, self._robot_id, self._seq, msg)
        return wire.encode(frame, None, self._signer)

    def _send_cert(self, f: str, raw: bytes) -> None:
        # A CERT is not counted in `frames_out` seq terms differently: it has a seq of
        # its own, but receivers do not replay-filter it (it is unauthenticated).
        self._send(wire.Cert(self._plan.slot(f), _NO_FRAME, raw))

    def _record_evidence(self, f: str, witness: int, suspect: int, epoch: int,
                         raw: bytes, now: float | None = None) -> None:
        if suspect == self._robot_id and witness != suspect and now is not None:
            # Evidence against us, relayed in a certificate (we may have missed the
            # warning itself): while we hold the slot, we refute it (rule 4).
            self._refute(f, witness, epoch, evidence_seq(raw), now)
        ready = self._ev.record(f, witness, suspect, epoch, raw, self._known[f].epoch, now)
        if ready is None:
            if suspect != self._robot_id:  # what we refuted ourselves is no news
                self._drops["stale_evidence"] += 1
            return
        for claimant, claim in ready:
            assert now is not None  # `record` readies a claim only with a `now`
            self._on_claim(claimant, claim, now)

    def _relay_cert(self, f: str | None, now: float, every: float | None = None) -> None:
        """Someone still believes an older holder of our slot: relay the certificate of
        our hold and re-announce the claim it backs, at most once per T_max (`every`)."""
        if f is None:
            return
        mine = self._ev.relay(f, now, every)
        if mine is None:
            return
        failed, frames = mine
        for raw in frames:
            self._send_cert(f, raw)
        self._send(wire.Claim(failed, self._plan.slot(f), self._epoch))

    def _on_cert(self, cert: wire.Cert, now: float) -> None:
        f = self._plan.function_at(cert.function)
        if f is None:
            self._drops["bad_function"] += 1
            return
        if isinstance(cert.inner.msg, wire.Refute):
            self._on_refute(cert.inner.sender, cert.inner.msg, now, cert.raw)
            return
        said = cert_says(cert)
        if said is not None:
            self._record_evidence(f, *said, cert.raw, now)

    # ------------------------------------------------------------------ refutes
    # Per-robot mode (DESIGN, "Convergence"): a holder's signed word that it was alive
    # after a warning voids that warning everywhere the word reaches.

    def _refute(self, f: str, witness: int, epoch: int, seq: int, now: float) -> None:
        """We hold f at `epoch` and hear `witness`'s warning number `seq` about us: sign
        and broadcast that we are alive after it. Not out of a buffer read after our own
        stall: then the warning was right (we were silent), and the takeover it backs
        fences us (rule 2)."""
        if self._identity is None or self._role != Role.ACTIVE or f != self._function \
                or epoch != self._epoch or now - self._stalled_at <= self._params.t_max:
            return
        if witness not in self._ev.may_watch(f, claimants=True) \
                or seq <= self._ev.refuted_up_to(f, self._robot_id, epoch, witness):
            return
        msg = wire.Refute(witness, self._plan.slot(f), epoch, seq)
        self._ev.add_refute(f, self._robot_id, msg, self._send(msg))

    def _on_refute(self, holder: int, r: wire.Refute, now: float, raw: bytes) -> None:
        f = self._plan.function_at(r.function)
        if f is None:
            self._drops["bad_function"] += 1
            return
        if holder == self._robot_id:
            return  # our own, relayed back
        if self._ev.add_refute(f, holder, r, raw):
            self._rejudge(f, now)

    def _rejudge(self, f: str, now: float) -> None:
        """New refutes of f came: a takeover of f they void is undone here as
        everywhere they reach — our own hold or claim ends, and the view of f goes back
        to the robot that refuted (DESIGN, "Convergence")."""
        me = self._robot_id
        c = self._claim
        if c is not None and c.function == f and not self._ev.certify(
                f, me, wire.Claim(c.failed, self._plan.slot(f), c.epoch), 0):
            self._emit(ev.Refute(subject=c.failed, function=f))
            self._claim = None
            self._to(Trigger.REFUTED)
        for _ in range(len(self._plan.robots)):  # each step lowers the epoch
            holder, epoch = self._known[f]
            failed = self._ev.replaced(f, holder, epoch)
            if failed is None or epoch == 0 or self._ev.is_certified(f, holder, epoch):
                return
            self._known[f] = Holder(failed, epoch - 1)
            if holder == me and self._function == f and self._role == Role.ACTIVE:
                self._emit(ev.Fenced(function=f, epoch=epoch - 1))
                self._release()
                self._to(Trigger.FENCE)
                self._fenced_until = now + self._params.heartbeat_interval

    def _relay_refutes(self, f: str, now: float) -> None:
        """Someone acts on a takeover of f that refutes we hold void (an uncertified
        heartbeat or claim): relay them, inside CERTs (they may be older than its replay
        window), at most once per T_max."""
        if self._identity is None:
            return
        holder, epoch = self._known[f]
        for raw in self._ev.refute_frames(f, holder, epoch, now):
            self._send_cert(f, raw)

    def _emit(self, event: ev.Event) -> None:
        self._pending.append(event)

    def _drop(self, reason: str) -> list[Action]:
        self._drops[reason] += 1
        return self._drain()

    def _drain(self) -> list[Action]:
        """End of every entry point: hand the actions over, and remember the deadline the
        driver is about to arm, by which `_advance` tells our own stall."""
        if not self._stopped:
            self._armed = self.next_deadline()
        out, self._pending = self._pending, []
        return out


__all__ = ["Holder", "Node", "NodeError", "Restored", "Snapshot", "WatchState"]
