"""Takeover certificates of one robot, in every auth mode (DESIGN section 2, "Who may say
what").

Every WARN, CLAIM, LEAVE and REFUTE carries what authenticates its sender in the swarm's
mode — per robot its own signature, with a shared key the swarm key's tag, unsigned
nothing — so a robot can show what others said, and each receiver checks it as if it
had heard it first-hand. A *certificate* is the set of frames that back a takeover of
slot f from `suspect` at `epoch`: the suspect's own LEAVE, or the WARNs of at least a
quorum of distinct witnesses (rule 3: the robots that may hold a slot watching f, plus
the claimant's own ears once, rule 9; never the suspect) that the suspect has not
refuted. An epoch rises only for a CLAIM whose certificate this robot verified, so one
liar alone — whatever it signs — never moves a slot (per robot; with a shared key an
insider can make frames in any name); and the new holder relays its certificate to
whoever missed it.

*One answer everywhere* (DESIGN, "Convergence"): whether a claim is certified is a
function of frames only — the warnings, the suspect's LEAVE, the suspect's REFUTEs —
never of when this robot happened to hear what. A suspect alive after a witness's
warning says so in a REFUTE naming that warning's seq; it voids that
warning and every earlier one of that witness, at every robot that has the REFUTE,
which the frames' holders relay to whoever still acts on a voided claim. Robots that
hold the same frames therefore hold the same view of every slot.

*Every proof is bound to its run* (DESIGN, "Who may say what"): a holder's LEAVE is
refuted the same way, by the holder itself — `REFUTE(holder, f, epoch, seq)`, itself
as the witness. Within one run of a daemon a robot never holds again the entry it left
(the slot can only come back to it at a higher epoch), so a LEAVE of its own about the
very entry it holds is a recording (an earlier run's, or a hold it resumed after a
restart that nobody took over): it answers it so, and the takeover that LEAVE backs
is void wherever the REFUTE reaches (`voided_by`).

State, per slot f (all bounded: a flood of invented epochs or claimants pushes out
the oldest, it cannot grow the store):
- `evidence`: {(suspect, epoch): {witness: its latest signed WARN or LEAVE}}.
- `refutes`: {(holder, epoch): {witness: (highest refuted seq, the signed REFUTE)}}.
- `certified`: {(claimant, epoch): (failed, {backer: seq})} of the CLAIMs a certificate
  backed here, re-judged against the refutes whenever it is asked about.
- `pending`: {(claimant, epoch): (failed, first heard, raw)}, claims heard before their
  certificate (a channel that reorders), counted once it comes, if still fresh.
- `claims`: {(claimant, epoch): the claimant's signed CLAIM} of the claims certified
  here, so that the whole certificate of a takeover — the evidence and the claim it
  backs — can be shown to a robot whose view of f differs (`proof`).
- `mine`: (epoch, failed, frames), the certificate of this robot's own hold of f.
- `relayed_at`: when the proof of our entry for f was last relayed (once per T_max);
  `refutes_relayed_at`, its REFUTEs alone; `digest_answered_at`, when a digest that
  showed f otherwise was last answered.

Sans-IO and pure: every method takes what it needs (`now`, the epoch floor of f) and
returns a decision or frames; the `Node` sends, emits and counts drops.
"""

from __future__ import annotations

from collections.abc import Sequence

from swarmd.core import wire
from swarmd.core.auth import Verifier
from swarmd.core.claims import CLAIMS_REMEMBERED
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.replay import header_seq

EVIDENCE_REMEMBERED = 16
"""(suspect, epoch) episodes of evidence kept per slot; a flood
of warnings about invented epochs pushes out the oldest, it cannot grow the node."""


