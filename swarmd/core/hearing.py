"""What a robot does with each message it accepts (paper Figs. 7-9, DESIGN rules 1-10).

`Hearing` is the part of `Node` that reacts to HEARTBEAT, WARN, CLAIM and LEAVE frames
once they passed the receive filters (`node.py`); per-robot evidence (CERT, REFUTE) is
`signed.py`'s, role changes are `moves.py`'s. Every method changes the node's state
and queues actions; none does I/O.
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.belief import byte_level, level_byte
from swarmd.core.drops import DropReason
from swarmd.core.evidence import seq_of
from swarmd.core.nodebase import NodeBase
from swarmd.core.records import Holder
from swarmd.core.roles import Health, Role, Trigger
from swarmd.core.slots import greater
from swarmd.core.state import Standby
from swarmd.core.witness import witnesses


class Hearing(NodeBase):
    # ------------------------------------------------------------------ HEARTBEAT
    def _on_heartbeat(self, sender: int, hb: wire.Heartbeat, now: float) -> None:
        for votes in self._votes.values():
            # A witness heard, its warning overdue: it stopped suspecting (`votes.py`).
            votes.witness_heard(sender, now)
        if hb.function == 0:
            if hb.role in (Role.STANDBY, Role.CLAIMING) and hb.health != Health.FAULTY:
                self._ears.standby_beat(sender, now)
            return
        f = self._slot(hb.function)
        if f is None:
            return
        known, entry = self._known[f], Holder(sender, hb.epoch)
        if greater(known, entry):
            self._older_beat(f, sender, hb, known, now)
            return
        if entry != known and self._identity is not None \
                and not self._ev.is_certified(f, sender, hb.epoch):
            self._uncertified_beat(f, hb, now)
            return
        if self._holds(f) and sender != self._robot_id:
            self._refute_claim(f, sender, hb.epoch, 0, now)  # if it replaces us, rule 4
        ahead = self._forward(f, entry)
        if ahead != entry:
            # Per robot: a takeover that the robot it replaced refuted. Its holder is
            # outranked by that robot's reassertion; show it why.
            self._learn_reassertion(f, ahead, now)
            self._relay_view(f, now)
            return
        self._known.merge(f, entry)
        self._ears.slot_beat(f, sender, hb.epoch, now)
        self._claims_seen.forget(f)
        # Rule 2: a greater entry for the slot we execute (a higher epoch, or ours by a
        # lower id) ends our hold.
        if self._holds(f) and sender != self._robot_id:
            self._fence(hb.epoch, now)
            return
        self._holder_heard(f, sender, hb.epoch, known, now)

    def _older_beat(self, f: str, sender: int, hb: wire.Heartbeat, known: Holder,
                    now: float) -> None:
        """A heartbeat for f older than our view of it (`known`): its sender missed a
        takeover, or lost a race at the same epoch; show it what it missed."""
        # A stale holder (e.g. back from a pause): if it is our slot, answer at once
        # so it hears the newer epoch and fences itself (rule 2) within a frame.
        if self._holds(f):
            # A rival holding it at our epoch (the race won on each side of a
            # partition) lacks only our CLAIM, most likely (its own evidence backs
            # ours): every other heartbeat period rather than every T_max, so a
            # lossy channel does not keep two robots executing one slot (rule 2).
            rival = hb.epoch == self._epoch
            self._relay_cert(f, now, 2 * self._params.heartbeat_interval if rival
                             else None)
            self._heartbeat_now(now)
        elif self._identity is not None:
            # Per-robot mode, a takeover it missed whose new holder may be gone:
            # whoever certified it shows the stale holder the evidence against it
            # (it fences itself, or refutes and keeps its slot everywhere).
            if self._relay_view(f, now) and sender == known.robot \
                    and self._ev.reasserted(f, sender, known.epoch) is not None:
                # Its own hold, below the reassertion our view holds: it refuted a
                # recorded takeover that we took before its word reached us and did not
                # reassert (DESIGN, "Every proof is bound to its run"). A signed doubt
                # (no standby counts it) tells it so; on our next relay it reasserts.
                self._send(wire.Warn(sender, hb.function, known.epoch, 0))
        elif not self._ears.heard_lately(f, known.robot, known.epoch, now,
                                         self._params.t_max) \
                and self._ev.relay_due(f, now):
            # Unsigned or shared key: a takeover it missed whose new holder is silent
            # here too. Our warning about that holder carries the entry (DESIGN,
            # "Convergence"): the stale holder and anyone else that missed it move
            # forward (`_warned_newer`), the stale holder fences, and the slot's
            # watchers take it from there. Once per T_max per slot. It says how strongly
            # we suspect that holder: a standby counts it only as a suspicion (DESIGN
            # "Detection"), the entry travels either way.
            level = self._ears.level_now(known.robot, now)
            self._send(wire.Warn(known.robot, hb.function, known.epoch, level_byte(level)))

    def _uncertified_beat(self, f: str, hb: wire.Heartbeat, now: float) -> None:
        """Per-robot mode: a heartbeat is not signed by its sender, so it never moves an
        epoch or a holder by itself; only the certified new holder's does."""
        self._drops[DropReason.UNCERTIFIED] += 1
        if self._holds(f):
            self._relay_cert(f, now)
        self._relay_refutes(f, now)  # it may act on a claim they void
        if self._rejoin is not None and self._rejoin.function == f:
            # Not believed, but enough to stay a standby rather than resume: the
            # cautious side of rule 2 across a reboot (the slot's watchers and
            # standbys take it over if nobody really holds it).
            self._rejoin_superseded(f, hb.epoch)

    def _unanchored_beat(self, sender: int, hb: wire.Heartbeat, now: float) -> None:
        """Per-robot mode: a heartbeat whose link we cannot tie to its sender's chain
        (`chain.py`: we lost the chain, or it is forged). It proves no liveness and moves
        nothing, but the answers cost nothing to give: a holder shown another view of its
        slot sends its certificate and, to a stale one, an anchored heartbeat (it may
        have lost our chain too: rule 2 within a frame); a robot rejoining that slot
        stays a standby (the cautious side, as for an uncertified heartbeat)."""
        self._drops[DropReason.UNANCHORED] += 1
        self._peer_back(sender, now)  # it may have lost our chain as we lost its
        f = self._plan.function_at(hb.function) if hb.function else None
        if f is None:
            return
        if self._holds(f):
            self._relay_cert(f, now)
            if hb.epoch <= self._epoch:
                self._heartbeat_now(now)
        if self._rejoin is not None and self._rejoin.function == f:
            self._rejoin_superseded(f, hb.epoch)

    def _holder_heard(self, f: str, sender: int, epoch: int, before: Holder,
                      now: float) -> None:
        """f's holder (`sender` at `epoch`; `before`: the view until now) heartbeated:
        watchdog, votes, our claim and our rejoin learn it."""
        watch = self._watches.get(f)
        if watch is not None:
            suspected = watch.suspecting
            reasserted = self._identity is not None and epoch > before.epoch \
                and self._ev.reasserted(f, sender, epoch) is not None
            if watch.heard(now, self._ears.patience(sender)) and suspected \
                    and (epoch <= before.epoch or reasserted):
                # The suspect heard alive (rule 4), or the rival that won the suspect's
                # own takeover race at its epoch (lowest id): the suspicion is over, and
                # the log says so (the paper's property: every warning ends in a
                # takeover, a refutation or an alert). A holder at a newer epoch ends it
                # by its takeover, unless that epoch is its reassertion (per robot: it
                # refuted the takeover we suspected, DESIGN "Convergence").
                self._emit(ev.Refute(subject=sender, function=f))
        votes = self._votes.get(f)
        if votes is not None and votes.witnesses:
            votes.clear()  # rule 4: the suspect is alive, or a new holder is
        claim = self._claim
        if claim is not None and claim.function == f:
            if epoch >= claim.epoch:
                self._back_off(sender)
            elif sender == claim.failed:
                self._emit(ev.Refute(subject=sender, function=f))
                self._to(Trigger.REFUTED, Standby())
        if self._rejoin is not None and self._rejoin.function == f and sender != self._robot_id:
            self._rejoin_superseded(f, self._known[f].epoch)

    # ------------------------------------------------------------------ WARN
    def _on_warn(self, sender: int, w: wire.Warn, now: float, raw: bytes = b"",
                 seq: int = 0) -> None:
        f = self._slot(w.function)
        if f is None:
            return
        if self._identity is not None and w.suspect == self._robot_id and self._holds(f) \
                and w.epoch > self._epoch:
            # A live robot took a recorded takeover of our hold before our word reached
            # it (DESIGN, "Every proof is bound to its run"): ours must be provable.
            self._shown_newer.add(f)
        # A warning below the suspicion level is a watcher's doubt (DESIGN "Detection"):
        # the suspect answers it (rule 4), views move on it, but it is nobody's evidence
        # and no standby counts it (Fig. 9 counts accusations).
        strong = byte_level(w.belief) >= self._params.suspect_level
        self._views_from_warn(f, sender, w, raw, now, evidence=strong)
        holder, epoch = self._known[f]
        if w.suspect == self._robot_id and not self._ours_unheld(f, sender, w, seq, now):
            return
        if self._rejoin is not None and self._rejoin.function == f:
            self._rejoin_superseded(f, w.epoch)
        if not strong or f not in self._covers or not self._standing_by():
            return
        if greater(Holder(holder, epoch), Holder(w.suspect, w.epoch)):
            return  # about an older holder: stale
        # A warning at a newer epoch than we know means we missed a takeover (we were
        # partitioned, or lost its heartbeats) and the new holder may be dead already:
        # count it, keyed by (suspect, epoch); per robot it does not move `known` (only
        # a certificate does; in the other modes `_warned_newer` moved it forward
        # above) — a single liar cannot reach the quorum, and the holder's heartbeat
        # refutes it.
        # Rule 3: only the holders of the slots that watch f are witnesses; never the
        # suspect itself.
        if sender == w.suspect or sender not in witnesses(self._plan, self._known, f):
            self._drops[DropReason.NOT_WITNESS] += 1
            return
        count = self._count_vote(f, sender, w, now)
        # Rule 4 from our own ears: the channel is a broadcast, so the standby hears the
        # suspect too. Heard within our own patience for its link (`Ears.alive_to_me`),
        # the suspect is alive whatever the witnesses missed (loss); after a real crash
        # this is silent by the time warnings come (they come a patience after the last
        # heartbeat), so it costs no latency. The next warning re-checks. The takeover
        # of a live robot so needs three links silent at once (DESIGN "Detection").
        if count >= self._params.quorum and not self._ears.alive_to_me(
                f, w.suspect, w.epoch, now):
            self._start_claim(f, w.suspect, w.epoch, now)

    def _views_from_warn(self, f: str, sender: int, w: wire.Warn, raw: bytes,
                         now: float, *, evidence: bool = True) -> None:
        """A warning about f's holder, before any standby counts it: per robot, its
        evidence is kept (a suspicion's, not a doubt's), and a robot whose view of f is
        newer than the warning's shows the warner its certificate; in the other modes a
        newer epoch in it may raise our view (DESIGN, "Convergence")."""
        if self._identity is None:
            self._warned_newer(f, sender, w, now)
            return
        if evidence:
            self._record_evidence(f, sender, w.suspect, w.epoch, raw, now)
        if self._holds(f) and (w.epoch, w.suspect) != (self._epoch, self._robot_id):
            self._relay_cert(f, now)  # a watcher that missed our takeover
        elif greater(self._known[f], Holder(w.suspect, w.epoch)):
            self._relay_view(f, now)  # one that missed a takeover we certified

    def _warned_newer(self, f: str, sender: int, w: wire.Warn, now: float) -> None:
        """Unsigned or shared-key mode: a robot that may watch or hold f (a witness of
        rule 3 by the plan, or a standby of f) warns about a holder whose entry is
        greater than our view: it heard that holder's heartbeat, which we missed
        (a partition, a fade), and the holder may be dead since. Our view moves forward
        to it (DESIGN, "Convergence"), or our warnings would name an older holder than
        the other witnesses' and the slot's standby would never count a quorum; a hold
        of ours it outranks ends (rule 2). In these modes any heartbeat moves a view as
        far (DESIGN section 2, "Who can still do what"); per robot, only a certificate
        does (`_relay_view`)."""
        new = Holder(w.suspect, w.epoch)
        if w.suspect == sender or not greater(new, self._known[f]) \
                or sender not in self._ev.may_watch(f, claimants=True):
            return
        self._learn_holder(f, new, now)

    def _learn_holder(self, f: str, new: Holder, now: float) -> None:
        """Our view of f moves forward to `new`, a takeover we learn of without hearing
        its holder (`_warned_newer`, `_relay_view`'s receivers). Not a sign of life: the
        watch treats it as a CLAIM heard (the new holder gets `claim_hold + t_max` to
        heartbeat; rule 10, once an episode), then suspects it. A hold of ours it
        outranks ends (rule 2); a claim of ours it supersedes backs off."""
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
        if self._rejoin is not None and self._rejoin.function == f:
            self._rejoin_superseded(f, new.epoch)

    def _ours_unheld(self, f: str, sender: int, w: wire.Warn, seq: int, now: float) -> bool:
        """A warning about ourselves. Holding the slot, we answer it (rule 4). Not
        holding it while the warner's view names us at an entry no older than ours (we
        left it, or were faulty, and nobody took it over; or the others learnt a hold of
        ours we cannot prove any more, or never had: a restart that could not verify
        it, a takeover recorded in another run): the warning is right, and as a robot
        that covers the slot we may take it over like any standby — True, count it
        (DESIGN, "Convergence": a slot has a holder while a live robot covers it)."""
        if self._role == Role.ACTIVE and f == self._function:
            self._warned_about_us(f, sender, w.epoch, seq, now)
            return False
        return not greater(self._known[f], Holder(self._robot_id, w.epoch))

    def _warned_about_us(self, f: str, sender: int, epoch: int, seq: int, now: float) -> None:
        """Rule 4: a warning about ourselves is answered with a heartbeat at once (and,
        per robot, a signed REFUTE)."""
        self._refute(f, sender, epoch, seq, now)
        if self._heartbeat_now(now):
            self._emit(ev.Refute(subject=self._robot_id, function=f))

    def _count_vote(self, f: str, sender: int, w: wire.Warn, now: float) -> int:
        """Fig. 9: count `sender`'s warning; returns the distinct witnesses now."""
        votes = self._votes[f]
        fresh = sender not in votes.witnesses or (w.suspect, w.epoch) != (votes.subject,
                                                                          votes.epoch)
        count = votes.add(sender, w.suspect, w.epoch, now)
        if fresh:  # repeated warnings refresh a vote; only a new witness is an event
            self._emit(ev.Vote(subject=w.suspect, function=f, from_=sender, count=count))
        if count < self._params.quorum and self._ears.own_ears(f, self._known, now):
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
        return count

    # ------------------------------------------------------------------ CLAIM
    def _on_claim(self, sender: int, c: wire.Claim, now: float, raw: bytes = b"") -> None:
        f = self._slot(c.function)
        if f is None:
            return
        if self._identity is not None and not self._claim_certified(f, sender, c, raw, now):
            return
        if not self._claims_seen.believed(f, sender, c.epoch, now):
            self._drops[DropReason.STALE_CLAIM] += 1
            return
        if self._claim is not None and self._claim.function == f:
            # The paper's wait state: the lower id wins; a claim at a higher epoch
            # knows more than we do.
            mine = self._claim.epoch
            if c.epoch > mine or (c.epoch == mine and sender < self._robot_id):
                self._back_off(sender, Trigger.BACKOFF)
            return
        if self._role == Role.ACTIVE and f == self._function:
            if c.failed == self._robot_id and c.epoch > self._epoch:
                self._refute_claim(f, sender, c.epoch, seq_of(raw) if raw else 0, now)
                if self._heartbeat_now(now):
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

    def _claim_certified(self, f: str, sender: int, c: wire.Claim, raw: bytes,
                         now: float) -> bool:
        """Per-robot mode: does this CLAIM (signed bytes `raw`) act here? Only with a
        certificate this robot verified; its signed bytes are kept for `_relay_view`."""
        if (sender, c.epoch) == tuple(self._known[f]):
            # The holder re-announcing its certificate (`_relay_cert`), or a relayed proof
            # resting on it: certified here too (a restarted robot's view of it came from
            # its state file, with no evidence), and its signed claim kept.
            if self._ev.certify(f, sender, c, self._known[f].epoch):
                self._ev.keep_claim(f, sender, c.epoch, raw)
            return False
        if not self._ev.certify(f, sender, c, self._known[f].epoch):
            # A claim without a certificate this robot verified silences nobody and
            # makes nobody back off (one robot alone cannot start a takeover); kept a
            # while in case its certificate comes later.
            self._ev.hold_pending(f, sender, c, now, raw)
            self._drops[DropReason.UNCERTIFIED] += 1
            self._relay_refutes(f, now)
            return False
        self._ev.keep_claim(f, sender, c.epoch, raw)
        return True

    # ------------------------------------------------------------------ LEAVE
    def _on_leave(self, sender: int, lv: wire.Leave, now: float, raw: bytes = b"") -> None:
        f = self._slot(lv.function)
        if f is None:
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
            if not self._ears.live_standby(f, sender, now):
                watch.mark_alerted()
                self._emit(ev.Alert(function=f, reason=ev.AlertCause.NO_STANDBY))
        if f in self._covers and self._standing_by():
            self._start_claim(f, sender, epoch, now, trigger=Trigger.LEAVE_HEARD)


__all__ = ["Hearing"]
