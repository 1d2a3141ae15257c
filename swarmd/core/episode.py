"""The takeover episode, top to bottom in the order it happens (paper Figs. 7-9 and 5's
wait state; DESIGN rules 2-4, 9, 10 and "One failover, crash to takeover"):

1. suspect: a watchdog on a neighbour's slot fires (Fig. 7) and its robot warns;
2. warn: a warning heard — its evidence kept, proofs shown, the suspect answering it
   (rule 4);
3. vote: a standby that covers the slot counts distinct witnesses (Fig. 9, rules 3, 9);
4. claim: at the quorum it claims the slot and holds (the wait state); others' claims,
   heard directly or relayed with their certificate, make it back off or are refuted;
5. take over: the hold ends, the claimant executes the slot at a new epoch (rule 2).

`Episode` is the layer of `Node` on `Proofs` (proofs relayed and refutes, on `Views`
and `NodeBase`): it calls only methods defined there or here. `hearing.py`,
above it, hands it the other messages' parts of the episode (a LEAVE's handover, a
CERT's evidence and relayed claims).
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Assign
from swarmd.core.belief import LEVEL_MAX, byte_level, level_byte
from swarmd.core.claims import WaitState
from swarmd.core.drops import DropReason
from swarmd.core.limits import EPOCH_MAX
from swarmd.core.proofs import Proofs
from swarmd.core.records import Holder
from swarmd.core.replay import header_seq
from swarmd.core.roles import Trigger
from swarmd.core.slots import greater
from swarmd.core.state import Active, Claiming
from swarmd.core.watchdog import SlotWatch
from swarmd.core.witness import witnesses


class Episode(Proofs):
    # ------------------------------------------------------------------ 1. suspect
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

    # ------------------------------------------------------------------ 2. warn
    def _on_warn(self, sender: int, w: wire.Warn, now: float, raw: bytes = b"",
                 seq: int = 0) -> None:
        f = self._slot(w.function)
        if f is None:
            return
        if w.suspect == self._robot_id and self._holds(f) and w.epoch > self._epoch:
            # A live robot took a recorded takeover of our hold before our word reached
            # it (DESIGN, "Every proof is bound to its run"): ours must be provable.
            self._shown_newer.add(f)
        # A warning below the suspicion level is a watcher's doubt (DESIGN "Detection"):
        # the suspect answers it (rule 4), a robot with a newer view shows the warner
        # its proof, but it is nobody's evidence and no standby counts it (Fig. 9
        # counts accusations).
        strong = byte_level(w.belief) >= self._params.suspect_level
        self._warning_evidence(f, sender, w, raw, now, evidence=strong)
        if w.suspect == self._robot_id and not self._ours_unheld(f, sender, w, seq, now):
            return
        self._rejoin_superseded(f, w.epoch)
        if not strong or f not in self._covers or not self._standing_by():
            return
        if greater(self._known[f], Holder(w.suspect, w.epoch)):
            return  # about an older holder: stale
        # A warning at a newer epoch than we know means we missed a takeover (we were
        # partitioned, or lost its heartbeats) and the new holder may be dead already:
        # count it, keyed by (suspect, epoch); it does not move `known` (only a
        # certificate does) — a single liar cannot reach the quorum, and the holder's
        # heartbeat refutes it.
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
            lost = self._ears.silent_watchers(f, self._known, now) \
                if self._robot_id in self._votes[f].witnesses else frozenset()
            self._start_claim(f, w.suspect, w.epoch, now, lost=lost)

    def _warning_evidence(self, f: str, sender: int, w: wire.Warn, raw: bytes,
                          now: float, *, evidence: bool = True) -> None:
        """A warning about f's holder, before any standby counts it: its evidence is kept
        (a suspicion's, not a doubt's), and a robot whose view of f is newer than the
        warning's shows the warner its certificate (DESIGN, "Convergence")."""
        if evidence:
            self._record_evidence(f, sender, w.suspect, w.epoch, raw, now)
        known, warned = self._known[f], Holder(w.suspect, w.epoch)
        if warned != known and (self._holds(f) or greater(known, warned)):
            # A watcher that missed our takeover, or one that missed a takeover we
            # certified: it is shown the proof of our entry.
            self._show(f, now)

    def _record_evidence(self, f: str, witness: int, suspect: int, epoch: int,
                         raw: bytes, now: float | None = None) -> None:
        if suspect == self._robot_id and now is not None:
            # Evidence against us, relayed in a certificate (we may have missed the
            # warning itself): while we hold the slot, we refute it (rule 4). Our own
            # LEAVE of the very entry we hold is a recording, of an earlier run or of a
            # hold we resumed after a restart (`evidence.py`): refuted alike, so that it
            # backs no takeover of the slot we execute.
            self._refute(f, witness, epoch, header_seq(raw), now)
            if witness == suspect and self._holds(f) and epoch == self._epoch \
                    and f not in self._shown_newer:
                # Our own LEAVE of the entry we hold backs nothing here either: unless
                # a live robot's warning showed that it took the recording (then our
                # reassertion, resting on it, must be provable), nothing moves.
                self._drops[DropReason.OUTDATED] += 1
                return
        ready = self._ev.record(f, witness, suspect, epoch, raw, self._known[f].epoch, now)
        if ready is None:
            if suspect != self._robot_id:  # what we refuted ourselves is no news
                self._drops[DropReason.STALE_EVIDENCE] += 1
            return
        for claimant, claim, raw_claim in ready:
            assert now is not None  # `record` readies a claim only with a `now`
            self._on_claim(claimant, claim, now, raw_claim)

    def _ours_unheld(self, f: str, sender: int, w: wire.Warn, seq: int, now: float) -> bool:
        """A warning about ourselves. Holding the slot, we answer it (rule 4): a REFUTE,
        and a heartbeat at once (`_answer_alive`). Not holding it while the warner's view
        names us at an entry no older than ours (we left it, or were faulty, and nobody
        took it over; or the others learnt a hold of ours we cannot prove any more, or
        never had: a restart that could not verify it, a takeover recorded in another
        run): the warning is right, and as a robot that covers the slot we may take it
        over like any standby — True, count it (DESIGN, "Convergence": a slot has a
        holder while a live robot covers it)."""
        if self._holds(f):
            self._refute(f, sender, w.epoch, seq, now)
            self._answer_alive(f, now)
            return False
        return not greater(self._known[f], Holder(self._robot_id, w.epoch))

    def _answer_alive(self, f: str, now: float) -> None:
        """Rule 4: a warning or a claim about ourselves, who hold f, is answered with a
        heartbeat at once (beside the REFUTE); if it went out, the suspicion of us ends
        refuted in our log."""
        if self._heartbeat_now(now):
            self._emit(ev.Refute(subject=self._robot_id, function=f))

    # ------------------------------------------------------------------ 3. vote
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
            if not mine:
                # Its own "warning" is a frame of its own, so the certificate can carry it.
                self._record_evidence(f, self._robot_id, w.suspect, w.epoch,
                                      self._next_frame(wire.Warn(w.suspect, w.function,
                                                                 w.epoch)))
            count = votes.add(self._robot_id, w.suspect, w.epoch, now)
            if not mine:
                self._emit(ev.Vote(subject=w.suspect, function=f, from_=self._robot_id,
                                   count=count))
        return count

    # ------------------------------------------------------------------ 4. claim
    def _start_claim(self, f: str, failed: int, epoch: int, now: float,
                     trigger: Trigger = Trigger.QUORUM, *,
                     lost: frozenset[tuple[str, int]] = frozenset()) -> None:
        # 65535 takeovers of one slot: saturate rather than wrap.
        new_epoch = min(epoch + 1, EPOCH_MAX)
        self._to(trigger, Claiming(WaitState(f, failed, epoch, new_epoch,
                                             now + self._params.claim_hold,
                                             now + self._params.warn_interval, lost)))
        self._clear_votes()
        self._emit(ev.Claim(subject=failed, function=f, epoch=new_epoch))
        self._send_claim()

    def _send_claim(self) -> None:
        assert self._claim is not None
        c = self._claim
        for raw in self._ev.cert_frames(c.function, c.failed, c.old_epoch):
            self._send_cert(c.function, raw)
        sent = self._send(wire.Claim(c.failed, self._plan.slot(c.function), c.epoch))
        self._ev.keep_claim(c.function, self._robot_id, c.epoch, sent)

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

    def _on_claim(self, sender: int, c: wire.Claim, now: float, raw: bytes = b"") -> None:
        f = self._slot(c.function)
        if f is None:
            return
        if self._holds(f) and c.failed == self._robot_id and c.epoch > self._epoch:
            # A claim that replaces our live hold (rule 4), answered whether or not its
            # certificate verifies here (`_refute_claim`).
            self._refute_claim(f, sender, c.failed, c.epoch, header_seq(raw), now)
            self._answer_alive(f, now)
        if not self._claim_certified(f, sender, c, raw, now):
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
        if self._holds(f):
            # Answered above if it replaces us. Another claim of the slot we hold moves
            # nothing by itself: its claimant's heartbeat or relayed proof does (rule 2).
            return
        watch = self._watches.get(f)
        if watch is not None and c.epoch > self._known[f].epoch:
            watch.claim_heard(now)  # paper: a claim tells the neighbours to stop warning
        votes = self._votes.get(f)
        if votes is not None:
            votes.clear()
        self._rejoin_superseded(f, c.epoch)

    def _claim_certified(self, f: str, sender: int, c: wire.Claim, raw: bytes,
                         now: float) -> bool:
        """Does this CLAIM (bytes `raw`) act here? Only with a certificate this robot
        verified; its bytes are kept for `_show`."""
        if (sender, c.epoch) == self._known[f]:
            # The holder's own proof shown (`_show`), or another proof resting on it:
            # certified here too (a restarted robot's view of it came from
            # its state file, with no evidence), and its claim kept.
            if self._ev.certify(f, sender, c, self._known[f].epoch):
                self._ev.keep_claim(f, sender, c.epoch, raw)
            return False
        if not self._ev.certify(f, sender, c, self._known[f].epoch):
            # A claim without a certificate this robot verified silences nobody and
            # makes nobody back off (one robot alone cannot start a takeover); kept a
            # while in case its certificate comes later.
            self._ev.hold_pending(f, sender, c, now, raw)
            self._drops[DropReason.UNCERTIFIED] += 1
            self._show(f, now, whole=False)  # refutes we hold may void it
            return False
        self._ev.keep_claim(f, sender, c.epoch, raw)
        return True

    def _on_relayed_claim(self, f: str, claimant: int, c: wire.Claim, raw: bytes,
                          now: float) -> None:
        """A CLAIM relayed inside a CERT (`_show`): heard as a claim (rule
        10 bounds what a repeat does), and, if the evidence here certifies it and its
        entry is greater than our view of f, our view moves forward to it
        (`_learn_holder`) — as far as a heartbeat of its claimant would have moved it,
        since a robot relays only the entry its own view holds. Holding f below it, we
        fence (rule 2), as that heartbeat would have fenced us — unless the claim
        replaces our own live hold: then we refute it (`_on_claim`) and the entry we
        move to is our reassertion (`_forward`), unless we were stalled, and then the
        takeover was right. Our own claim relayed back acts on nothing here."""
        if claimant == self._robot_id:
            # Our own claim, relayed back with its certificate as the proof of the
            # reassertion that outranks it: it must verify here as anywhere (no act),
            # and we keep it to show that proof in turn (a recorded claim of ours from
            # an earlier run that we took: DESIGN, "Every proof is bound to its run").
            if self._ev.certify(f, claimant, c, self._known[f].epoch):
                self._ev.keep_claim(f, claimant, c.epoch, raw)
            return
        self._on_claim(claimant, c, now, raw)
        new = Holder(claimant, c.epoch)
        if greater(new, self._known[f]) and self._ev.is_certified(f, claimant, c.epoch):
            ahead = self._forward(f, new)
            if ahead == new:
                self._learn_holder(f, new, now)
            else:
                self._learn_reassertion(f, ahead, now)

    # ------------------------------------------------------------------ 5. take over
    def _take_over(self, now: float) -> None:
        assert self._claim is not None
        c = self._claim
        if not self._ev.certify(
                c.function, self._robot_id,
                wire.Claim(c.failed, self._plan.slot(c.function), c.epoch),
                self._known[c.function].epoch, refutes=True) \
                or self._ears.heard_again(c.lost, c.until - self._params.claim_hold):
            # Its certificate was refuted during the hold (or never complete): a takeover
            # no other robot would believe is none (DESIGN, "Convergence").
            # Or rule 9's premise failed during the hold: a watcher we took for lost with
            # the suspect heartbeats, so it was our link to it that faded, and our
            # silence is one robot's word. If the suspect is dead, its live watchers go
            # on warning, and the claim comes again from them (a new holder of a watcher
            # slot, after a takeover of its own, is not such a watcher).
            self._claim_refuted()
            return
        ahead = self._forward(c.function, Holder(self._robot_id, c.epoch))
        if ahead.robot != self._robot_id:
            # The robot we would replace refuted a claim of ours at this epoch (an
            # earlier one, during a burst of loss, say): a takeover at this epoch is void
            # wherever that REFUTE goes (`EvidenceStore.voided_by`), outranked by its
            # reassertion, which our view takes instead (DESIGN, "Convergence").
            self._claim_refuted()
            self._learn_reassertion(c.function, ahead, now)
            return
        if greater(self._known[c.function], Holder(self._robot_id, c.epoch)):
            # The slot moved past our claim during the hold: a greater entry is never
            # lowered (`slots.py`), so ours would be fenced at once.
            self._back_off(self._known[c.function].robot)
            return
        self._ev.took_over(c.function, c.failed, c.old_epoch, c.epoch)
        self._emit(ev.Takeover(function=c.function, epoch=c.epoch, replaced=c.failed))
        self._become_holder(Trigger.CLAIM_HELD, c.function, c.epoch, now)

    def _become_holder(self, trigger: Trigger, f: str, epoch: int, now: float) -> None:
        """Execute f at `epoch` from now: the entry (us, epoch) in the table, tell the
        robot, watch f's neighbours, heartbeat now and every heartbeat_interval from now
        on."""
        self._to(trigger, Active(f, epoch))
        self._known.merge(f, Holder(self._robot_id, epoch))
        self._pending.append(Assign(f, epoch))
        self._watch_neighbours(now)
        if self._heartbeating():
            self._send_heartbeat(now)
            self._beat.restart(now)


__all__ = ["Episode"]
