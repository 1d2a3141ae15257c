"""Per-robot mode's part of the node (DESIGN section 2, "Who may say what" and
"Convergence"): recording signed evidence, relaying certificates and refutes, signing
refutes, undoing a takeover the refutes void, verifying a restored hold. The evidence
itself — which claim a certificate backs — is `evidence.py`'s; `Signed` turns its
answers into frames, events and role changes.
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Assign
from swarmd.core.drops import DropReason
from swarmd.core.evidence import cert_says, seq_of
from swarmd.core.limits import EPOCH_MAX
from swarmd.core.nodebase import NodeBase
from swarmd.core.records import Holder, Restored
from swarmd.core.roles import Role, Trigger
from swarmd.core.slots import greater
from swarmd.core.state import Active, Standby

_NO_FRAME = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
"""The `inner` of a CERT this robot sends: only its `raw` bytes go on the wire."""

RELAY_EVERY = 8
"""Per-robot mode: a holder that took its slot over relays its certificate at least
once per this many T_max even unasked (4 s at udp, 16 s at radio), so every robot that
hears the slot holds the certificate of its holder within that bound."""


class Signed(NodeBase):
    def _verified_hold(self, f: str, epoch: int,
                       restored: Restored) -> tuple[str, int] | None:
        """The hold of f at `epoch` a restarted robot read from its state file, if it is
        provable as a received one would be — the plan's own holder at epoch 0, or a
        certificate that verifies and backs it; otherwise None (it rejoins as a standby,
        and the slot's watchers take it over if nobody holds it)."""
        assert self._verifier is not None
        if epoch == 0:
            return (f, 0) if self._plan.initial_holder(f) == self._robot_id else None
        if self._ev.restore(f, epoch, tuple(restored.certificate), self._verifier):
            self._known.merge(f, Holder(self._robot_id, epoch))
            return (f, epoch)
        return None

    def _sign_only(self, msg: wire.Message) -> bytes:
        """A frame signed by this robot, for a certificate, not broadcast by itself."""
        assert self._signer is not None
        self._seq = min(self._seq + 1, wire.SEQ_MAX)
        frame = wire.Frame(self._plan.swarm_id, self._robot_id, self._seq, msg)
        return wire.encode(frame, None, self._signer)

    def _send_cert(self, f: str, raw: bytes) -> None:
        # It has a seq of its own, but receivers do not replay-filter it: the wrapper is
        # unauthenticated, what it relays is signed and judged on its own.
        self._send(wire.Cert(self._plan.slot(f), _NO_FRAME, raw))

    def _record_evidence(self, f: str, witness: int, suspect: int, epoch: int,
                         raw: bytes, now: float | None = None) -> None:
        if suspect == self._robot_id and now is not None:
            # Evidence against us, relayed in a certificate (we may have missed the
            # warning itself): while we hold the slot, we refute it (rule 4). Our own
            # LEAVE of the very entry we hold is a recording, of an earlier run or of a
            # hold we resumed after a restart (`evidence.py`): refuted alike, so that it
            # backs no takeover of the slot we execute.
            self._refute(f, witness, epoch, seq_of(raw), now)
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
        for claimant, claim, signed in ready:
            assert now is not None  # `record` readies a claim only with a `now`
            self._on_claim(claimant, claim, now, signed)

    def _forward(self, f: str, new: Holder) -> Holder:
        """The entry the signed frames held here make of `new`: itself, or, per robot,
        when the robot it replaced signed a REFUTE of that claim (rule 4,
        `_refute_claim`), that robot's reassertion at the next epoch
        (`EvidenceStore.voided_by`): a voided takeover is outranked, never undone
        (`slots.py`; DESIGN, "Convergence")."""
        if self._identity is None or new.epoch >= EPOCH_MAX:
            return new
        failed = self._ev.voided_by(f, new.robot, new.epoch)
        return new if failed is None else Holder(failed, new.epoch + 1)

    def _learn_reassertion(self, f: str, new: Holder, now: float) -> None:
        """Our view of f moves forward to a holder's reassertion (`_forward`). Unlike a
        takeover learnt second-hand, it is a sign of life: the holder signed its refute
        while holding f, so a suspicion of the takeover's holder we watched is moot. It
        ends as a refuted one (rule 4), and the watch runs on for the holder (it fires
        again after T_max if that one is silent)."""
        self._learn_holder(f, new, now)
        watch = self._watches.get(f)
        if watch is not None and watch.suspecting and self._known[f] == new:
            watch.heard(now)
            self._emit(ev.Refute(subject=new.robot, function=f))

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

    def _refute_claim(self, f: str, claimant: int, epoch: int, seq: int, now: float) -> None:
        """Per robot: we hold f one epoch below a certified claim of it that replaces us,
        and we are alive, not stalled (rule 4): sign that we refute that claim, once. The
        signed REFUTE names the claimant and the claim's epoch; with the claim's
        certificate it proves our reassertion (`_forward`) to every robot alike."""
        if self._identity is None or not self._holds(f) or epoch != self._epoch + 1 \
                or now - self._stalled_at <= self._params.t_max \
                or self._ev.replaced(f, claimant, epoch) != self._robot_id \
                or self._ev.refuted_up_to(f, self._robot_id, epoch, claimant) >= 0:
            return
        msg = wire.Refute(claimant, self._plan.slot(f), epoch, seq)
        self._ev.add_refute(f, self._robot_id, msg, self._send(msg))

    def _relay_cert(self, f: str | None, now: float, every: float | None = None) -> None:
        """Someone still believes an older holder of our slot: relay the certificate of
        our hold and re-announce the claim it backs, at most once per T_max (`every`)."""
        if f is None:
            return
        if self._identity is not None \
                and self._ev.reasserted(f, self._robot_id, self._epoch) is not None:
            self._relay_view(f, now, every)  # a reassertion: its proof is the view's
            return
        mine = self._ev.relay(f, now, every)
        if mine is None:
            return
        failed, frames = mine
        for raw in frames:
            self._send_cert(f, raw)
        self._send(wire.Claim(failed, self._plan.slot(f), self._epoch))

    def _relay_unasked(self, now: float) -> None:
        """Anti-entropy: a robot that restarted, or missed the takeover (or its undoing)
        and heard nothing since that would make us relay, learns it within RELAY_EVERY
        T_max (DESIGN, "Convergence")."""
        if self._identity is None or self._role != Role.ACTIVE or self._function is None:
            return
        every = RELAY_EVERY * self._params.t_max
        if self._epoch:
            self._relay_cert(self._function, now, every)
        # And the refutes of a takeover of our slot we undid: a robot that restarted
        # with it in its view learns it is void (`_rejudge`).
        for raw in self._ev.refute_frames(self._function, self._robot_id, self._epoch, now,
                                          every):
            self._send_cert(self._function, raw)

    def _on_cert(self, cert: wire.Cert, now: float) -> None:
        f = self._slot(cert.function)
        if f is None:
            return
        msg = cert.inner.msg
        if self._outdated(cert.inner.sender, cert.inner.seq, msg, now):
            # Its signer's own later heartbeat says otherwise: a recorded LEAVE of an
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
        said = cert_says(cert)
        if said is not None:
            self._record_evidence(f, *said, cert.raw, now)

    def _relay_view(self, f: str, now: float, every: float | None = None) -> bool:
        """Someone's view of f is older than ours (it heartbeats f, or warns about f's
        holder, at an older epoch): if a certificate here backs our view, relay it
        whole, the signed CLAIM last (`EvidenceStore.view_frames`), at most once per
        T_max. Without it, a robot that missed a takeover whose new holder died before
        it heard a heartbeat would warn about the old holder for ever, the others
        about the new one, and the slot's standby would count no quorum (DESIGN,
        "Convergence"). True if it relayed anything."""
        holder, epoch = self._known[f]
        frames = self._ev.view_frames(f, holder, epoch, now, every)
        for raw in frames:
            self._send_cert(f, raw)
        return bool(frames)

    def _on_relayed_claim(self, f: str, claimant: int, c: wire.Claim, raw: bytes,
                          now: float) -> None:
        """A signed CLAIM relayed inside a CERT (`_relay_view`): heard as a claim (rule
        10 bounds what a repeat does), and, if the evidence here certifies it and its
        entry is greater than our view of f, our view moves forward to it
        (`_learn_holder`) — as far as a heartbeat of its claimant would have moved it,
        since a robot relays only the entry its own view holds. Holding f below it, we
        fence (rule 2), as that heartbeat would have fenced us — unless the claim
        replaces our own live hold: then we refute it (`Hearing._on_claim`) and the
        entry we move to is our reassertion (`_forward`), unless we were stalled, and
        then the takeover was right. Our own claim relayed back acts on nothing here."""
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

    # ------------------------------------------------------------------ refutes
    # A holder's signed word that it was alive after a warning voids that warning
    # everywhere the word reaches (DESIGN, "Convergence").

    def _refute(self, f: str, witness: int, epoch: int, seq: int, now: float) -> None:
        """We hold f at `epoch` and hear `witness`'s warning number `seq` about us (or,
        `witness` being us, our own LEAVE of that entry): sign and broadcast that we are
        alive, holding it, after it. Not out of a buffer read after our own stall: then
        the warning was right (we were silent), and the takeover it backs fences us
        (rule 2)."""
        if self._identity is None or self._role != Role.ACTIVE or f != self._function \
                or epoch != self._epoch or now - self._stalled_at <= self._params.t_max:
            return
        if witness not in self._ev.may_watch(f, claimants=True):
            return
        if seq <= self._ev.refuted_up_to(f, self._robot_id, epoch, witness):
            # Refuted already: whoever shows it to us again missed our refutes.
            self._relay_refutes(f, now)
            return
        msg = wire.Refute(witness, self._plan.slot(f), epoch, seq)
        self._ev.add_refute(f, self._robot_id, msg, self._send(msg))

    def _on_refute(self, holder: int, r: wire.Refute, now: float, raw: bytes) -> None:
        f = self._slot(r.function)
        if f is None or holder == self._robot_id:
            return  # a bad slot (counted), or our own refute relayed back
        if self._ev.add_refute(f, holder, r, raw):
            self._rejudge(f, now, Holder(holder, r.epoch))

    def _rejudge(self, f: str, now: float, refuter: Holder) -> None:
        """New refutes of f came from `refuter` (holder, epoch): a claim of ours that they
        void ends in its wait state (rule 4: the suspect is alive); a takeover in our view
        that they void is outranked by the refuter's reassertion at the next epoch
        (`_forward`): views only move forward (`slots.py`; DESIGN, "Convergence")."""
        c = self._claim
        if c is not None and c.function == f and not self._ev.certify(
                f, self._robot_id, wire.Claim(c.failed, self._plan.slot(f), c.epoch), 0,
                refutes=True):
            self._emit(ev.Refute(subject=c.failed, function=f))
            self._to(Trigger.REFUTED, Standby())
        known = self._known[f]
        ahead = self._forward(f, known)
        if ahead != known:
            self._learn_reassertion(f, ahead, now)
        # A refute of a claim (its own epoch, `_refute_claim`) proves the refuter's
        # reassertion one epoch above it, and a refute of its own LEAVE (the epoch it
        # held) the reassertion above the claim that LEAVE backed, whatever entry our
        # view holds now: a relayed proof brings it to a robot whose view moved on
        # without it (a rival at that epoch, or none).
        for epoch in (refuter.epoch + 1, refuter.epoch + 2):
            mine = Holder(refuter.robot, epoch)
            if epoch <= EPOCH_MAX and greater(mine, self._known[f]) \
                    and self._ev.reasserted(f, mine.robot, mine.epoch) is not None:
                self._learn_reassertion(f, mine, now)

    def _relay_refutes(self, f: str, now: float) -> None:
        """Someone acts on a takeover of f that refutes we hold void (an uncertified
        heartbeat or claim): relay them, inside CERTs (they may be older than its replay
        window), at most once per T_max."""
        if self._identity is None:
            return
        holder, epoch = self._known[f]
        for raw in self._ev.refute_frames(f, holder, epoch, now):
            self._send_cert(f, raw)


__all__ = ["RELAY_EVERY", "Signed"]
