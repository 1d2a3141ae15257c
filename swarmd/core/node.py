"""The protocol node: one robot's failure handling, sans-IO (DESIGN section 2).

Shaped like aioquic's `QuicConnection`: every entry point takes `now` (monotonic
seconds) and returns the actions to execute; `next_deadline()` says when `tick` must
be called next. Nothing here does I/O, reads a clock or draws a random number.

What happens where:
- `receive`: decode and filter a frame (peer garbage becomes a counted drop, never an
  exception), then the per-message rules (`hearing.py`; WARN and CLAIM `episode.py`;
  REFUTE `proofs.py`).
- `tick`: deadlines — own heartbeat (`nodebase.py`), watchdogs (Fig. 7) and claim hold
  (the wait state; `episode.py`), fence hold, rejoin hold (`restart.py`).
- `robot_health`: the robot's single input (Fig. 4); FAULTY sends LEAVE (rule 7).
- `stop`: graceful stop, LEAVE when asked to hand over.
- the constructor: the plan's holders, or what a restarted robot persisted
  (`restart.py`: its own hold resumed only after listening).

Roles and transitions are the table in `roles.py`; every change of role goes through
`NodeBase._to()`, which enforces it. The state is declared in `nodebase.py`. `Node` is
the top layer: it sits on `Restart`, `Hearing`, `Episode`, `Proofs`, `Views` and
`NodeBase`, each on the next, each calling only itself and what is below it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from types import MappingProxyType

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Action, Broadcast, Release
from swarmd.core.auth import Identity
from swarmd.core.chain import OwnChain, PeerChains, anchor_every, resync_after
from swarmd.core.claims import ClaimMemory
from swarmd.core.drops import DropReason
from swarmd.core.errors import NodeError
from swarmd.core.evidence import EvidenceStore
from swarmd.core.heartbeat import HeartbeatClock
from swarmd.core.limits import check_keys, check_restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.records import Holder, Restored, Snapshot, Standing
from swarmd.core.replay import ReplayFilter, header_seq
from swarmd.core.restart import Restart
from swarmd.core.roles import Health, Trigger
from swarmd.core.state import Active, Fenced, Standby
from swarmd.core.votes import VoteCounter
from swarmd.core.watchdog import WatchState
from swarmd.core.witness import Ears
from swarmd.core.words import LatestWords

ECHO_MEMORY = 64
"""Frames this node sent lately, kept byte for byte (`Node._echoes`): a multicast
channel hands each back within milliseconds; this is seconds of a robot's own traffic
(10 Hz heartbeats and the warnings, claims and certificates of a failover)."""


# Enum members read through their class cost ~120 ns each on CPython 3.11 (measured with
# timeit), a module constant ~10: the ones read for every frame heard, bound once.
_HEARTBEAT, _CERT = wire.MsgType.HEARTBEAT, wire.MsgType.CERT


class Node(Restart):
    """One robot's protocol state. Its state is private: drivers read `snapshot()` and
    the few read-only properties below."""

    def __init__(self, robot_id: int, plan: SwarmPlan, params: Params, now: float, *,
                 keys: Sequence[bytes] = (), identity: Identity | None = None,
                 seq_start: int = 0, restored: Restored | None = None) -> None:
        if robot_id not in plan.robots:
            raise NodeError(f"robot {robot_id} is not in the swarm plan")
        check_restored(restored, seq_start)  # out-of-range state: refuse, never loop
        self._robot_id, self._plan, self._params = robot_id, plan, params
        self._keys, self._identity = tuple(keys), identity
        self._signer, self._verifier = identity if identity is not None else (None, None)
        self._seq = self._seq_start = seq_start
        self._health = Health.OK
        self._drops = Counter()
        self._frames_in = self._frames_out = 0
        self._known = self._views(restored)
        self._covers = frozenset(plan.covered(robot_id))
        self._relevant = plan.relevant(robot_id)
        self._state = Standby()
        self._votes = {f: VoteCounter.of(params) for f in self._covers}
        self._heard_at = {}
        self._ears = Ears(robot_id, plan, params, now)
        self._claims_seen = ClaimMemory(params)
        self._replay = ReplayFilter(seq_start, now)  # bounded by our own clock
        self._ev = EvidenceStore(robot_id, plan, params)  # certificates, `evidence.py`
        self._start_time, self._stalled_at = now, -1e18
        self._beat = HeartbeatClock(params, now)
        self._chain = OwnChain(robot_id, self._signer, seq_start) if self._signer else None
        self._chains = PeerChains(1 / params.heartbeat_interval)
        # What each peer last said of itself (`words.py`).
        self._words, self._shown_newer = LatestWords(), set()
        self._anchor_every, self._resync_after = anchor_every(params), resync_after(params)
        self._armed = now
        self._stopped = self._started = False
        self._pending = []
        self._echoes: dict[bytes, None] = {}
        """The last `ECHO_MEMORY` frames sent, oldest first (an ordered set): `receive`
        knows their echoes without decoding them again."""
        if restored is not None:
            self._restore(restored, now)
        elif (own := plan.robots[robot_id].function) is not None:
            self._state = Active(own, self._known[own].epoch)
            self._watch_neighbours(now)

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

    def patience(self, robot: int) -> float:
        """s of silence of `robot`'s slot heartbeats after which this robot suspects it:
        its belief of that link (DESIGN "Detection"; `t_max` for a clean or unmeasured
        link, up to `t_max_bursty`)."""
        return self._ears.patience(robot)

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
                standby_beat=head.mtype == _HEARTBEAT and head.slot == 0):
            # Before the HMAC and any state: a daemon's cost follows its neighbourhood,
            # not the swarm. No deadline moved, so there is nothing to hand back.
            self._drops[DropReason.IRRELEVANT] += 1
            return []
        self._advance(now)
        if self._stopped:
            return self._drain()
        if head is not None and head.sender == self._robot_id and data in self._echoes \
                and head.mtype != _CERT:
            # Our own frame back from the channel, byte for byte as we sent it with the
            # keys in force (`set_keys` and `revoke` forget what was sent before): it
            # decodes, and `_accept` drops it as `own` (`_own_frame`, its seq is ours
            # since the start), so the echo of every frame sent costs no second check
            # of its tag or signature. A CERT goes to `_on_cert` whoever relays it.
            return self._drop(DropReason.OWN)
        if head is not None and head.swarm_id == self._plan.swarm_id \
                and head.sender != self._robot_id and head.sender in self._plan.robots \
                and head.mtype != _CERT:
            # Cheap checks before the tag or signature (DESIGN "Who can still do what"):
            # a frame played back, or beyond the clock bound, costs no signature check.
            stale = self._replay.stale(head.sender, header_seq(data), now)
            if stale is not None:
                return self._drop(stale)
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
        about = msg.suspect if isinstance(msg, wire.Warn) else \
            msg.failed if isinstance(msg, wire.Claim) else 0
        if self._irrelevant(frame.swarm_id, frame.sender, msg.function, about,
                            standby_beat=isinstance(msg, wire.Heartbeat) and msg.function == 0):
            self._drops[DropReason.IRRELEVANT] += 1
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
        """A decoded frame."""
        sender = frame.sender
        if frame.swarm_id != self._plan.swarm_id:
            return self._drop(DropReason.SWARM)
        if sender not in self._plan.robots:
            return self._drop(DropReason.UNKNOWN_SENDER)
        if isinstance(frame.msg, wire.Cert):
            # Not through the replay filter: the wrapper is unauthenticated (what it
            # relays is judged on its own), so it must move no counter.
            self._on_cert(frame.msg, now)
            return self._drain()
        if sender == self._robot_id:
            return self._own_frame(frame)
        msg = frame.msg
        if isinstance(msg, wire.Heartbeat) and self._verifier is not None \
                and not self._chains.check(sender, msg.n, msg.link, now, anchor=msg.anchor):
            # Before the replay filter: a heartbeat not from its sender moves no counter.
            self._peer_back(sender, now)  # it may have lost our chain as we lost its
            self._unproven_beat(self._plan.function_at(msg.function), msg,
                                DropReason.UNANCHORED, now)
            return self._drain()
        reason = self._replay.check(sender, frame.seq, now)
        if reason is not None:
            return self._drop(reason)
        if self._outdated(sender, frame.seq, msg, now):
            # Its own later heartbeat says otherwise: a recording of an earlier run, or
            # a frame reordered behind it (DESIGN, "Every proof is bound to its run").
            return self._drop(DropReason.OUTDATED)
        self._on_message(frame, now)
        return self._drain()

    def _on_message(self, frame: wire.Frame, now: float) -> None:
        """A frame through every receive filter: the per-message rules (`hearing.py`,
        `episode.py`, `proofs.py`)."""
        sender = frame.sender
        self._frames_in += 1
        self._peer_back(sender, now)
        self._heard_at[sender] = now
        match frame.msg:
            case wire.Heartbeat() as hb:
                if self._verifier is not None:
                    self._chains.commit(sender, hb.n, hb.link, now, anchor=hb.anchor)
                # The slot it names, looked up once for the rules below (the plan is
                # fixed for the node's life).
                f = self._plan.function_at(hb.function) if hb.function else None
                self._on_heartbeat(sender, hb, now)
                # Its seq bound to its sender (a swarm key's tag, per robot an anchor,
                # or unsigned anything): its word.
                if hb.anchor or self._keys or self._verifier is None:
                    self._heard_word(sender, frame.seq, hb, f, self._replay.top(sender))
            case wire.Warn() as w:
                self._on_warn(sender, w, now, frame.raw, frame.seq)
            case wire.Claim() as c:
                self._on_claim(sender, c, now, frame.raw)
            case wire.Leave() as lv:
                self._on_leave(sender, lv, now, frame.raw)
            case wire.Refute() as rf:
                self._on_refute(sender, rf, now, frame.raw)

    def _own_frame(self, frame: wire.Frame) -> list[Action]:
        """A verified frame sent as this robot. Multicast loopback echoes our own frames
        (`own`; the runtime tells a second daemon with our id by frames it did not send).
        One from before this node started is a replay, not a duplicate robot
        (`replay`). Either way it moves none of our counters: a robot's seq, epoch and
        chain move only on what it sends itself, so a frame in its name from elsewhere
        (a forger, a second daemon with our id) cannot push our counter past what the
        receivers accept (DESIGN section 2, "Sequence numbers"); the receivers' filter
        keeps hearing our next frames even if it took the forged one (`replay.py`)."""
        return self._drop(DropReason.REPLAY if frame.seq < self._seq_start else DropReason.OWN)

    def _heard_word(self, sender: int, seq: int, hb: wire.Heartbeat, f: str | None,
                    top: int | None) -> None:
        """A heartbeat (for slot `f`) we believed, whose seq is bound to its sender (a
        swarm key's tag, per robot an anchor, or unsigned anything: `_on_message`
        checks), sets its sender's latest word (`words.py`) if it is the top of the
        sender's own run (`top`, `ReplayFilter.top`: not a lone frame far ahead, which
        would make the sender's own next frames `outdated`). A hold we did not believe
        (uncertified, outranked) sets nothing: an insider's own anchor at a forged epoch
        must not make its real heartbeats `outdated`."""
        self._words.held(sender, hb)
        if (top is None or seq >= top) and (
                hb.function == 0 or (f is not None and self._known[f] == (sender, hb.epoch))):
            self._words.heard(sender, seq, hb)

    def tick(self, now: float) -> list[Action]:
        """Fire every deadline that is due at `now`."""
        self._advance(now)
        if self._stopped:
            return self._drain()
        if not self._started:
            self._start()
        if self._rejoin is not None and now >= self._rejoin.until:
            self._finish_rejoin(now)
        if isinstance(self._state, Fenced) and now >= self._state.until:
            self._to(Trigger.FENCE_DONE, Standby())
        self._claim_due(now)
        for g, watch in self._watches.items():
            if now >= watch.deadline:
                self._watch_fired(g, watch, now)
        if self._heartbeating() and now >= self._beat.next:
            self._send_heartbeat(now)
            self._show_unasked(now)
            self._beat.scheduled(now, self._role)
        return self._drain()

    def robot_health(self, health: Health, now: float) -> list[Action]:
        """The robot's health (paper Fig. 4's single input; DESIGN rule 7)."""
        self._advance(now)
        if self._stopped or health == self._health:
            return self._drain()
        was_faulty = self._health == Health.FAULTY
        self._health = health
        if health == Health.FAULTY:
            if self._function is not None:
                f = self._function
                self._leave(f, ev.LeaveCause.FAULT, wire.LeaveReason.FAULT)
                self._pending.append(Release(f))
            if self._rejoin is not None and self._started:
                # A faulty robot resumes nothing: it is a standby now.
                self._emit(ev.Started(role=ev.RoleName.STANDBY, function=None))
            state = self._state
            self._to(Trigger.FAULT, state if isinstance(state, Fenced) else Standby())
            self._clear_votes()
        elif was_faulty:
            self._beat.next = now  # back to heartbeating as a standby at once
        return self._drain()

    def stop(self, now: float, *, handover: bool) -> list[Action]:
        """Graceful stop. With `handover`, an ACTIVE robot sends LEAVE so a standby
        takes over without waiting for a timeout."""
        self._advance(now)
        if self._stopped:
            return self._drain()
        if self._function is not None:
            if handover:
                self._leave(self._function, ev.LeaveCause.SHUTDOWN, wire.LeaveReason.SHUTDOWN)
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
        `auth`. Raises `NodeError` (and changes nothing) for keys `limits.check_keys`
        refuses: turning signing off takes a restart."""
        self._keys = check_keys(keys, signing=bool(self._keys))
        self._echoes.clear()  # a frame tagged with a key no longer listed is `auth` now

    def revoke(self, robots: Iterable[int]) -> None:
        """Per-robot mode: these robots' keys were revoked (SIGHUP; docs/operations.md).
        Their frames no longer verify, and what this node knew of their heartbeat chains
        is forgotten, so from now on they are silent to it: their slots are taken over
        as a dead robot's (DESIGN, "Who may say what")."""
        gone = tuple(robots)
        self._chains.forget(gone)
        self._words.forget(gone)
        # The keyring changed with this call (SIGHUP): our own key may be another now,
        # and our echoes are checked again like any frame.
        self._echoes.clear()

    def next_deadline(self) -> float | None:
        """When `tick` must be called next (absolute, same clock as `now`). Every entry
        point ends in `_drain`, which works it out once (a driver asks after each)."""
        if self._stopped:
            return None
        return self._armed if self._armed is not None else self._deadline()

    def _deadline(self) -> float | None:
        if not self._started:
            return self._start_time
        # Worked out at the end of every entry point (`_drain`), so once per frame heard:
        # the common case (an active robot's heartbeats and watchdogs, or a standby's
        # heartbeats) reads the role once and builds no list.
        state = self._state
        best = self._beat.next if self._heartbeating() else None
        if isinstance(state, Active):
            for w in state.watches.values():
                if best is None or w.deadline < best:
                    best = w.deadline
        if isinstance(state, Active | Standby):
            return best
        return self._rare_deadline(best)

    def _rare_deadline(self, best: float | None) -> float | None:
        """`_deadline` beyond heartbeats and watchdogs (`best`, the earliest of those):
        a claim's wait, a fence, a rejoin's hold."""
        candidates = [] if best is None else [best]
        if self._claim is not None:
            c = self._claim
            candidates.append(min(c.until, c.resend))
        if isinstance(self._state, Fenced):
            candidates.append(self._state.until)
        if self._rejoin is not None:
            candidates.append(self._rejoin.until)
        return min(candidates) if candidates else None

    def standing(self) -> Standing:
        """Role, slot table and seq, without copying the rest of the state (`snapshot`)."""
        return Standing(self._role, self._function, self._epoch,
                        tuple(sorted(self._known.items())), self._seq)

    def snapshot(self) -> Snapshot:
        return Snapshot(
            robot_id=self._robot_id, role=self._role, function=self._function,
            epoch=self._epoch, health=self._health, known=dict(self._known),
            suspects={g: self._known[g].robot for g, w in self._watches.items() if w.suspecting},
            votes={f: len(v.witnesses) for f, v in self._votes.items() if v.witnesses},
            drops=dict(self._drops), seq=self._seq, frames_in=self._frames_in,
            frames_out=self._frames_out, heard=dict(self._heard_at),
            peer_seq=self._replay.tops(),
            certificate=self._ev.certificate(self._function),
        )

    # ------------------------------------------------------------------ plumbing
    def _advance(self, now: float) -> None:
        """Notice our own stall: called much later than our deadline (SIGSTOP, a
        suspended laptop), our silence is ours, not the neighbours'."""
        armed = self._armed
        if armed is not None and self._started and now - armed > self._params.t_max / 2:
            for w in self._watches.values():
                w.refresh(now)
            self._ears.forget_gaps()  # the gap was ours: no sample of any link
            self._clear_votes()
            if self._claim is not None:
                self._claim.until = max(self._claim.until, now + self._params.claim_hold)
            self._beat.next = now
            self._stalled_at = now
            self._armed = None  # noticed once; `_drain` arms the next deadline

    def _leave(self, f: str, cause: ev.LeaveCause, reason: wire.LeaveReason) -> None:
        """We leave f, which we hold (rule 7): the event and a LEAVE. Our own LEAVE is
        evidence for its handover like anyone's (`Hearing._on_leave`): kept here too, so
        a certificate relayed from us can carry it."""
        self._emit(ev.Leave(function=f, reason=cause))
        data = self._send(wire.Leave(self._plan.slot(f), self._epoch, reason))
        self._record_evidence(f, self._robot_id, self._robot_id, self._epoch, data)

    def _drop(self, reason: str) -> list[Action]:
        """Count a refused frame. A drop moves no state, so the deadline `_drain` worked
        out at the end of the previous entry point still stands and is not worked out
        again: unless `_advance` noticed our own stall in this call (it then cleared
        `_armed`), or something is pending."""
        self._drops[reason] += 1
        if self._armed is not None and not self._pending:
            return []
        return self._drain()

    def _drain(self) -> list[Action]:
        """End of every entry point: hand the actions over, and remember the deadline the
        driver is about to arm, by which `_advance` tells our own stall."""
        if not self._stopped:
            self._armed = self._deadline()
        out, self._pending = self._pending, []
        if out:
            self._remember_sent(out)
        return out

    def _remember_sent(self, actions: list[Action]) -> None:
        """The frames among `actions` into `_echoes`, the oldest forgotten past
        `ECHO_MEMORY`."""
        echoes = self._echoes
        for action in actions:
            if isinstance(action, Broadcast):
                echoes[action.frame] = None
        while len(echoes) > ECHO_MEMORY:
            del echoes[next(iter(echoes))]


__all__ = ["Holder", "Node", "NodeError", "Restored", "Snapshot", "Standing",
           "WatchState"]
