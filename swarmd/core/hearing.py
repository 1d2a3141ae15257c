"""What a robot does with each message it accepts that the takeover episode does not
take whole (paper Figs. 7-9, DESIGN rules 1-10): HEARTBEAT (the holder heard: watchdog,
votes, a claim and a rejoin learn it; an older or unproven one answered), LEAVE (the
handover, rule 7) and CERT (evidence relayed in a certificate).

`Hearing` is the layer of `Node` on `Episode` (`episode.py`: WARN and CLAIM, from
suspicion to takeover), which sits on `Proofs`, `Views` and `NodeBase`; it calls only
methods defined there or here. Every method changes the node's state and queues
actions; none does I/O.
"""

from __future__ import annotations

from swarmd.core import digest, wire
from swarmd.core import events as ev
from swarmd.core.drops import DropReason
from swarmd.core.episode import Episode
from swarmd.core.evidence import says
from swarmd.core.records import Holder
from swarmd.core.roles import Health, Role, Trigger
from swarmd.core.slots import greater
from swarmd.core.state import Active, Claiming


class Hearing(Episode):
    # ------------------------------------------------------------------ HEARTBEAT
    def _on_heartbeat(self, sender: int, hb: wire.Heartbeat, now: float) -> None:
        for votes in self._votes.values():
            # A witness heard, its warning overdue: it stopped suspecting (`votes.py`).
            votes.witness_heard(sender, now)
        if hb.function == 0:
            if hb.role in (Role.STANDBY, Role.CLAIMING) and hb.health != Health.FAULTY:
                self._ears.standby_beat(sender, now)
            self._digest_heard(sender, hb.epoch, now)
            return
        f = self._slot(hb.function)
        if f is None:
            return
        known, entry = self._known[f], Holder(sender, hb.epoch)
        if greater(known, entry):
            self._older_beat(f, sender, hb, known, now)
            return
        if entry != known and not self._ev.is_certified(f, sender, hb.epoch):
            self._unproven_beat(f, hb, DropReason.UNCERTIFIED, now)
            return
        # Ours, heard from another robot (our own frames never get here, `Node._accept`
        # drops them as `own`): the one case below that moves our role.
        rival = self._holds(f)
        if rival:
            # If its certified claim replaces us, rule 4.
            self._refute_claim(f, sender, self._ev.replaced(f, sender, hb.epoch), hb.epoch,
                               0, now)
        ahead = self._forward(f, entry)
        if ahead != entry:
            # A takeover that the robot it replaced refuted. Its holder is outranked by
            # that robot's reassertion; show it why.
            self._learn_reassertion(f, ahead, now)
            self._show(f, now)
            return
        self._known.merge(f, entry)
        self._ears.slot_beat(f, sender, hb.epoch, now)
        self._claims_seen.forget(f)
        # Rule 2: a greater entry for the slot we execute (a higher epoch, or ours by a
        # lower id) ends our hold. Only if `rival`: nothing since made us hold f.
        if rival and self._holds(f):
            self._fence(hb.epoch, now)
            return
        self._holder_heard(f, sender, hb.epoch, known, now)

    def _digest_heard(self, sender: int, shown: int, now: float) -> None:
        """A heartbeat without a slot shows, in its epoch field, its sender's view of
        the slots it covers (`digest.py`). If it shows the slot we hold at an entry
        other than ours, one of us is behind: we answer at once with our proof
        (`_show`), and an extra heartbeat, whose entry it merges (per robot an anchor: a
        robot that restarted has lost our chain). So a standby that missed a takeover
        learns it within one standby period rather than the unasked relay's RELAY_EVERY
        T_max (DESIGN, "Convergence"). If the sender is ahead, our own heartbeats, every
        period, are the stale ones it answers (`_older_beat`).

        At most once per T_max per slot, or per half a standby period where that is
        shorter: a standby shows a new digest once a standby period, so the gate never
        skips its next one, and a forged digest makes us answer no faster."""
        f = self._function
        if f is None or not digest.differs(shown, self._plan.covered(sender), f, self._epoch):
            return
        every = min(self._params.t_max, self._params.standby_heartbeat_interval / 2)
        if not self._ev.answer_due(f, now, every):
            return
        # The gate above bounds it: a relay of ours to someone else within T_max before
        # (the unasked one, say) did not reach this robot, or it would not show an older
        # view.
        self._show(f, now, 0.0)
        if not self._heartbeat_now(now) and self._chain is not None:
            # Too soon after our last heartbeat for an extra one: the next one, within
            # a heartbeat period, carries our entry, and per robot as an anchor.
            self._chain.anchor_next()

    def _older_beat(self, f: str, sender: int, hb: wire.Heartbeat, known: Holder,
                    now: float) -> None:
        """A heartbeat for f older than our view of it (`known`): its sender missed a
        takeover, or lost a race at the same epoch; show it what it missed. If it is the
        robot our view names, behind on its own entry, it is alive all the same: its
        watchdog and our ears hear it."""
        # A stale holder (e.g. back from a pause): if it is our slot, answer at once
        # so it hears the newer epoch and fences itself (rule 2) within a frame.
        if self._holds(f):
            # Two robots execute our slot until the proof reaches it: a rival at our
            # epoch (the race won on each side of a partition) lacks only our CLAIM,
            # most likely; a holder back from a pause lacks the whole takeover, and
            # once its stall is T_max behind it, it would refute the warnings in it
            # instead of fencing itself. Every other heartbeat period, not every T_max,
            # so a lossy channel does not keep two executors past the bound (rule 2).
            self._show(f, now, 2 * self._params.heartbeat_interval)
            self._heartbeat_now(now)
        # Else a takeover it missed whose new holder may be gone: whoever certified it
        # shows the stale holder the evidence against it (it fences itself, or refutes
        # and keeps its slot everywhere).
        else:
            if sender == known.robot:
                # Its own hold below the entry naming it here (its reassertion, made of
                # its refutes, which reached us before it learnt it): it executes f and
                # is alive. A watchdog, and a standby's own ears (rules 4 and 9), judge
                # the robot the entry names, at whatever epoch it heartbeats: so the
                # watchdog is fed as by a heartbeat at the entry, or we would suspect a
                # live holder T_max later, the very time our next relay below brings it
                # forward; and a standby neither counts itself a witness of its silence
                # nor lets one warning outvote what it heard. Nothing else moves: a
                # claim against the entry already went out with its certificate, and a
                # holder behind its entry refutes no warning about it. A suspicion it
                # ends is logged as refuted, as `_holder_heard` logs one.
                watch = self._watches.get(f)
                if watch is not None and watch.heard(now, self._ears.patience(sender)):
                    self._emit(ev.Refute(subject=sender, function=f))
                self._ears.slot_beat(f, sender, known.epoch, now)
            if self._show(f, now) and sender == known.robot \
                    and self._ev.reasserted(f, sender, known.epoch) is not None:
                # Its own hold, below the reassertion our view holds: it refuted a
                # recorded takeover that we took before its word reached us and did not
                # reassert (DESIGN, "Every proof is bound to its run"). A doubt (no
                # standby counts it) tells it so; on our next relay it reasserts.
                self._send(wire.Warn(sender, hb.function, known.epoch, 0))

    def _unproven_beat(self, f: str | None, hb: wire.Heartbeat, reason: str,
                       now: float) -> None:
        """A heartbeat (naming slot f) that proves nothing here, counted as `reason`: per
        robot its link is not tied to its sender's chain (`unanchored`, `chain.py`: we
        lost the chain, or it is forged), or no certificate here backs the hold it names
        (`uncertified`: a heartbeat is no proof, so it never moves an epoch or a holder
        by itself; only the certified new holder's does). It moves nothing, but the
        answers cost nothing to give. If we hold f, its sender shows another view of our
        slot: we show it our proof and, to a stale one, a heartbeat (per robot an anchor:
        it may have lost our chain too; rule 2 within a frame). Otherwise we show the
        REFUTEs we hold: it may act on a claim they void. And a robot rejoining f stays a
        standby rather than resume it: the cautious side of rule 2 across a reboot (the
        slot's watchers and standbys take it over if nobody really holds it)."""
        self._drops[reason] += 1
        if f is None:
            return
        holds = self._holds(f)
        self._show(f, now, whole=holds)
        if holds and hb.epoch <= self._epoch:
            self._heartbeat_now(now)
        self._rejoin_superseded(f, hb.epoch)

    def _holder_heard(self, f: str, sender: int, epoch: int, before: Holder,
                      now: float) -> None:
        """f's holder (`sender` at `epoch`; `before`: the view until now) heartbeated:
        watchdog, votes, our claim and our rejoin learn it."""
        # The role read once: only an active robot watches, claims and rejoins are
        # roles of their own (`state.py`), and the watch's verdict moves no role.
        state = self._state
        watch = state.watches.get(f) if isinstance(state, Active) else None
        if watch is not None:
            suspected = watch.suspecting
            reasserted = epoch > before.epoch \
                and self._ev.reasserted(f, sender, epoch) is not None
            if watch.heard(now, self._ears.patience(sender)) and suspected \
                    and (epoch <= before.epoch or sender == before.robot or reasserted):
                # The suspect heard alive (rule 4), or the rival that won the suspect's
                # own takeover race at its epoch (lowest id): the suspicion is over, and
                # the log says so (the paper's property: every warning ends in a
                # takeover, a refutation or an alert). Another holder at a newer epoch
                # ends it by its takeover, unless that epoch is its reassertion (per
                # robot: it refuted the takeover we suspected, DESIGN "Convergence").
                # The suspect itself at a newer epoch is alive whatever took it there:
                # it may have taken its own slot over, restarted as a standby, in a
                # takeover we missed and logged before we warned.
                self._emit(ev.Refute(subject=sender, function=f))
        votes = self._votes.get(f)
        if votes is not None and votes.witnesses:
            votes.clear()  # rule 4: the suspect is alive, or a new holder is
        if isinstance(state, Claiming) and state.wait.function == f:
            if epoch >= state.wait.epoch:
                self._back_off(sender)
            elif sender == state.wait.failed:
                self._claim_refuted()
        self._rejoin_superseded(f, self._known[f].epoch)

    # ------------------------------------------------------------------ LEAVE
    def _on_leave(self, sender: int, lv: wire.Leave, now: float, raw: bytes = b"") -> None:
        f = self._slot(lv.function)
        if f is None:
            return
        # A LEAVE from the holder itself is evidence enough for its own slot.
        self._record_evidence(f, sender, sender, lv.epoch, raw, now)
        if (sender, lv.epoch) != self._known[f]:
            return  # not the current holder: stale
        watch = self._watches.get(f)
        if watch is not None:
            watch.claim_heard(now)
            if not self._ears.live_standby(f, sender, now):
                watch.mark_alerted()
                self._emit(ev.Alert(function=f, reason=ev.AlertCause.NO_STANDBY))
        if f in self._covers and self._standing_by():
            self._start_claim(f, sender, lv.epoch, now, trigger=Trigger.LEAVE_HEARD)

    # ------------------------------------------------------------------ CERT
    def _on_cert(self, cert: wire.Cert, now: float) -> None:
        f = self._slot(cert.function)
        if f is None:
            return
        msg = cert.inner.msg
        if self._outdated(cert.inner.sender, cert.inner.seq, msg, now):
            # Its sender's own later heartbeat says otherwise: a recorded LEAVE of an
            # earlier run backs nothing (DESIGN, "Every proof is bound to its run"),
            # refused before it is kept as evidence.
            self._drops[DropReason.OUTDATED] += 1
            return
        if isinstance(msg, wire.Refute):
            self._on_refute(cert.inner.sender, msg, now, cert.raw)
            return
        if isinstance(msg, wire.Claim):
            self._on_relayed_claim(f, cert.inner.sender, msg, cert.raw, now)
            return
        said = says(cert.inner)
        if said is not None:
            self._record_evidence(f, *said, cert.raw, now)


__all__ = ["Hearing"]
