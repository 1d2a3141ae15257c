"""How a robot changes what it does (paper Fig. 5 with the wait state; DESIGN rules 2, 5,
8, 10): start, claim, take over, fence, rejoin after a restart, watch the neighbours'
slots, heartbeat. `Moves` is that part of `Node`; every role change goes through the
table in `roles.py` (`NodeBase._to`).
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Assign, Release
from swarmd.core.belief import LEVEL_MAX, level_byte
from swarmd.core.claims import WaitState
from swarmd.core.limits import EPOCH_MAX
from swarmd.core.nodebase import NodeBase
from swarmd.core.records import Holder
from swarmd.core.roles import Role, Trigger
from swarmd.core.slots import greater
from swarmd.core.state import Active, Claiming, Fenced, Standby
from swarmd.core.watchdog import SlotWatch


class Moves(NodeBase):
    # ------------------------------------------------------------------ start
    def _start(self, now: float) -> None:
        self._started = True
        if self._rejoin is not None:
            return  # `started` tells the outcome once the rejoin hold is over
        self._emit(ev.Started(role=ev.RoleName.of(self._role), function=self._function))
        if self._role == Role.ACTIVE and self._function is not None:
            self._pending.append(Assign(self._function, self._epoch))

    # ------------------------------------------------------------------ the wait state
    def _start_claim(self, f: str, failed: int, epoch: int, now: float,
                     trigger: Trigger = Trigger.QUORUM) -> None:
        # 65535 takeovers of one slot: saturate rather than wrap.
        new_epoch = min(epoch + 1, EPOCH_MAX)
        self._to(trigger, Claiming(WaitState(f, failed, epoch, new_epoch,
                                             now + self._params.claim_hold,
                                             now + self._params.warn_interval)))
        self._clear_votes()
        self._emit(ev.Claim(subject=failed, function=f, epoch=new_epoch))
        self._send_claim()

    def _send_claim(self) -> None:
        assert self._claim is not None
        c = self._claim
        if self._identity is not None:
            for raw in self._ev.cert_frames(c.function, c.failed, c.old_epoch):
                self._send_cert(c.function, raw)
        signed = self._send(wire.Claim(c.failed, self._plan.slot(c.function), c.epoch))
        if self._identity is not None:
            self._ev.keep_claim(c.function, self._robot_id, c.epoch, signed)

    def _claim_due(self, now: float) -> None:
        """The wait state's deadlines: take over at the end of the hold, else repeat the
        claim every warn interval."""
        c = self._claim
        if c is None:
            return
        if now >= c.until:
            self._take_over(now)
        elif now >= c.resend:
            c.resend = now + self._params.warn_interval
            self._send_claim()

    def _take_over(self, now: float) -> None:
        assert self._claim is not None
        c = self._claim
        if self._identity is not None and not self._ev.certify(
                c.function, self._robot_id,
                wire.Claim(c.failed, self._plan.slot(c.function), c.epoch),
                self._known[c.function].epoch, refutes=True):
            # Its certificate was refuted during the hold (or never complete): a takeover
            # no other robot would believe is none (DESIGN, "Convergence").
            self._emit(ev.Refute(subject=c.failed, function=c.function))
            self._to(Trigger.REFUTED, Standby())
            return
        if greater(self._known[c.function], Holder(self._robot_id, c.epoch)):
            # The slot moved past our claim during the hold: a greater entry is never
            # lowered (`slots.py`), so ours would be fenced at once.
            self._back_off(self._known[c.function].robot)
            return
        if self._identity is not None:
            self._ev.took_over(c.function, c.failed, c.old_epoch, c.epoch)
        self._emit(ev.Takeover(function=c.function, epoch=c.epoch, replaced=c.failed))
        self._become_holder(Trigger.CLAIM_HELD, c.function, c.epoch, now)

    def _become_holder(self, trigger: Trigger, f: str, epoch: int, now: float) -> None:
        """Execute f at `epoch` from now: the entry (us, epoch) in the table, tell the
        robot, watch f's neighbours, heartbeat."""
        self._to(trigger, Active(f, epoch))
        self._known.merge(f, Holder(self._robot_id, epoch))
        self._pending.append(Assign(f, epoch))
        self._watch_neighbours(now)
        self._restart_heartbeats(now)

    # ------------------------------------------------------------------ fencing (rule 2)
    def _fence(self, epoch: int, now: float) -> None:
        f = self._function
        assert f is not None
        self._emit(ev.Fenced(function=f, epoch=epoch))
        self._pending.append(Release(f))
        self._to(Trigger.FENCE, Fenced(now + self._params.heartbeat_interval))

    # ------------------------------------------------------------------ rejoin (rule 2)
    def _finish_rejoin(self, now: float) -> None:
        rejoin = self._rejoin
        assert rejoin is not None
        if not rejoin.resumes(self._known[rejoin.function]):
            self._to(Trigger.OUTDATED, Standby())
            self._emit(ev.Started(role=ev.RoleName.STANDBY, function=None))
            return
        self._emit(ev.Started(role=ev.RoleName.ACTIVE, function=rejoin.function))
        self._become_holder(Trigger.REJOIN, rejoin.function, rejoin.epoch, now)

    def _rejoin_superseded(self, f: str, seen_epoch: int) -> None:
        """Someone holds, warns about or claims our old slot at `seen_epoch`: newer than
        the one we held (or held by another robot), we stay a standby."""
        assert self._rejoin is not None
        if self._rejoin.superseded(self._known[f], seen_epoch):
            self._to(Trigger.OUTDATED, Standby())
            self._emit(ev.Started(role=ev.RoleName.STANDBY, function=None))

    # ------------------------------------------------------------------ watchdogs
    def _watch_neighbours(self, now: float) -> None:
        state = self._state
        assert isinstance(state, Active)
        state.watches = {g: SlotWatch(g, self._params, now,
                                      self._heard_at.get(self._known[g].robot),
                                      self._ears.patience(self._known[g].robot))
                         for g in self._plan.watched(state.function)}

    def _watch_fired(self, g: str, watch: SlotWatch, now: float) -> None:
        subject, epoch = self._known[g]
        fired = watch.fire(now)
        level = self._warn_level(subject, watch, now)
        if fired.doubt:
            # Not a suspicion yet (DESIGN "Detection"): the warning asks the holder to
            # answer (rule 4), its weak level tells standbys not to count it.
            self._send(wire.Warn(subject, self._plan.slot(g), epoch, level_byte(level)))
            return
        if fired.first:
            self._emit(ev.Suspect(subject=subject, function=g))
            self._emit(ev.Warn(subject=subject, function=g))
        if fired.alert:
            # Also on a first fire: a handover that brought no holder is logged as a new
            # suspicion, and it may end past alert_after (a claim late in the episode, a
            # stall of our own over the hold). `fire` marked the episode alerted, so an
            # alert not logged here never comes: the warning would end in nothing (rule
            # 8; the paper's property that every warning ends somewhere).
            self._emit(ev.Alert(function=g, reason=ev.AlertCause.NO_CLAIM))
        elif (not fired.first and not watch.alerted and watch.since is not None
              and now - watch.since >= self._params.t_max
              and not self._ears.live_standby(g, subject, now)):
            # Rule 8, without waiting for alert_after: nobody can take over. Not on the
            # first fire: one more T_max of silence first, so loss alone rarely alerts.
            watch.mark_alerted()
            self._emit(ev.Alert(function=g, reason=ev.AlertCause.NO_STANDBY))
        # A suspicion: its level, and at least the swarm's `suspect_level` (the patience
        # cap, `t_max_bursty`, may have ended the wait before the level got there).
        strong = max(level, self._params.suspect_level)
        self._send(wire.Warn(subject, self._plan.slot(g), epoch, level_byte(strong)))

    def _warn_level(self, subject: int, watch: SlotWatch, now: float) -> float:
        """How strongly we suspect `subject` now: the belief of its link for the silence
        since we last heard the slot (never heard: as strongly as can be)."""
        if watch.last_heard is None:
            return LEVEL_MAX
        return self._ears.level(subject, now - watch.last_heard)

    # ------------------------------------------------------------------ heartbeats
    def _send_heartbeat(self, now: float, *, extra: bool = False) -> None:
        slot = self._plan.slot(self._function) if self._function is not None else 0
        # A rejoining robot is a standby to the others until it resumes (rule 6).
        role = Role.STANDBY if self._role == Role.REJOINING else self._role
        epoch = self._epoch if slot else 0
        hb = wire.Heartbeat(slot, epoch, int(role), int(self._health))
        if self._chain is not None:
            # Per-robot mode: the next link of our chain; an anchor (signed) where a
            # receiver may have lost it (`chain.py`).
            n, link, anchor = self._chain.next(now, (slot, epoch, int(role)),
                                               self._anchor_every, extra=extra)
            hb = wire.Heartbeat(slot, epoch, int(role), int(self._health), n, link, anchor)
        self._send(hb)
        self._beat.sent(now)

    def _restart_heartbeats(self, now: float) -> None:
        """Became ACTIVE: heartbeat now and every heartbeat_interval from now on."""
        if self._heartbeating():
            self._send_heartbeat(now)
            self._beat.restart(now)

    def _heartbeat_now(self, now: float) -> bool:
        """An extra heartbeat out of schedule (refutation, fencing a stale holder),
        at most four per heartbeat period so a flood of warnings cannot amplify."""
        if not self._heartbeating() or not self._beat.extra_allowed(now):
            return False
        self._send_heartbeat(now, extra=True)
        return True


__all__ = ["Moves"]
