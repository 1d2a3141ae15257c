"""The state of one robot's node and the plumbing every rule uses (DESIGN section 2).

`Node` (`node.py`) is assembled from this base and four rule modules: `hearing.py`
(what a robot does with each message), `moves.py` (how its role changes), `signed.py`
(per-robot evidence) and `restart.py` (what a restarted robot starts from). They share
the state declared here, set up once by `Node.__init__`; drivers see it only through
`Node.snapshot()`. The methods a rule module calls in another are declared here and
defined there.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

from swarmd.core import events as ev
from swarmd.core import wire
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
from swarmd.core.records import Holder, Restored
from swarmd.core.rejoin import Rejoin
from swarmd.core.replay import ReplayFilter
from swarmd.core.roles import Health, Role, Trigger, transition
from swarmd.core.slots import SlotTable
from swarmd.core.state import NO_WATCHES, Active, Claiming, Rejoining, RoleState, Standby
from swarmd.core.votes import VoteCounter
from swarmd.core.watchdog import SlotWatch
from swarmd.core.witness import Ears
from swarmd.core.words import LatestWords


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
    """Per robot: slots we hold of which a live robot's signed warning named us at a
    newer epoch than ours (it took a recorded takeover that our refute voids: our
    reassertion must be verifiable, `Signed._record_evidence`)."""
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

    # ------------------------------------------------------------------ plumbing
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

    def _emit(self, event: Event) -> None:
        self._pending.append(event)

    def _peer_back(self, sender: int, now: float) -> None:
        """Per-robot mode: a frame of `sender`, verified or not. Back after a silence
        long enough to have lost our chain, it gets anchors from us (`chain.py`)."""
        last = self._heard_at.get(sender)
        if self._chain is not None and last is not None and now - last > self._resync_after:
            self._chain.reanchor(now, self._resync_after)

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
        frame). Per robot, its `LEAVE` that it refuted itself, once it heartbeats a
        reassertion above it, is kept as the void backer it is (`evidence.py`): that
        reassertion rests on the certificate the `LEAVE` backs, and every robot must
        verify it alike."""
        if isinstance(msg, wire.Leave) and self._identity is not None \
                and not self._words.knows(sender) \
                and now - self._start_time < self._params.startup_grace:
            # Per robot, within our start-up grace we may not have heard its anchor yet
            # (one comes every `anchor_every`, half the grace): its LEAVE cannot be
            # judged, and a recorded takeover it backs, taken here alone, would move the
            # slot's epoch everywhere in the end (the holder's reassertion). After the
            # grace, a robot we never heard is dead or cut off, and its LEAVE (relayed
            # with the takeover it backs) counts.
            return True
        if not self._words.outdated(sender, seq, msg):
            return False
        if isinstance(msg, wire.Leave) and self._identity is not None \
                and self._words.above(sender, msg.function, msg.epoch):
            # Its signer refuted it and heartbeats a reassertion above it: somewhere the
            # recording was taken, and this LEAVE is the void backer of that reassertion.
            f = self._plan.function_at(msg.function)
            return f is None or self._ev.refuted_up_to(f, sender, msg.epoch, sender) < seq
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
        """Do we execute slot f now (ACTIVE on it)?"""
        return f == self._function and self._role == Role.ACTIVE

    def _heartbeating(self) -> bool:
        return not self._stopped and self._health != Health.FAULTY

    # ------------------------------------------------------------------ across modules
    # Defined in `hearing.py`, `moves.py` and `signed.py`.
    def _on_claim(self, sender: int, c: wire.Claim, now: float, raw: bytes = b"") -> None:
        raise NotImplementedError

    def _learn_holder(self, f: str, new: Holder, now: float) -> None:
        raise NotImplementedError

    def _relay_view(self, f: str, now: float, every: float | None = None) -> bool:
        raise NotImplementedError

    def _fence(self, epoch: int, now: float) -> None:
        raise NotImplementedError

    def _start_claim(self, f: str, failed: int, epoch: int, now: float,
                     trigger: Trigger = Trigger.QUORUM) -> None:
        raise NotImplementedError

    def _rejoin_superseded(self, f: str, seen_epoch: int) -> None:
        raise NotImplementedError

    def _heartbeat_now(self, now: float) -> bool:
        raise NotImplementedError

    def _record_evidence(self, f: str, witness: int, suspect: int, epoch: int,
                         raw: bytes, now: float | None = None) -> None:
        raise NotImplementedError

    def _relay_cert(self, f: str | None, now: float, every: float | None = None) -> None:
        raise NotImplementedError

    def _relay_refutes(self, f: str, now: float) -> None:
        raise NotImplementedError

    def _refute(self, f: str, witness: int, epoch: int, seq: int, now: float) -> None:
        raise NotImplementedError

    def _sign_only(self, msg: wire.Message) -> bytes:
        raise NotImplementedError

    def _forward(self, f: str, new: Holder) -> Holder:
        raise NotImplementedError

    def _refute_claim(self, f: str, claimant: int, epoch: int, seq: int, now: float) -> None:
        raise NotImplementedError

    def _reassert(self, f: str, epoch: int, now: float) -> None:
        raise NotImplementedError

    def _learn_reassertion(self, f: str, new: Holder, now: float) -> None:
        raise NotImplementedError

    def _verified_hold(self, f: str, epoch: int,
                       restored: Restored) -> tuple[str, int] | None:
        raise NotImplementedError

    def _send_cert(self, f: str, raw: bytes) -> None:
        raise NotImplementedError


__all__ = ["NodeBase"]
