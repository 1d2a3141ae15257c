"""How a robot starts (DESIGN rule 2 across a reboot): who holds each slot at start, from
the plan or from what a restarted robot persisted before it went down (its own hold only
if it is provable); the hold it resumes only after listening (`rejoin.py`), and the
first tick's `started`, which a rejoining robot says only once its hold is over.

`Restart` is the layer of `Node` on `Hearing` (and so on `Episode`, `Proofs`, `Views`,
`NodeBase`): it calls only methods defined there or here. `Node`'s constructor calls
`_views` and `_restore` once; `Node.tick` calls `_start` and `_finish_rejoin`.
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Assign
from swarmd.core.drops import DropReason
from swarmd.core.hearing import Hearing
from swarmd.core.records import Holder, Restored
from swarmd.core.rejoin import Rejoin
from swarmd.core.roles import Trigger
from swarmd.core.slots import SlotTable
from swarmd.core.state import Rejoining, Standby


class Restart(Hearing):
    def _views(self, restored: Restored | None) -> SlotTable:
        """Who holds each slot at start: the plan's holders at epoch 0, or newer ones a
        restarted robot persisted (its own memory: what it had verified before it went
        down; its own hold is verified again, `_restore`)."""
        known = SlotTable((f, self._initial(f)) for f in self._plan.functions)
        held = restored.held[0] if restored is not None and restored.held else None
        for f, (holder, epoch) in (restored.known.items() if restored is not None else ()):
            # An entry naming ourselves for a slot we did not hold when we stopped (we
            # left it, or were faulty) is no knowledge: nobody can be shown its proof,
            # and a view naming us would keep us from counting the warnings about the
            # slot's real holder. The plan's entry, or what we hear, stands instead.
            if f in known and (holder != self._robot_id or f == held):
                known.merge(f, Holder(holder, epoch))
        return known

    def _initial(self, f: str) -> Holder:
        holder = self._plan.initial_holder(f)
        return Holder(holder if holder is not None else 0, 0)

    def _restore(self, restored: Restored, now: float) -> None:
        """A restarted robot: peers' seqs (a refused absurd value counts as `seq_jump`),
        and a held slot resumed only after listening (rule 2 across a reboot: a takeover
        may have happened while it was down)."""
        for peer, top in restored.peer_seq.items():
            if peer != self._robot_id and peer in self._plan.robots \
                    and not self._replay.restore(peer, top):
                self._drops[DropReason.SEQ_JUMP] += 1
        held = restored.held
        if held is None or held[0] not in self._known:
            return
        f = held[0]
        held = self._verified_hold(f, held[1], restored)
        if held is None and self._known[f].robot == self._robot_id:
            # Our own hold, unproven: the file's view of the slot is no better. The
            # table is being built (nothing has read it yet), so it starts again from
            # the plan's entry for f rather than lowering one.
            self._known = SlotTable((g, self._initial(g) if g == f else e)
                                    for g, e in self._known.items())
        if held is not None:
            self._state = Rejoining(Rejoin(self._robot_id, *held,
                                           now + self._params.rejoin_hold))

    def _verified_hold(self, f: str, epoch: int,
                       restored: Restored) -> tuple[str, int] | None:
        """The hold of f at `epoch` a restarted robot read from its state file, if it is
        provable as a received one would be — the plan's own holder at epoch 0, or a
        certificate that verifies and backs it; otherwise None (it rejoins as a standby,
        and the slot's watchers take it over if nobody holds it)."""
        if epoch == 0:
            return (f, 0) if self._plan.initial_holder(f) == self._robot_id else None
        if self._ev.restore(f, epoch, tuple(restored.certificate), self._keys,
                            self._verifier):
            self._known.merge(f, Holder(self._robot_id, epoch))
            return (f, epoch)
        return None

    # ------------------------------------------------------------------ start
    def _start(self) -> None:
        self._started = True
        if self._rejoin is not None:
            return  # `started` tells the outcome once the rejoin hold is over
        self._emit(ev.Started(role=ev.RoleName.of(self._role), function=self._function))
        if self._function is not None:
            self._pending.append(Assign(self._function, self._epoch))

    # ------------------------------------------------------------------ rejoin (rule 2)
    def _finish_rejoin(self, now: float) -> None:
        rejoin = self._rejoin
        assert rejoin is not None
        if not rejoin.resumes(self._known[rejoin.function]):
            self._to(Trigger.OUTDATED, Standby())
            self._emit(ev.Started(role=ev.RoleName.STANDBY, function=None))
            return
        f, epoch = rejoin.function, rejoin.epoch
        failed = self._ev.replaced(f, self._robot_id, epoch)
        if failed is not None:
            # A hold resumed at a takeover's epoch: its CLAIM went down with the robot;
            # made again, so the proof we show is whole (`_show`).
            claim = self._next_frame(wire.Claim(failed, self._plan.slot(f), epoch))
            self._ev.keep_claim(f, self._robot_id, epoch, claim)
        self._emit(ev.Started(role=ev.RoleName.ACTIVE, function=f))
        self._become_holder(Trigger.REJOIN, f, epoch, now)


__all__ = ["Restart"]
