"""What a robot does when its view of a slot moves forward without the holder's own
heartbeat (DESIGN "Convergence", rule 2): the slot table's entry moves, a hold of ours it
outranks ends (fence) or holds on at our reassertion's epoch, a claim of ours it
supersedes backs off, and a rejoin of that slot gives way.

`Views` is the layer of `Node` on `NodeBase` (state and plumbing); every layer above
(`proofs.py`, `episode.py`, `hearing.py`, `restart.py`) moves a view through it, and it
calls nothing above itself.
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core.actions import Assign, Release
from swarmd.core.nodebase import NodeBase
from swarmd.core.records import Holder
from swarmd.core.roles import Trigger
from swarmd.core.state import Active, Fenced, Standby


class Views(NodeBase):
    def _learn_holder(self, f: str, new: Holder, now: float) -> None:
        """Our view of f moves forward to `new`, a takeover we learn of without hearing
        its holder (a proof another robot showed, `Proofs._show`, or a claim relayed
        with its certificate).
        Not a sign of life: the watch treats it as a CLAIM heard (the new holder gets
        `claim_hold + t_max` to heartbeat; rule 10, once an episode), then suspects it.
        A hold of ours it outranks ends (rule 2); a claim of ours it supersedes backs
        off."""
        if not self._known.merge(f, new):
            return
        if self._holds(f) and new.robot == self._robot_id:
            self._reassert(f, new.epoch, now)
        elif self._holds(f):
            self._fence(new.epoch, now)
        claim = self._claim
        if claim is not None and claim.function == f and new.epoch >= claim.epoch:
            self._back_off(new.robot)
        watch = self._watches.get(f)
        if watch is not None:
            watch.claim_heard(now)
        self._rejoin_superseded(f, new.epoch)

    def _reassert(self, f: str, epoch: int, now: float) -> None:
        """We hold f, and a takeover of our hold that our refutes void reached us: we
        hold f on at the reassertion's epoch (`_forward`), tell the robot, and heartbeat
        it at once (an anchor: the epoch changed) so the others move forward too. The log
        says `refute` about ourselves: the suspicion of us ended refuted (rule 4); it is
        not a takeover (nobody new executes f)."""
        assert isinstance(self._state, Active)
        self._state.epoch = epoch
        self._shown_newer.discard(f)
        self._emit(ev.Refute(subject=self._robot_id, function=f))
        self._pending.append(Assign(f, epoch))
        self._heartbeat_now(now)

    # ------------------------------------------------------------------ fencing (rule 2)
    def _fence(self, epoch: int, now: float) -> None:
        f = self._function
        assert f is not None
        self._emit(ev.Fenced(function=f, epoch=epoch))
        self._pending.append(Release(f))
        self._to(Trigger.FENCE, Fenced(now + self._params.heartbeat_interval))

    # ------------------------------------------------------------------ rejoin (rule 2)
    def _rejoin_superseded(self, f: str, seen_epoch: int) -> None:
        """Someone holds, warns about or claims slot f at `seen_epoch`: if we are
        rejoining f and that is newer than the entry we held (or held by another robot),
        we stay a standby. Every frame that names f at an epoch says so here; for a
        robot not rejoining f it changes nothing."""
        rejoin = self._rejoin
        if rejoin is not None and rejoin.function == f \
                and rejoin.superseded(self._known[f], seen_epoch):
            self._to(Trigger.OUTDATED, Standby())
            self._emit(ev.Started(role=ev.RoleName.STANDBY, function=None))


__all__ = ["Views"]
