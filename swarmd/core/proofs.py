"""Proofs (DESIGN section 2, "Who may say what" and "Convergence"), in every auth mode:
showing the proof of an entry (`_show`, the one way a proof travels), refuting a warning
or a claim, outranking a takeover the refutes void. The evidence itself — which claim a
certificate backs — is `evidence.py`'s; `Proofs` turns its answers into frames, events
and view changes.

`Proofs` is the layer of `Node` on `Views` (how a view moves forward) and `NodeBase`;
it calls only methods defined there or here. Keeping a warning as evidence
(`Episode._record_evidence`) and acting on a relayed claim are the takeover episode's,
above it: a certificate completed or relayed is a claim heard.
"""

from __future__ import annotations

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.limits import EPOCH_MAX
from swarmd.core.records import Holder
from swarmd.core.slots import greater
from swarmd.core.views import Views

_NO_FRAME = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
"""The `inner` of a CERT this robot sends: only its `raw` bytes go on the wire."""

RELAY_EVERY = 8
"""A holder that took its slot over relays its certificate at least once per this many
T_max even unasked (4 s at udp, 16 s at radio), so every robot that hears the slot holds
the certificate of its holder within that bound."""


class Proofs(Views):
    def _send_cert(self, f: str, raw: bytes) -> None:
        # It has a seq of its own, but receivers do not replay-filter it: the wrapper is
        # unauthenticated, what it relays is judged on its own.
        if self._verifier is None:
            # With a shared key the frame is tagged with the key in force now, which
            # the receivers hold (`wire.retag`); per robot its sender's signature stays.
            raw = wire.retag(raw, self._keys[0] if self._keys else None)
        self._send(wire.Cert(self._plan.slot(f), _NO_FRAME, raw))

    def _forward(self, f: str, new: Holder) -> Holder:
        """The entry the frames held here make of `new`: itself, or, when the robot it
        replaced sent a REFUTE of that claim (rule 4, `_refute_claim`), that robot's
        reassertion at the next epoch (`EvidenceStore.voided_by`): a voided takeover is
        outranked, never undone (`slots.py`; DESIGN, "Convergence")."""
        if new.epoch >= EPOCH_MAX:
            return new
        failed = self._ev.voided_by(f, new.robot, new.epoch)
        return new if failed is None else Holder(failed, new.epoch + 1)

    def _learn_reassertion(self, f: str, new: Holder, now: float) -> None:
        """Our view of f moves forward to a holder's reassertion (`_forward`). Unlike a
        takeover learnt second-hand, it is a sign of life: the holder sent its refute
        while holding f, so a suspicion of the takeover's holder we watched is moot. It
        ends as a refuted one (rule 4), and the watch runs on for the holder (it fires
        again after T_max if that one is silent)."""
        self._learn_holder(f, new, now)
        watch = self._watches.get(f)
        if watch is not None and watch.suspecting and self._known[f] == new:
            watch.heard(now)
            self._emit(ev.Refute(subject=new.robot, function=f))

    def _refute_claim(self, f: str, claimant: int, failed: int | None, epoch: int, seq: int,
                      now: float) -> None:
        """We hold f one epoch below a claim of it that replaces us (`failed`: the robot
        it replaces, as the claim itself or the certificate here says), and we are alive,
        not stalled (rule 4): say that we refute that claim, once. The REFUTE names the
        claimant and the claim's epoch; with the claim's certificate it proves our
        reassertion (`_forward`) to every robot alike. Whether that certificate verifies
        here does not matter: the robots that hold it judge the REFUTE with it, and
        ours may lack a backer it rests on (our own `LEAVE` of the entry we hold is no
        evidence here, `Episode._record_evidence`). Only a claimant that may claim f
        (it covers f) is answered, once a claim: a stream of forged claims gets one
        REFUTE per robot that covers f, no more."""
        if not self._holds(f) or epoch != self._epoch + 1 or failed != self._robot_id \
                or claimant not in self._plan.covered_by(f) \
                or now - self._stalled_at <= self._params.t_max \
                or self._ev.refuted_up_to(f, self._robot_id, epoch, claimant) >= 0:
            return
        msg = wire.Refute(claimant, self._plan.slot(f), epoch, seq)
        self._ev.add_refute(f, self._robot_id, msg, self._send(msg))

    def _show(self, f: str, now: float, every: float | None = None, *,
              whole: bool = True) -> bool:
        """A robot's view of f differs from ours (it heartbeats f, warns about f's
        holder or shows a digest at another entry, or acts on a claim against ours):
        relay the proof of our entry (`EvidenceStore.proof`: the takeover's certificate
        and CLAIM, or a reassertion's, and the holder's REFUTEs at it), inside CERTs
        (they may be older than its replay window), at most once per `every` (T_max by
        default). The one way a proof travels (DESIGN,
        "Convergence"): a stale holder fences itself or refutes, a robot that missed a
        takeover certifies it and moves forward, one that acts on a voided claim drops
        it. Without it, a robot that missed a takeover whose new holder died before it
        heard a heartbeat would warn about the old holder for ever, the others about
        the new one, and the slot's standby would count no quorum. Not `whole`: only
        the REFUTEs, to a robot that acts on a claim they void, on a clock of their own
        (`EvidenceStore.due`). True if it relayed anything."""
        # The clock asked first: the unasked relay asks at every heartbeat of a holder,
        # and building the proof each time would put that work on the frame path.
        if not self._ev.due(f, now, every, whole=whole, stamp=False):
            return False
        holder, epoch = self._known[f]
        frames = self._ev.proof(f, holder, epoch, whole=whole)
        if not frames:
            return False
        self._ev.due(f, now, every, whole=whole)  # due (asked above): the clock starts
        for raw in frames:
            self._send_cert(f, raw)
        return True

    def _show_unasked(self, now: float) -> None:
        """Anti-entropy: the holder shows the proof of its entry every RELAY_EVERY T_max
        even unasked, so a robot that restarted, or missed the takeover (or its undoing)
        and heard nothing since that would make us show it, learns it within that bound
        (DESIGN, "Convergence")."""
        if self._function is not None:
            self._show(self._function, now, RELAY_EVERY * self._params.t_max)

    # ------------------------------------------------------------------ refutes
    # A holder's word that it was alive after a warning voids that warning everywhere
    # the word reaches (DESIGN, "Convergence").

    def _refute(self, f: str, witness: int, epoch: int, seq: int, now: float) -> None:
        """We hold f at `epoch` and hear `witness`'s warning number `seq` about us (or,
        `witness` being us, our own LEAVE of that entry): broadcast that we are alive,
        holding it, after it. Not out of a buffer read after our own stall: then the
        warning was right (we were silent), and the takeover it backs fences us (rule
        2)."""
        if not self._holds(f) or epoch != self._epoch \
                or now - self._stalled_at <= self._params.t_max:
            return
        if witness not in self._ev.may_watch(f, claimants=True):
            return
        if seq <= self._ev.refuted_up_to(f, self._robot_id, epoch, witness):
            # Refuted already: whoever shows it to us again missed our refutes.
            self._show(f, now, whole=False)
            return
        msg = wire.Refute(witness, self._plan.slot(f), epoch, seq)
        self._ev.add_refute(f, self._robot_id, msg, self._send(msg))

    def _on_refute(self, holder: int, r: wire.Refute, now: float, raw: bytes) -> None:
        """A holder's REFUTE, heard or relayed (`_show`). Ours too: relayed back, it is
        one we keep already and moves nothing (`add_refute`); one of ours from before
        this start (restarted without a state file) is as much a fact of this run as a
        peer's, and proves the reassertion the others moved to, which names us: without
        it we would be fenced by the very claim it voids (DESIGN, "Every proof is bound
        to its run")."""
        f = self._slot(r.function)
        if f is None:
            return  # a bad slot (counted)
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
            self._claim_refuted()
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


__all__ = ["RELAY_EVERY", "Proofs"]