class EvidenceStore:
    """The evidence, refutes, certificates and pending claims of one robot (module doc)."""

    def __init__(self, robot_id: int, plan: SwarmPlan, params: Params) -> None:
        self._robot_id = robot_id
        self._plan = plan
        self._params = params
        self._evidence: dict[str, dict[tuple[int, int], dict[int, bytes]]] = {}
        self._refutes: dict[str, dict[tuple[int, int], dict[int, tuple[int, bytes]]]] = {}
        self._certified: dict[str, dict[tuple[int, int], tuple[int, dict[int, int]]]] = {}
        self._pending: dict[str, dict[tuple[int, int], tuple[int, float, bytes]]] = {}
        self._claims: dict[str, dict[tuple[int, int], bytes]] = {}
        self._mine: dict[str, tuple[int, int, tuple[bytes, ...]]] = {}
        self._relayed_at: dict[str, float] = {}
        self._refutes_relayed_at: dict[str, float] = {}
        self._digest_answered_at: dict[str, float] = {}
        self._may_watch_cache: dict[tuple[str, bool], frozenset[int]] = {}

    # ------------------------------------------------------------------ evidence
    def record(self, f: str, witness: int, suspect: int, epoch: int, raw: bytes,
               floor: int, now: float | None = None,
               ) -> list[tuple[int, wire.Claim, bytes]] | None:
        """Keep `witness`'s signed frame `raw` against `suspect` at `epoch` (`floor`:
        the epoch of f as known). None when the suspect refuted it; otherwise the
        pending claims it now certifies (claimant, claim, its signed bytes), still
        fresh at `now`, for the node to count."""
        if not raw or epoch + 2 < floor:
            # Older than anything that can still change our view. Evidence about the two
            # epochs below it is kept: about E - 1, it may back a rival claim of that same
            # takeover, which the lower id wins (the paper's race, after a partition
            # healed); about E - 2, a takeover at E - 1 that its holder refuted, whose
            # reassertion at E outranks a rival there (DESIGN, "Convergence").
            return []
        # A warning the suspect refuted, or its own LEAVE it refuted (a recording:
        # module doc).
        refuted = self.refuted_up_to(f, suspect, epoch, witness) >= header_seq(raw)
        episodes = self._evidence.setdefault(f, {})
        got = episodes.get((suspect, epoch))
        if got is None:
            if len(episodes) >= EVIDENCE_REMEMBERED:
                del episodes[next(iter(episodes))]
            got = episodes[(suspect, epoch)] = {}
        old = got.get(witness)
        if old is None or header_seq(old) < header_seq(raw):
            got[witness] = raw  # the latest: the least likely to be refuted
        if refuted:
            # The suspect said, signed, that it was alive after this warning (rule 4): no
            # new claim may rest on it. Kept all the same: a takeover it backed that was
            # accepted somewhere stands (entries only move forward, `slots.py`), and
            # every robot must be able to verify that takeover alike.
            return None
        ready: list[tuple[int, wire.Claim, bytes]] = []
        pending = self._pending.get(f)
        if pending:
            for (claimant, new_epoch), (failed, heard, signed) in list(pending.items()):
                claim = wire.Claim(failed, self._plan.slot(f), new_epoch)
                if (failed, new_epoch - 1) == (suspect, epoch) \
                        and self.certify(f, claimant, claim, floor):
                    # Its certificate came after it (a channel that reorders): the
                    # claim counts now, if it is still a fresh one.
                    del pending[(claimant, new_epoch)]
                    if now is not None and now - heard <= self._params.claim_hold:
                        ready.append((claimant, claim, signed))
        return ready

    def _backers(self, f: str, suspect: int, epoch: int, claimant: int,
                 refutes: bool = False) -> dict[int, int]:
        """{witness: seq} of the signed evidence backing `claimant` taking f over from
        `suspect` at `epoch`: the suspect's own LEAVE alone (the suspect as its own
        backer), or the warnings of distinct witnesses (the robots that may hold a slot
        watching f, rule 3, and the claimant itself as rule 9's own ears, once), never
        the suspect's. With `refutes`, only the frames the suspect has not refuted: what
        a claimant may still act on."""
        got = self._evidence.get(f, {}).get((suspect, epoch))
        if not got:
            return {}
        leave = got.get(suspect)
        if leave is not None and (
                not refutes
                or header_seq(leave) > self.refuted_up_to(f, suspect, epoch, suspect)):
            return {suspect: header_seq(leave)}
        may = self.may_watch(f)
        out: dict[int, int] = {}
        for w, raw in got.items():
            if w != suspect and (w == claimant or w in may):
                seq = header_seq(raw)
                if not refutes or seq > self.refuted_up_to(f, suspect, epoch, w):
                    out[w] = seq
        return out

    def _enough(self, failed: int, backers: dict[int, int]) -> bool:
        """A quorum of witnesses, or the failed robot's own LEAVE (`_backers` never
        counts the suspect as a witness, so its entry is that LEAVE)."""
        return failed in backers or len(backers) >= self._params.quorum

    def may_watch(self, f: str, *, claimants: bool = False) -> frozenset[int]:
        """Every robot that may hold a slot watching f (its holder or a substitute):
        judged by the plan, not by `known`, so a robot that cannot hear who holds a
        watching slot now (DESIGN section 2, "What a robot hears") still verifies the
        certificate. Witnesses stay distinct robots, so one robot is one witness."""
        key = (f, claimants)
        got = self._may_watch_cache.get(key)
        if got is None:
            got = frozenset(r for g in self._plan.watched_by(f) for r in self._plan.covered_by(g))
            if claimants:  # rule 9: a claimant's own ears count as one witness
                got |= frozenset(self._plan.covered_by(f))
            self._may_watch_cache[key] = got
        return got

    # ------------------------------------------------------------------ certificates
    def certify(self, f: str, claimant: int, c: wire.Claim, floor: int, *,
                refutes: bool = False) -> bool:
        """Does the evidence held back `claimant`'s CLAIM `c` of f? (`floor`: the epoch
        of f as known; certified takeovers older than it are forgotten first.) A claim
        certified stays certified: signed frames alone decide it, so every robot that
        holds them judges alike (DESIGN, "Convergence"). With `refutes`, the question a
        claimant asks before it takes over: is it still backed once the suspect's
        refutes are counted (rule 4)?"""
        if claimant not in self._plan.covered_by(f):
            return False
        certified = self._certified.setdefault(f, {})
        backers = self._backers(f, c.failed, c.epoch - 1, claimant, refutes)
        if not self._enough(c.failed, backers):
            old = certified.get((claimant, c.epoch))
            # Evidence pushed out by a flood is judged by what it was.
            return old is not None and old[0] == c.failed \
                and (not refutes or self._still(f, c.epoch, old))
        if (claimant, c.epoch) not in certified and len(certified) >= CLAIMS_REMEMBERED:
            for key in [k for k in certified if k[1] < floor] or [next(iter(certified))]:
                del certified[key]
        certified[(claimant, c.epoch)] = (c.failed, backers)
        return True

    def _still(self, f: str, epoch: int, entry: tuple[int, dict[int, int]]) -> bool:
        failed, backers = entry
        left = {w: s for w, s in backers.items()
                if s > self.refuted_up_to(f, failed, epoch - 1, w)}
        return self._enough(failed, left)

    def is_certified(self, f: str, claimant: int, epoch: int) -> bool:
        """Is (claimant, epoch) of f an entry the signed frames held here prove: a takeover
        a certificate backs, or a holder's reassertion over a takeover its refutes void
        (`reasserted`)?"""
        entry = self._certified.get(f, {}).get((claimant, epoch))
        if entry is not None and self.certify(
                f, claimant, wire.Claim(entry[0], self._plan.slot(f), epoch), 0):
            return True
        return self.reasserted(f, claimant, epoch) is not None

    def voided_by(self, f: str, claimant: int, epoch: int) -> int | None:
        """The holder whose signed word voids the certified takeover (claimant, epoch) of
        f, or None: the robot it replaced, which signed a REFUTE of that very claim
        (`REFUTE(claimant, f, epoch, seq)`, the claim's own epoch: it was holding f, and
        not stalled, when the claim reached it; rule 4), or, for a takeover its own
        LEAVE backs, its REFUTE of that LEAVE (module doc: a recording of another run).
        One signed frame decides it, so every robot that holds that frame and the
        certificate judges alike, whichever backers each happens to hold: the refute of
        the claim voids it whether or not a robot holds the LEAVE too. Only a robot that
        holds the entry the LEAVE left refutes the claim, and within one run a robot
        never holds that entry again: it came back without its state file, as the
        plan's holder (a robot restarted on its state file after a LEAVE holds nothing,
        and rejoins nothing)."""
        return None if self._voiding(f, claimant, epoch) is None else \
            self._certified[f][(claimant, epoch)][0]

    def _voiding(self, f: str, claimant: int, epoch: int) -> bytes | None:
        """The signed REFUTE that voids the certified takeover (claimant, epoch) of f
        (`voided_by`), or None."""
        entry = self._certified.get(f, {}).get((claimant, epoch))
        if entry is None:
            return None
        failed, backers = entry
        refutes = self._refutes.get(f, {})
        got = refutes.get((failed, epoch), {}).get(claimant)
        if got is not None:
            return got[1]
        if failed in backers:  # backed by its LEAVE, which only failed itself refutes
            got = refutes.get((failed, epoch - 1), {}).get(failed)
            return got[1] if got is not None and got[0] >= backers[failed] else None
        return None

    def reasserted(self, f: str, holder: int, epoch: int) -> int | None:
        """Is (holder, epoch) of f the reassertion of `holder`'s hold at `epoch - 2` over a
        takeover at `epoch - 1` that its refutes void? The claimant of that takeover if
        so. The entry the refutes produce is the next epoch, never the old one: the
        slot table only moves forward (`slots.py`; DESIGN, "Convergence")."""
        for (claimant, e), (failed, _) in self._certified.get(f, {}).items():
            if e == epoch - 1 and failed == holder \
                    and self.voided_by(f, claimant, e) == holder:
                return claimant
        return None

    def replaced(self, f: str, claimant: int, epoch: int) -> int | None:
        """The robot a certified (claimant, epoch) of f replaced, if known here."""
        entry = self._certified.get(f, {}).get((claimant, epoch))
        return entry[0] if entry is not None else None

    def hold_pending(self, f: str, claimant: int, c: wire.Claim, now: float,
                     raw: bytes = b"") -> None:
        """Keep an uncertified claim a while, in case its certificate comes later."""
        pending = self._pending.setdefault(f, {})
        if len(pending) >= CLAIMS_REMEMBERED:
            del pending[next(iter(pending))]
        pending[(claimant, c.epoch)] = (c.failed, now, raw)

    def keep_claim(self, f: str, claimant: int, epoch: int, raw: bytes) -> None:
        """Keep the signed CLAIM of a takeover certified here (`proof` relays it): the
        latest its claimant signed, as for evidence. An earlier one relayed back must
        not replace it: a claimant that heartbeated as a standby since (a rejoin after
        a restart, which signs its claim again) made that one `outdated` at every robot
        that heard it so. Bounded like the certificates: the oldest epoch goes first."""
        if not raw:
            return
        kept = self._claims.setdefault(f, {})
        old = kept.get((claimant, epoch))
        if old is not None and header_seq(old) >= header_seq(raw):
            return
        if old is None and len(kept) >= CLAIMS_REMEMBERED:
            del kept[min(kept, key=lambda k: k[1])]
        kept[(claimant, epoch)] = raw

    def cert_frames(self, f: str, suspect: int, epoch: int,
                    claimant: int | None = None) -> tuple[bytes, ...]:
        """The certificate this robot (or `claimant`, whose takeover it certified) can
        show for taking f over from `suspect`: every backer, not just a quorum."""
        got = self._evidence.get(f, {}).get((suspect, epoch), {})
        who = self._robot_id if claimant is None else claimant
        return tuple(got[w] for w in self._backers(f, suspect, epoch, who))

    def proof(self, f: str, holder: int, epoch: int, *, whole: bool = True,
              ) -> tuple[bytes, ...]:
        """The signed frames that prove the entry (`holder`, `epoch`) of f here, for a
        robot whose view of f differs (DESIGN, "Convergence"): the certificate of the
        takeover that made it — the evidence against the robot replaced, then `holder`'s
        signed CLAIM — or, for a reassertion, the takeover it outranks and the REFUTE
        that voids it; then the REFUTEs `holder` signed at `epoch`, which void every
        claim against the entry that still goes round. A stale holder fences itself or
        refutes, any other robot certifies the entry and moves its view, and one that
        acts on a voided claim drops it. Empty when nothing here proves the entry (the
        plan's own holder at epoch 0 needs no proof) and nothing refutes a claim
        against it. Not `whole`: the REFUTEs alone, for a robot that acts on a claim
        against the entry (its certificate would not change its mind)."""
        refutes = self._refutes.get(f, {}).get((holder, epoch))
        signed = tuple(raw for _, raw in refutes.values()) if refutes else ()
        if not whole:
            return signed
        voided = self.reasserted(f, holder, epoch)
        if voided is not None:
            refute = self._voiding(f, voided, epoch - 1)
            frames = self._takeover_frames(f, voided, epoch - 1) \
                + ((refute,) if refute is not None else ())
        else:
            frames = self._takeover_frames(f, holder, epoch)
        return frames + signed

    def due(self, f: str, now: float, every: float | None = None, *,
            whole: bool = True, stamp: bool = True) -> bool:
        """May this robot show another its view of f now (`proof`; unsigned and
        shared-key modes relay a warning instead, `Hearing._older_beat`)? One relay of
        f at most per `every` (default T_max), whoever asked: True, and the time
        stamped, if one is due now (not `stamp`: only asked, so that a proof is built
        only when it may go, and the clock starts only when it went). The REFUTEs alone
        (not `whole`) are timed on a clock of their own: sent to a robot that acts on a
        voided claim, they must not hold the whole proof back from a robot that lost
        the last one."""
        return self._due(self._relayed_at if whole else self._refutes_relayed_at, f, now,
                         every, stamp)

    def answer_due(self, f: str, now: float, every: float) -> bool:
        """May the holder of f answer a view digest that shows f otherwise
        (`Hearing._digest_heard`) now? At most once per `every` per slot, on a clock of
        its own so that the relays it makes stay due."""
        return self._due(self._digest_answered_at, f, now, every)

    def _due(self, stamps: dict[str, float], f: str, now: float,
             every: float | None = None, stamp: bool = True) -> bool:
        """One relay of f at most per `every` (default T_max), timed by `stamps`: True,
        and (with `stamp`) the time stamped, if one is due now."""
        gap = self._params.t_max if every is None else every
        if now - stamps.get(f, -1e18) < gap:
            return False
        if stamp:
            stamps[f] = now
        return True

    def _takeover_frames(self, f: str, holder: int, epoch: int) -> tuple[bytes, ...]:
        """The evidence against the robot `holder` replaced at `epoch`, then `holder`'s
        signed CLAIM (empty when no such takeover is certified here). For this robot's
        own hold, the certificate it keeps (`took_over`), refreshed to its backers'
        latest frames while they are here: a flood of invented episodes may push the
        evidence out of the store, never the hold's own proof."""
        mine = self._mine.get(f)
        if holder == self._robot_id and mine is not None and mine[0] == epoch:
            frames = self.cert_frames(f, mine[1], epoch - 1) or mine[2]
            self._mine[f] = (epoch, mine[1], frames)
        else:
            failed = self.replaced(f, holder, epoch)
            if failed is None or epoch == 0:
                return ()
            frames = self.cert_frames(f, failed, epoch - 1, holder)
        claim = self._claims.get(f, {}).get((holder, epoch))
        return (*frames, claim) if claim is not None and frames else frames

    def took_over(self, f: str, failed: int, old_epoch: int, epoch: int) -> None:
        """This robot holds f at `epoch` now: keep the certificate of its hold."""
        self._mine[f] = (epoch, failed, self.cert_frames(f, failed, old_epoch))
        self._certified.setdefault(f, {})[(self._robot_id, epoch)] = (
            failed, self._backers(f, failed, old_epoch, self._robot_id))

    def certificate(self, f: str | None) -> tuple[bytes, ...]:
        """The frames certifying this robot's hold of f (empty if none)."""
        return self._mine[f][2] if f is not None and f in self._mine else ()

    def restore(self, f: str, epoch: int, frames: tuple[bytes, ...],
                keys: Sequence[bytes], verifier: Verifier | None) -> bool:
        """The certificate of a hold of f at `epoch` kept across a reboot, verified as if
        it had just been received: frames that verify, about one and the same robot at
        `epoch - 1`, enough of them (a quorum of witnesses or that robot's LEAVE). True
        if it certifies the hold; then it is this robot's certificate again."""
        failed: int | None = None
        for kept in frames:
            raw = bytes(kept)
            if verifier is None:
                # With a shared key or unsigned, a tag proves no more than our own
                # memory: the frames are ours to vouch for again under the key in force
                # (`wire.retag`), as when we relay them.
                raw = wire.retag(raw, keys[0] if keys else None)
            try:
                # Judged as the frames of a relayed certificate are (`inner`): per robot,
                # keys no longer in force for new frames still verify these (DESIGN, "Key
                # changes never rewrite history").
                got = wire.decode(raw, keys, verifier, inner=True)
            except wire.CodecError:
                continue
            said = says(got)
            if said is None or said[2] != epoch - 1 or got.msg.function != self._plan.slot(f):
                continue
            if failed is None:
                failed = said[1]
            if said[1] == failed:
                self.record(f, said[0], said[1], said[2], raw, 0)
        if failed is None or f not in self._plan.functions or epoch < 1:
            return False
        self.took_over(f, failed, epoch - 1, epoch)
        return self._enough(failed, self._certified[f][(self._robot_id, epoch)][1])

    # ------------------------------------------------------------------ refutes
    def refuted_up_to(self, f: str, holder: int, epoch: int, witness: int) -> int:
        """The highest seq of `witness`'s warnings about `holder` at `epoch` that the
        holder refuted (-1: none)."""
        entry = self._refutes.get(f, {}).get((holder, epoch), {}).get(witness)
        return entry[0] if entry is not None else -1

    def add_refute(self, f: str, holder: int, r: wire.Refute, raw: bytes) -> bool:
        """Keep `holder`'s signed REFUTE `r` (raw bytes). True if it refutes more than
        what was known: the node then re-judges the claims it believes."""
        if r.witness not in self.may_watch(f, claimants=True):
            return False  # refutes nothing a certificate could count
        episodes = self._refutes.setdefault(f, {})
        got = episodes.get((holder, r.epoch))
        if got is None:
            if len(episodes) >= EVIDENCE_REMEMBERED:
                del episodes[next(iter(episodes))]
            got = episodes[(holder, r.epoch)] = {}
        old = got.get(r.witness)
        if old is not None and old[0] >= r.seq:
            return False
        got[r.witness] = (r.seq, raw)
        return True


def says(frame: wire.Frame) -> tuple[int, int, int] | None:
    """(witness, suspect, epoch) that a signed frame (a CERT's relayed `inner`, or one
    restored from a state file) says, if it is evidence: a WARN about its suspect, or a
    LEAVE, its sender's own."""
    msg = frame.msg
    if isinstance(msg, wire.Warn):
        return frame.sender, msg.suspect, msg.epoch
    if isinstance(msg, wire.Leave):
        return frame.sender, frame.sender, msg.epoch
    return None


__all__ = ["CLAIMS_REMEMBERED", "EVIDENCE_REMEMBERED", "EvidenceStore", "says"]
