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

from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Broadcast, Event, Release
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.replay import ReplayFilter
from swarmd.core.roles import Health, Role, Trigger, transition
from swarmd.core.votes import VoteCounter
from swarmd.core.watchdog import SlotWatch, WatchState


@dataclass(frozen=True, slots=True)
class Restored:
    """What a restarted robot persisted (the runtime writes it atomically)."""

    known: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    """function -> (holder robot id, epoch) as last known."""
    held: tuple[str, int] | None = None
    """(function, epoch) this robot was executing when it stopped, if any."""


@dataclass(frozen=True, slots=True)
class Snapshot:
    """Read-only view for persistence, the monitor and tests."""

    robot_id: int
    role: Role
    function: str | None
    epoch: int
    health: Health
    known: Mapping[str, tuple[int, int]]
    suspects: Mapping[str, int]
    """function -> suspected holder, for the slots this robot currently warns about."""
    votes: Mapping[str, int]
    """function -> distinct witnesses counted now (standbys)."""
    drops: Mapping[str, int]
    seq: int


@dataclass(slots=True)
class _Claim:
    function: str
    failed: int
    old_epoch: int
    epoch: int
    until: float
    resend: float


class NodeError(RuntimeError):
    """Misuse of the node API (a bug in the driver), never caused by peer frames."""


