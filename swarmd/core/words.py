"""What each robot last said of itself, to refuse its older word that contradicts it
(DESIGN section 2, "Who may say what": "Every proof is bound to its run").

A robot's sequence numbers only rise, across its restarts too (`wire.seq_seed`, the
seq reservation of `swarmd.services.state`), and within one run a robot never holds
again an entry it left. So once a receiver has heard a robot's own authenticated
heartbeat at seq `s`, a frame of that robot below `s` that says the opposite about the
same slot is not its current word: a `LEAVE` of the very entry it heartbeats since, or
a hold of an entry it does not hold since. It is a recording of an earlier run (the
swarm started afresh, epochs from 0 again), or a frame the channel reordered behind a
later one, and the receiver refuses it (`outdated`) before it backs, starts or moves
anything. A frame that agrees with the later word (a `LEAVE` followed by standby
heartbeats) passes: it says nothing the later frame did not.

A `CLAIM` below its claimant's later heartbeat as a standby is its word no more either:
the claimant gave it up (backed off, refuted, fenced, or started afresh), so it backs no
takeover, whatever warnings back it (a warning is no word of its signer about itself).
Yet such a claim stays what the holder it named refutes, the proof of that holder's
reassertion (DESIGN "Convergence"): the node keeps it where that holder heartbeats
above it (`NodeBase._outdated`).

Which heartbeats may set the word: only those whose sequence number is the sender's own,
bound by what authenticates the frame — a tag of the swarm key, or, per robot without
one, an anchor (its signature covers the header). A chain-linked heartbeat binds no
field (an outsider that heard a fresh link first can repeat it with another seq), so
it sets nothing here. Unsigned, anyone's frame sets it: anyone can make any frame in
that mode. The node also requires the frame to be the top of the sender's
own run as the replay filter tells it (`Node._heard_word`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

from swarmd.core import wire
from swarmd.core.roles import Role

# Enum members read through their class cost ~120 ns each on CPython 3.11 (measured with
# timeit), a module constant ~10: the ones read for every frame heard, bound once.
_ACTIVE = Role.ACTIVE


class Word(NamedTuple):
    """A robot's heartbeat: its seq and what it said it was doing."""

    seq: int
    role: int
    slot: int
    epoch: int
    """Without a slot, the sender's view digest (`digest.py`): never read as an epoch
    (`outdated` judges holds only)."""


class LatestWords:
    """Per sender, its latest heartbeat that may set the word (module docstring).
    Bounded by the plan's robots: one entry a sender."""

    __slots__ = ("_heard", "_last", "_top")

    def __init__(self) -> None:
        self._last: dict[int, Word] = {}
        self._heard: set[int] = set()
        """Senders of an authenticated heartbeat, believed or not (`knows`)."""
        self._top: dict[tuple[int, int], int] = {}
        """(sender, slot) -> the highest epoch it heartbeat holding that slot, believed
        or not (`above`). At most one entry per robot and slot of the plan."""

    def heard(self, sender: int, seq: int, hb: wire.Heartbeat) -> None:
        """`sender`'s heartbeat number `seq`, accepted, and the top of its own run as
        the replay filter tells it (`ReplayFilter.top`): its word now. Replaced, not
        maxed, so a forged frame far ahead that was once the top (the first one heard)
        is its word only until the sender's own frames outnumber it."""
        self._last[sender] = Word(seq, hb.role, hb.function, hb.epoch)

    def held(self, sender: int, hb: wire.Heartbeat) -> None:
        """`sender`'s authenticated heartbeat, believed or not (an uncertified epoch: a
        holder's reassertion this robot cannot verify yet)."""
        self._heard.add(sender)
        if hb.function:
            key = (sender, hb.function)
            self._top[key] = max(self._top.get(key, -1), hb.epoch)

    def knows(self, sender: int) -> bool:
        """Has `sender` said anything of itself here yet (an authenticated heartbeat)?"""
        return sender in self._heard

    def above(self, sender: int, slot: int, epoch: int) -> bool:
        """Has `sender` heartbeat holding `slot` at an epoch above `epoch`?"""
        return self._top.get((sender, slot), -1) > epoch

    def slot_above(self, slot: int, epoch: int) -> bool:
        """Has any robot heartbeat holding `slot` at an epoch above `epoch`?"""
        return any(s == slot and e > epoch for (_, s), e in self._top.items())

    def forget(self, senders: Iterable[int]) -> None:
        """These robots' word is no longer believed (revoked: `Node.revoke`)."""
        gone = set(senders)
        for r in gone:
            self._last.pop(r, None)
            self._heard.discard(r)
        for key in [k for k in self._top if k[0] in gone]:
            del self._top[key]

    def outdated(self, sender: int, seq: int, msg: wire.Message) -> bool:
        """Does `sender`'s frame number `seq` say of itself what its later heartbeat,
        heard already, contradicts?"""
        last = self._last.get(sender)
        if last is None or last.seq <= seq:
            return False
        holds = last.role == _ACTIVE and last.slot == msg.function
        match msg:
            case wire.Leave(_, epoch, _):
                # It never holds again an entry it left.
                return holds and last.epoch == epoch
            case wire.Heartbeat(function, epoch) if function != 0:
                return not (holds and last.epoch >= epoch)
            case wire.Claim():
                # A claimant heartbeating as a standby since gave its claim up (backed
                # off, refuted, fenced, or started afresh): it backs no takeover now.
                return last.role == Role.STANDBY
        return False


__all__ = ["LatestWords", "Word"]
