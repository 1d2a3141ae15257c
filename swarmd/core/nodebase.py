"""The state of one robot's node and the plumbing every rule uses (DESIGN section 2):
the role and its data, the one way a role changes (`_to`), sending, signing and events,
the receive-side checks every message shares, and our own heartbeats and their schedule.

`NodeBase` is the bottom layer of `Node` (`node.py`), which stacks one class on the
next, each calling only methods defined in itself or below: `NodeBase` <- `Views`
(`views.py`: a slot's view moves forward) <- `Proofs` (`proofs.py`: proofs relayed and
refutes) <- `Episode` (`episode.py`: the takeover episode, suspicion to takeover) <-
`Hearing` (`hearing.py`: heartbeats, LEAVE, CERT) <- `Restart` (`restart.py`: what a
robot starts from) <- `Node` (the entry points). They share the state declared here,
set up once by `Node.__init__`; drivers see it only through `Node.snapshot()`.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

from swarmd.core import digest, wire
from swarmd.core import events as ev
from swarmd.core.actions import Action, Broadcast
from swarmd.core.auth import Identity, Signer, Verifier
from swarmd.core.chain import OwnChain, PeerChains
from swarmd.core.claims import ClaimMemory, WaitState
from swarmd.core.drops import DropReason
from swarmd.core.errors import TransitionError
from swarmd.core.events import Event
from swarmd.core.evidence import EvidenceStore
from swarmd.core.heartbeat import HeartbeatClock
from swarmd.core.params import Params
from swarmd.core.plan import Relevant, SwarmPlan
from swarmd.core.rejoin import Rejoin
from swarmd.core.replay import ReplayFilter
from swarmd.core.roles import Health, Role, Trigger, transition
from swarmd.core.slots import SlotTable
from swarmd.core.state import NO_WATCHES, Active, Claiming, Rejoining, RoleState, Standby
from swarmd.core.votes import VoteCounter
from swarmd.core.watchdog import SlotWatch
from swarmd.core.witness import Ears
from swarmd.core.words import LatestWords

# Enum members read through their class cost ~120 ns each on CPython 3.11 (measured with
# timeit), a module constant ~10: the ones read for every frame heard, bound once.
_FAULTY = Health.FAULTY


class NodeBase:
    _robot_id: int
    _plan: SwarmPlan
    _params: Params
    _keys: tuple[bytes, ...]
    _identity: Identity | None
    _signer: Signer | None
    _verifier: Verifier | None
    _seq: int
    """Our own sequence counter (a clock: DESIGN, "Sequence numbers")."""
    _seq_start: int
    _health: Health
    _drops: Counter[str]
    _frames_in: int
    _frames_out: int
    _known: SlotTable
    """function -> (holder, epoch): whoever executes each slot, as far as we know; it
    only moves forward (`slots.py`)."""
    _covers: frozenset[str]
    _relevant: Relevant
    _state: RoleState
    """What this robot is doing, with that role's data (`state.py`)."""
    _votes: dict[str, VoteCounter]
    _heard_at: dict[int, float]
    """robot -> last frame accepted from it."""
    _ears: Ears
    _claims_seen: ClaimMemory
    _replay: ReplayFilter
    _ev: EvidenceStore
    _start_time: float
    _stalled_at: float
    _beat: HeartbeatClock
    _chain: OwnChain | None
    """Per-robot mode: our heartbeats' hash chain (`chain.py`)."""
    _chains: PeerChains
    """Per-robot mode: where each peer's chain stands, as we verified it."""
    _words: LatestWords
    """What each peer last said of itself, to refuse its older word that contradicts it
    (`words.py`)."""
    _shown_newer: set[str]
    """Slots we hold of which a live robot's warning named us at a newer epoch than
    ours (it took a recorded takeover that our refute voids: our reassertion must be
    verifiable, `Episode._record_evidence`)."""
    _anchor_every: float
    _resync_after: float
    _armed: float | None
    """The deadline the driver was last given: a call far past it is our own stall,
    not the neighbours' silence (`Node._advance`)."""
    _stopped: bool
    _started: bool
    _pending: list[Action]

    # ------------------------------------------------------------------ the role
    # Read-only views of `_state`: a role's data exists only while the robot has that
    # role, and changes only with it (`_to`).
    @property
    def _role(self) -> Role:
        return self._state.role

    @property
    def _function(self) -> str | None:
        return self._state.function if isinstance(self._state, Active) else None

    @property
    def _epoch(self) -> int:
        return self._state.epoch if isinstance(self._state, Active) else 0

    @property
    def _watches(self) -> Mapping[str, SlotWatch]:
        return self._state.watches if isinstance(self._state, Active) else NO_WATCHES

    @property
    def _claim(self) -> WaitState | None:
        return self._state.wait if isinstance(self._state, Claiming) else None

    @property
    def _rejoin(self) -> Rejoin | None:
        return self._state.rejoin if isinstance(self._state, Rejoining) else None

    def _to(self, trigger: Trigger, state: RoleState) -> None:
        """The one way a role changes: `trigger` must lead from the current role to
        `state`'s in the table (`roles.TRANSITIONS`), which raises `TransitionError`
        otherwise."""
        role = transition(self._state.role, trigger)
        if role != state.role:
            raise TransitionError(f"{trigger.name} leads {self._state.role.name} to "
                                  f"{role.name}, not {state.role.name}")
        self._state = state

    def _back_off(self, winner: int, trigger: Trigger = Trigger.SUPERSEDED) -> None:
        """Our claim ends in the wait state: `winner` holds or claims the slot at its
        epoch or higher (the paper's lowest id, or a greater entry)."""
        c = self._claim
        assert c is not None
        self._emit(ev.Backoff(subject=c.failed, function=c.function, winner=winner))
        self._to(trigger, Standby())

    def _claim_refuted(self) -> None:
        """Our claim ends in the wait state, refuted: its suspect is alive (rule 4), or
        the certificate behind it no longer holds. The log says `refute` about the
        suspect."""
        c = self._claim
        assert c is not None
        self._emit(ev.Refute(subject=c.failed, function=c.function))
        self._to(Trigger.REFUTED, Standby())

    # ------------------------------------------------------------------ plumbing
    def _send(self, msg: wire.Message) -> bytes:
        data = self._next_frame(msg)
        self._pending.append(Broadcast(data))
        self._frames_out += 1
        return data

    def _next_frame(self, msg: wire.Message) -> bytes:
        """`msg` as our next frame, not broadcast by itself (`_send` broadcasts it; a
        certificate may carry it): every frame we make takes the next seq. Signed per
        robot, tagged with a shared key."""
        self._seq = min(self._seq + 1, wire.SEQ_MAX)
        frame = wire.Frame(self._plan.swarm_id, self._robot_id, self._seq, msg)
        return wire.encode(frame, self._keys[0] if self._keys else None, self._signer)

    def _emit(self, event: Event) -> None:
        self._pending.append(event)

    def _peer_back(self, sender: int, now: float) -> None:
        """Per-robot mode: a frame of `sender`, verified or not. Back after a silence
        long enough to have lost our chain, it gets anchors from us (`chain.py`)."""
        chain = self._chain
        if chain is None:  # a shared key or unsigned: no chain, nothing to look up
            return
        last = self._heard_at.get(sender)
        if last is not None and now - last > self._resync_after:
            chain.reanchor(now, self._resync_after)

    def _slot(self, index: int) -> str | None:
        """The function at wire slot `index`; None (and a `bad_function` drop) if the
        plan has none there."""
        f = self._plan.function_at(index)
        if f is None:
            self._drops[DropReason.BAD_FUNCTION] += 1
        return f

    def _outdated(self, sender: int, seq: int, msg: wire.Message, now: float) -> bool:
        """`sender`'s frame number `seq` is older than its own later word, heard already,
        that contradicts it (`words.py`: a recording of an earlier run, or a reordered
        frame). Its `LEAVE` that it refuted itself, once it heartbeats a reassertion
        above it, is kept as the void backer it is (`evidence.py`): that reassertion
        rests on the certificate the `LEAVE` backs, and every robot must verify it
        alike; so is a `CLAIM` its claimant gave up, below the reassertion of the holder
        it named."""
        if isinstance(msg, wire.Leave) and sender != self._robot_id \
                and not self._words.knows(sender) \
                and now - self._start_time < self._params.startup_grace \
                and not self._words.slot_above(msg.function, msg.epoch):
            # Within our start-up grace we may not have heard its word yet (per robot an
            # anchor comes every `anchor_every`, half the grace): its LEAVE cannot be
            # judged, and a recorded takeover it backs, taken here alone, would move the
            # slot's epoch everywhere in the end (the holder's reassertion). After the
            # grace, a robot we never heard is dead or cut off, and its LEAVE (relayed
            # with the takeover it backs) counts. So it does within the grace once a
            # robot's own word (authenticated, `words.py`) holds the slot above the
            # LEAVE's entry: epochs start from 0 in every run, so this run is past that
            # entry already and the LEAVE moves it nowhere it has not been. That is a
            # robot restarted without its state file as the plan's holder of a slot
            # handed over twice since: the new holder's proof rests on the LEAVE of a
            # robot gone, and waiting the grace for that robot's word would leave two
            # executors for the whole grace. Our own LEAVE is no word to wait for:
            # from before this start, it is refuted at once if we hold its entry
            # (`Episode._record_evidence`), rather than held off for the grace while
            # the takeover it backs executes beside us.
            return True
        if not self._words.outdated(sender, seq, msg):
            return False
        if isinstance(msg, wire.Leave) and self._words.above(sender, msg.function, msg.epoch):
            # Its signer refuted it and heartbeats a reassertion above it: somewhere the
            # recording was taken, and this LEAVE is the void backer of that reassertion.
            f = self._plan.function_at(msg.function)
            return f is None or self._ev.refuted_up_to(f, sender, msg.epoch, sender) < seq
        if isinstance(msg, wire.Claim):
            # The holder it named heartbeats a reassertion above it, or is us and a live
            # robot's warning showed us that it took the claim (`_shown_newer`):
            # the claim is the void backer of that reassertion, kept to verify it.
            return not (self._words.above(msg.failed, msg.function, msg.epoch)
                        or (msg.failed == self._robot_id
                            and self._plan.function_at(msg.function) in self._shown_newer))
        return True

    def _clear_votes(self) -> None:
        for v in self._votes.values():
            v.clear()

    def _standing_by(self) -> bool:
        """A standby that may vote and claim (Fig. 9): not faulty. A rejoining robot is
        not one: it still means to resume its own slot (rule 2 across a reboot) and must
        not take another one meanwhile."""
        return self._role == Role.STANDBY and self._health != Health.FAULTY

    def _holds(self, f: str) -> bool:
        """Do we execute slot f now (ACTIVE on it: only `Active` has a function)?"""
        return f == self._function

    def _heartbeating(self) -> bool:
        return not self._stopped and self._health != _FAULTY

    # ------------------------------------------------------------------ heartbeats
    def _send_heartbeat(self, now: float, *, extra: bool = False) -> None:
        slot = self._plan.slot(self._function) if self._function is not None else 0
        # A rejoining robot is a standby to the others until it resumes (rule 6).
        role = Role.STANDBY if self._role == Role.REJOINING else self._role
        # Without a slot, the epoch field carries our view of the slots we cover: whoever
        # holds a greater entry for one of them sees it differs and sends it (`digest.py`).
        epoch = self._epoch if slot else digest.make(self._plan.covered(self._robot_id),
                                                     self._known)
        n, link, anchor = 0, b"", False  # a shared key or unsigned: no chain
        if self._chain is not None:
            # Per-robot mode: the next link of our chain; an anchor (signed) where a
            # receiver may have lost it (`chain.py`). A change of digest is no change of
            # what we say of ourselves: it is never believed as proof, so it needs no
            # anchor of its own.
            said = (slot, epoch if slot else 0, int(role))
            n, link, anchor = self._chain.next(now, said, self._anchor_every, extra=extra)
        self._send(wire.Heartbeat(slot, epoch, int(role), int(self._health), n, link, anchor))
        self._beat.sent(now)

    def _heartbeat_now(self, now: float) -> bool:
        """An extra heartbeat out of schedule (refutation, fencing a stale holder),
        at most four per heartbeat period so a flood of warnings cannot amplify."""
        if not self._heartbeating() or not self._beat.extra_allowed(now):
            return False
        self._send_heartbeat(now, extra=True)
        return True


__all__ = ["NodeBase"]