class Node:
    def __init__(
        self,
        robot_id: int,
        plan: SwarmPlan,
        params: Params,
        now: float,
        *,
        keys: Sequence[bytes] = (),
        seq_start: int = 0,
        restored: Restored | None = None,
    ) -> None:
        if robot_id not in plan.robots:
            raise NodeError(f"robot {robot_id} is not in the swarm plan")
        self.robot_id = robot_id
        self.plan = plan
        self.params = params
        self.keys = tuple(keys)
        self.seq = seq_start
        self.health = Health.OK
        self.drops: Counter[str] = Counter()
        self.frames_in = 0
        self.frames_out = 0

        # function -> (holder, epoch): whoever executes each slot, as far as we know.
        self.known: dict[str, tuple[int, int]] = {}
        for f in plan.functions:
            holder = plan.initial_holder(f)
            self.known[f] = (holder if holder is not None else 0, 0)
        if restored is not None:
            for f, (holder, epoch) in restored.known.items():
                if f in self.known and epoch >= self.known[f][1]:
                    self.known[f] = (holder, epoch)

        self.covers = frozenset(f for f in plan.functions if robot_id in plan.covered_by(f))
        self.role = Role.STANDBY
        self.function: str | None = None
        self.epoch = 0
        self.watches: dict[str, SlotWatch] = {}
        self.votes: dict[str, VoteCounter] = {f: VoteCounter(params.vote_window)
                                              for f in self.covers}
        self.claim: _Claim | None = None
        self.fenced_until: float | None = None
        self.rejoin: tuple[str, int, float] | None = None
        self.heard_at: dict[int, float] = {}  # robot -> last frame accepted from it
        # function -> (holder, epoch, time) of the last heartbeat heard *for that slot*:
        # a robot that stopped heartbeating but still sends other frames (a faulty
        # liar) must not look alive to the standby that would replace it.
        self.slot_heard: dict[str, tuple[int, int, float]] = {}
        self.standby_at: dict[int, float] = {}  # standby robot -> last standby heartbeat
        self.replay = ReplayFilter()
        self.start_time = now
        self.next_heartbeat = now
        self.last_heartbeat = -1e18
        self.armed: float | None = now
        self.stopped = False
        self.started = False
        self._pending: list[Action] = []

        own = plan.robots[robot_id].function
        if restored is not None and restored.held is not None:
            # Rule 2 across a reboot: listen before resuming, a takeover may have
            # happened while this robot was down.
            f, epoch = restored.held
            if f in self.known:
                self.rejoin = (f, epoch, now + params.rejoin_hold)
        elif restored is None and own is not None:
            self.role = Role.ACTIVE
            self.function = own
            self.epoch = self.known[own][1]
            self._watch_neighbours(now)

    # ------------------------------------------------------------------ entry points
    def receive(self, data: bytes, now: float) -> list[Action]:
        """A frame from the channel. Never raises on peer input."""
        self._advance(now)
        if self.stopped:
            return self._drain()
        try:
            frame = wire.decode(data, self.keys)
        except wire.CodecError as exc:
            return self._drop(exc.reason)
        return self._accept(frame, now)

    def receive_frame(self, frame: wire.Frame, now: float) -> list[Action]:
        """A frame already decoded and verified with this swarm's keys. For simulators
        that deliver one broadcast to many nodes and decode it once; the runtime uses
        `receive`."""
        self._advance(now)
        if self.stopped:
            return self._drain()
        return self._accept(frame, now)

    def _accept(self, frame: wire.Frame, now: float) -> list[Action]:
        sender = frame.sender
        if frame.swarm_id != self.plan.swarm_id:
            return self._drop("swarm")
        if sender == self.robot_id:
            return self._drop("own")  # multicast loopback echoes our own frames
        if sender not in self.plan.robots:
            return self._drop("unknown_sender")
        if not self.replay.accept(sender, frame.seq):
            return self._drop("replay")
        self.frames_in += 1
        self.heard_at[sender] = now
        match frame.msg:
            case wire.Heartbeat() as hb:
                self._on_heartbeat(sender, hb, now)
            case wire.Warn() as w:
                self._on_warn(sender, w, now)
            case wire.Claim() as c:
                self._on_claim(sender, c, now)
            case wire.Leave() as lv:
                self._on_leave(sender, lv, now)
        return self._drain()

    def tick(self, now: float) -> list[Action]:
        """Fire every deadline that is due at `now`."""
        self._advance(now)
        if self.stopped:
            return self._drain()
        if not self.started:
            self._start(now)
        p = self.params
        if self.rejoin is not None and now >= self.rejoin[2]:
            self._finish_rejoin(now)
        if self.fenced_until is not None and now >= self.fenced_until:
            self.fenced_until = None
            self._to(Trigger.FENCE_DONE)
        if self.claim is not None:
            if now >= self.claim.until:
                self._take_over(now)
            elif now >= self.claim.resend:
                self.claim.resend = now + p.warn_interval
                self._send_claim()
        for g, watch in self.watches.items():
            if now >= watch.deadline:
                self._watch_fired(g, watch, now)
        if self._heartbeating() and now >= self.next_heartbeat:
            self._send_heartbeat(now)
            # No drift: the next one is due one period after the *deadline*.
            period = self._heartbeat_period()
            self.next_heartbeat += period
            if self.next_heartbeat <= now:
                self.next_heartbeat = now + period
        return self._drain()

    def robot_health(self, health: Health, now: float) -> list[Action]:
        """The robot's health (paper Fig. 4's single input; DESIGN rule 7)."""
        self._advance(now)
        if self.stopped or health == self.health:
            return self._drain()
        was_faulty = self.health == Health.FAULTY
        self.health = health
        if health == Health.FAULTY:
            if self.role == Role.ACTIVE and self.function is not None:
                f = self.function
                self._emit("leave", function=f, reason="fault")
                self._send(wire.Leave(self.plan.slot(f), self.epoch, wire.LeaveReason.FAULT))
                self._release()
            elif self.claim is not None:
                self.claim = None
            if self.rejoin is not None:
                self.rejoin = None  # a faulty robot resumes nothing: it is a standby now
                if self.started:
                    self._emit("started", role="standby", function=None)
            self._to(Trigger.FAULT)
            self._clear_votes()
        elif was_faulty:
            self.next_heartbeat = now  # back to heartbeating as a standby at once
        return self._drain()

    def stop(self, now: float, *, handover: bool) -> list[Action]:
        """Graceful stop. With `handover`, an ACTIVE robot sends LEAVE so a standby
        takes over without waiting for a timeout."""
        self._advance(now)
        if self.stopped:
            return self._drain()
        if self.role == Role.ACTIVE and self.function is not None:
            if handover:
                self._emit("leave", function=self.function, reason="shutdown")
                self._send(wire.Leave(self.plan.slot(self.function), self.epoch,
                                      wire.LeaveReason.SHUTDOWN))
            self._pending.append(Release(self.function))
        self._emit("stopped")
        self.stopped = True
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
        if not new and self.keys:
            raise NodeError("no swarm key given while frames are signed; turning signing "
                            "off needs a restart, not a key reload")
        self.keys = new

    def next_deadline(self) -> float | None:
        """When `tick` must be called next (absolute, same clock as `now`)."""
        if self.stopped:
            return None
        if not self.started:
            self.armed = self.start_time
            return self.armed
        candidates = [w.deadline for w in self.watches.values()]
        if self._heartbeating():
            candidates.append(self.next_heartbeat)
        if self.claim is not None:
            candidates.append(min(self.claim.until, self.claim.resend))
        if self.fenced_until is not None:
            candidates.append(self.fenced_until)
        if self.rejoin is not None:
            candidates.append(self.rejoin[2])
        self.armed = min(candidates) if candidates else None
        return self.armed

    def snapshot(self) -> Snapshot:
        return Snapshot(
            robot_id=self.robot_id,
            role=self.role,
            function=self.function,
            epoch=self.epoch,
            health=self.health,
            known=dict(self.known),
            suspects={g: self.known[g][0] for g, w in self.watches.items() if w.suspecting},
            votes={f: len(v.witnesses) for f, v in self.votes.items() if v.witnesses},
            drops=dict(self.drops),
            seq=self.seq,
        )

    # ------------------------------------------------------------------ message rules
    def _on_heartbeat(self, sender: int, hb: wire.Heartbeat, now: float) -> None:
        if hb.function == 0:
            if hb.role in (Role.STANDBY, Role.CLAIMING) and hb.health != Health.FAULTY:
                self.standby_at[sender] = now
            return
        f = self.plan.function_at(hb.function)
        if f is None:
            self.drops["bad_function"] += 1
            return
        holder, epoch = self.known[f]
        newer = hb.epoch > epoch or (hb.epoch == epoch and (sender == holder or sender < holder))
        if not newer:
            # A stale holder (e.g. back from a pause): if it is our slot, answer at once
            # so it hears the newer epoch and fences itself (rule 2) within a frame.
            if f == self.function and self.role == Role.ACTIVE:
                self._heartbeat_now(now)
            return
        self.known[f] = (sender, hb.epoch)
        self.slot_heard[f] = (sender, hb.epoch, now)
        # Rule 2: our own slot held at a higher epoch, or at ours by a lower id.
        if f == self.function and self.role == Role.ACTIVE and sender != self.robot_id:
            self._fence(hb.epoch, now)
            return
        watch = self.watches.get(f)
        if watch is not None:
            suspected = watch.suspecting
            if watch.heard(now) and suspected and hb.epoch == epoch and sender == holder:
                self._emit("refute", subject=sender, function=f)
        votes = self.votes.get(f)
        if votes is not None and votes.witnesses:
            votes.clear()  # rule 4: the suspect is alive, or a new holder is
        if self.claim is not None and self.claim.function == f:
            if hb.epoch >= self.claim.epoch:
                self._emit("backoff", subject=self.claim.failed, function=f, winner=sender)
                self.claim = None
                self._to(Trigger.SUPERSEDED)
            elif sender == self.claim.failed:
                self._emit("refute", subject=sender, function=f)
                self.claim = None
                self._to(Trigger.REFUTED)
        if self.rejoin is not None and self.rejoin[0] == f and sender != self.robot_id:
            self._rejoin_superseded(f, self.known[f][1])

    def _on_warn(self, sender: int, w: wire.Warn, now: float) -> None:
        f = self.plan.function_at(w.function)
        if f is None:
            self.drops["bad_function"] += 1
            return
        if w.suspect == self.robot_id:
            # Rule 4: a warning about ourselves is answered with a heartbeat at once.
            if self.role == Role.ACTIVE and f == self.function and self._heartbeat_now(now):
                self._emit("refute", subject=self.robot_id, function=f)
            return
        holder, epoch = self.known[f]
        if self.rejoin is not None and self.rejoin[0] == f:
            self._rejoin_superseded(f, w.epoch)
        if f not in self.covers or not self._standing_by():
            return
        if w.epoch < epoch or (w.epoch == epoch and w.suspect != holder):
            return  # about an older holder: stale
        # A warning at a newer epoch than we know means we missed a takeover (we were
        # partitioned, or lost its heartbeats) and the new holder may be dead already:
        # count it, keyed by (suspect, epoch), without believing it into `known` — a
        # single liar cannot reach the quorum, and the holder's heartbeat refutes it.
        # Rule 3: only the holders of the slots that watch f are witnesses; never the
        # suspect itself.
        witnesses = {self.known[g][0] for g in self.plan.watched_by(f)}
        if sender == w.suspect or sender not in witnesses:
            self.drops["not_witness"] += 1
            return
        votes = self.votes[f]
        fresh = sender not in votes.witnesses or (w.suspect, w.epoch) != (votes.subject,
                                                                          votes.epoch)
        count = votes.add(sender, w.suspect, w.epoch, now)
        if fresh:  # repeated warnings refresh a vote; only a new witness is an event
            self._emit("vote", subject=w.suspect, function=f, **{"from": sender}, count=count)
        if count >= self.params.quorum:
            # Rule 4 from our own ears: the channel is a broadcast, so the standby hears
            # the suspect too. Heard within T_max/2, the suspect is alive whatever the
            # witnesses missed (loss); after a real crash this is silent by the time
            # warnings come (they come T_max after the last heartbeat), so it costs no
            # latency. The next warning re-checks.
            heard = self.slot_heard.get(f)
            if heard is not None and heard[:2] == (w.suspect, w.epoch) \
                    and now - heard[2] < self.params.t_max / 2:
                return
            self._start_claim(f, w.suspect, w.epoch, now)

    def _on_claim(self, sender: int, c: wire.Claim, now: float) -> None:
        f = self.plan.function_at(c.function)
        if f is None:
            self.drops["bad_function"] += 1
            return
        if self.claim is not None and self.claim.function == f:
            # The paper's wait state: the lower id wins; a claim at a higher epoch
            # knows more than we do.
            mine = self.claim.epoch
            if c.epoch > mine or (c.epoch == mine and sender < self.robot_id):
                self._emit("backoff", subject=self.claim.failed, function=f, winner=sender)
                self.claim = None
                self._to(Trigger.BACKOFF)
            return
        if self.role == Role.ACTIVE and f == self.function:
            if c.failed == self.robot_id and c.epoch > self.epoch and self._heartbeat_now(now):
                self._emit("refute", subject=self.robot_id, function=f)
            return
        watch = self.watches.get(f)
        if watch is not None and c.epoch > self.known[f][1]:
            watch.claim_heard(now)  # paper: a claim tells the neighbours to stop warning
        votes = self.votes.get(f)
        if votes is not None:
            votes.clear()
        if self.rejoin is not None and self.rejoin[0] == f:
            self._rejoin_superseded(f, c.epoch)

    def _on_leave(self, sender: int, lv: wire.Leave, now: float) -> None:
        f = self.plan.function_at(lv.function)
        if f is None:
            self.drops["bad_function"] += 1
            return
        holder, epoch = self.known[f]
        if (sender, lv.epoch) != (holder, epoch):
            return  # not the current holder: stale
        watch = self.watches.get(f)
        if watch is not None:
            watch.claim_heard(now)
            if not self._live_standby(f, sender, now):
                watch.mark_alerted()
                self._emit("alert", function=f, reason="no standby left")
        if f in self.covers and self._standing_by():
            self._start_claim(f, sender, epoch, now, trigger=Trigger.LEAVE_HEARD)

    # ------------------------------------------------------------------ transitions
    def _start(self, now: float) -> None:
        self.started = True
        if self.rejoin is not None:
            return  # `started` tells the outcome once the rejoin hold is over
        self._emit("started", role=self.role.name.lower(), function=self.function)
        if self.role == Role.ACTIVE and self.function is not None:
            self._pending.append(Assign(self.function, self.epoch))

    def _start_claim(self, f: str, failed: int, epoch: int, now: float,
                     trigger: Trigger = Trigger.QUORUM) -> None:
        self._to(trigger)
        new_epoch = epoch + 1
        if new_epoch > 0xFFFF:
            new_epoch = 0xFFFF  # 65535 takeovers of one slot; saturate rather than wrap
        self.claim = _Claim(f, failed, epoch, new_epoch, now + self.params.claim_hold,
                            now + self.params.warn_interval)
        self._clear_votes()
        self._emit("claim", subject=failed, function=f, epoch=new_epoch)
        self._send_claim()

    def _send_claim(self) -> None:
        assert self.claim is not None
        c = self.claim
        self._send(wire.Claim(c.failed, self.plan.slot(c.function), c.epoch))

    def _take_over(self, now: float) -> None:
        assert self.claim is not None
        c, self.claim = self.claim, None
        self._to(Trigger.CLAIM_HELD)
        self.function, self.epoch = c.function, c.epoch
        self.known[c.function] = (self.robot_id, c.epoch)
        self._emit("takeover", function=c.function, epoch=c.epoch, replaced=c.failed)
        self._pending.append(Assign(c.function, c.epoch))
        self._watch_neighbours(now)
        self._restart_heartbeats(now)

    def _fence(self, epoch: int, now: float) -> None:
        f = self.function
        assert f is not None
        self._emit("fenced", function=f, epoch=epoch)
        self._release()
        self._to(Trigger.FENCE)
        self.fenced_until = now + self.params.heartbeat_interval

    def _release(self) -> None:
        if self.function is not None:
            self._pending.append(Release(self.function))
        self.function = None
        self.epoch = 0
        self.watches = {}

    def _finish_rejoin(self, now: float) -> None:
        assert self.rejoin is not None
        f, epoch, _ = self.rejoin
        self.rejoin = None
        holder, known_epoch = self.known[f]
        if known_epoch > epoch or (known_epoch == epoch and holder != self.robot_id
                                   and holder < self.robot_id):
            self._emit("started", role="standby", function=None)
            return
        self._to(Trigger.REJOIN)
        self.function, self.epoch = f, epoch
        self.known[f] = (self.robot_id, epoch)
        self._emit("started", role="active", function=f)
        self._pending.append(Assign(f, epoch))
        self._watch_neighbours(now)
        self._restart_heartbeats(now)

    def _rejoin_superseded(self, f: str, seen_epoch: int) -> None:
        """Someone holds, warns about or claims our old slot at `seen_epoch`: newer than
        the one we held (or held by another robot), we stay a standby. WARN and CLAIM
        do not update `known` (a liar must not move it), so their epoch is passed in."""
        assert self.rejoin is not None
        _, epoch, _ = self.rejoin
        if seen_epoch > epoch or self.known[f][1] > epoch or self.known[f][0] != self.robot_id:
            self.rejoin = None
            self._emit("started", role="standby", function=None)

    def _standing_by(self) -> bool:
        """A standby that may vote and claim (Fig. 9): not faulty, and not in the rejoin
        hold, where it still means to resume its own slot (rule 2 across a reboot) and
        must not take another one meanwhile."""
        return self.role == Role.STANDBY and self.health != Health.FAULTY \
            and self.rejoin is None

    def _to(self, trigger: Trigger) -> None:
        self.role = transition(self.role, trigger)

    # ------------------------------------------------------------------ watchdogs
    def _watch_neighbours(self, now: float) -> None:
        assert self.function is not None
        self.watches = {}
        for g in self.plan.watched(self.function):
            holder = self.known[g][0]
            self.watches[g] = SlotWatch(g, self.params, now, self.heard_at.get(holder))

    def _watch_fired(self, g: str, watch: SlotWatch, now: float) -> None:
        subject, epoch = self.known[g]
        fired = watch.fire(now)
        if fired.first:
            self._emit("suspect", subject=subject, function=g)
            self._emit("warn", subject=subject, function=g)
        elif fired.alert:
            self._emit("alert", function=g, reason="no claim")
        elif (not watch.alerted and watch.since is not None
              and now - watch.since >= self.params.t_max
              and not self._live_standby(g, subject, now)):
            # Rule 8, without waiting for alert_after: nobody can take over. Not on the
            # first fire: one more T_max of silence first, so loss alone rarely alerts.
            watch.mark_alerted()
            self._emit("alert", function=g, reason="no standby left")
        self._send(wire.Warn(subject, self.plan.slot(g), epoch))

    def _live_standby(self, f: str, subject: int, now: float) -> bool:
        """Is any robot that may take `f` over plausibly alive (rules 6, 8)? A standby
        never heard counts as alive during the start-up grace time only."""
        in_grace = now - self.start_time < self.params.startup_grace
        for r in self.plan.covered_by(f):
            if r in (subject, self.robot_id):
                continue
            seen = self.standby_at.get(r)
            if seen is None and in_grace:
                return True
            if seen is not None and now - seen <= self.params.standby_timeout:
                return True
        return False

    # ------------------------------------------------------------------ heartbeats
    def _heartbeating(self) -> bool:
        return not self.stopped and self.health != Health.FAULTY

    def _heartbeat_period(self) -> float:
        if self.role == Role.ACTIVE:
            return self.params.heartbeat_interval
        return self.params.standby_heartbeat_interval

    def _send_heartbeat(self, now: float) -> None:
        slot = self.plan.slot(self.function) if self.function is not None else 0
        self._send(wire.Heartbeat(slot, self.epoch if slot else 0, int(self.role),
                                  int(self.health)))
        self.last_heartbeat = now

    def _restart_heartbeats(self, now: float) -> None:
        """Became ACTIVE: heartbeat now and every heartbeat_interval from now on (the
        standby period would let the new neighbours' T_max run out)."""
        if self._heartbeating():
            self._send_heartbeat(now)
            self.next_heartbeat = now + self.params.heartbeat_interval

    def _heartbeat_now(self, now: float) -> bool:
        """An extra heartbeat out of schedule (refutation, fencing a stale holder),
        at most four per heartbeat period so a flood of warnings cannot amplify."""
        if not self._heartbeating():
            return False
        if now - self.last_heartbeat < self.params.heartbeat_interval / 4:
            return False
        self._send_heartbeat(now)
        return True

    # ------------------------------------------------------------------ plumbing
    def _advance(self, now: float) -> None:
        """Notice our own stall: called much later than our deadline (SIGSTOP, a
        suspended laptop), our silence is ours, not the neighbours'."""
        armed = self.armed
        if armed is not None and self.started and now - armed > self.params.t_max / 2:
            for w in self.watches.values():
                w.refresh(now)
            self._clear_votes()
            if self.claim is not None:
                self.claim.until = max(self.claim.until, now + self.params.claim_hold)
            self.next_heartbeat = now
            self.armed = None  # until the driver asks for the next deadline again

    def _clear_votes(self) -> None:
        for v in self.votes.values():
            v.clear()

    def _send(self, msg: wire.Message) -> None:
        self.seq = min(self.seq + 1, wire.SEQ_MAX)
        frame = wire.Frame(self.plan.swarm_id, self.robot_id, self.seq, msg)
        self._pending.append(Broadcast(wire.encode(frame, self.keys[0] if self.keys else None)))
        self.frames_out += 1

    def _emit(self, name: str, **fields: object) -> None:
        self._pending.append(Event(name, fields))

    def _drop(self, reason: str) -> list[Action]:
        self.drops[reason] += 1
        return self._drain()

    def _drain(self) -> list[Action]:
        out, self._pending = self._pending, []
        return out


__all__ = ["Node", "NodeError", "Restored", "Snapshot", "WatchState"]
