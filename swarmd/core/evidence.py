"""Takeover certificates of one robot, per-robot mode (DESIGN section 2, "Who may say what").

In per-robot mode every WARN, CLAIM and LEAVE is signed by its own sender, so a robot
can prove what others said. A *certificate* is the set of signed frames that back a
takeover of slot f from `suspect` at `epoch`: the suspect's own signed LEAVE, or the
signed WARNs of at least a quorum of distinct witnesses (rule 3: the robots that may
hold a slot watching f, plus the claimant's own ears once, rule 9; never the suspect).
An epoch rises only for a CLAIM whose certificate this robot verified, so one liar
alone — whatever it signs — never moves a slot; and the new holder relays its
certificate to whoever missed it.

State, per slot f (all bounded: a flood of invented epochs or claimants pushes out
the oldest, it cannot grow the store):
- `evidence`: {(suspect, epoch): {witness: signed WARN or LEAVE bytes}}.
- `certified`: {(claimant, epoch)} whose CLAIM a certificate backs here.
- `pending`: {(claimant, epoch): (failed, first heard)}, claims heard before their
  certificate (a channel that reorders), counted once it comes, if still fresh.
- `mine`: (failed, frames), the certificate of this robot's own hold of f.
- `relayed_at`: when `mine` was last relayed (at most once per T_max).
- `alive`: ((holder, epoch), {witness: its highest seq}) when f's holder was last
  heard alive: warnings about it sent before then are void (rule 4).

Sans-IO and pure: every method takes what it needs (`now`, the epoch floor of f) and
returns a decision or frames; the `Node` sends, emits and counts drops.
"""

from __future__ import annotations

from collections.abc import Callable

from swarmd.core import wire
from swarmd.core.auth import Verifier
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

EVIDENCE_REMEMBERED = 16
"""(suspect, epoch) episodes of signed evidence kept per slot (per-robot mode); a flood
of warnings about invented epochs pushes out the oldest, it cannot grow the node."""


CLAIMS_REMEMBERED = 16
"""Claims remembered per slot (rule 10); a flood of invented (claimant, epoch) pairs
pushes out the oldest, it cannot grow the node."""


class EvidenceStore:
    """The evidence, certificates and pending claims of one robot (see module doc)."""

    def __init__(self, robot_id: int, plan: SwarmPlan, params: Params) -> None:
        self._robot_id = robot_id
        self._plan = plan
        self._params = params
        self._evidence: dict[str, dict[tuple[int, int], dict[int, bytes]]] = {}
        self._certified: dict[str, set[tuple[int, int]]] = {}
        self._pending: dict[str, dict[tuple[int, int], tuple[int, float]]] = {}
        self._mine: dict[str, tuple[int, tuple[bytes, ...]]] = {}
        self._relayed_at: dict[str, float] = {}
        self._may_watch_cache: dict[tuple[str, bool], frozenset[int]] = {}
        self._alive: dict[str, tuple[tuple[int, int], dict[int, int]]] = {}

    def record(self, f: str, witness: int, suspect: int, epoch: int, raw: bytes,
               floor: int, now: float | None = None) -> list[tuple[int, wire.Claim]] | None:
        """Keep `witness`'s signed frame `raw` against `suspect` at `epoch` (`floor`:
        the epoch of f as known). None when it is void (sent before the suspect was
        last heard alive); otherwise the pending claims it now certifies, still fresh
        at `now`, for the node to count."""
        if not raw or epoch < floor:
            return []
        alive = self._alive.get(f)
        if alive is not None and alive[0] == (suspect, epoch) \
                and int.from_bytes(raw[5:11], "big") <= alive[1].get(witness, -1):
            # Sent before the suspect was last heard alive: a suspicion it refuted
            # (rule 4), perhaps captured and played back; it backs no takeover.
            return None
        episodes = self._evidence.setdefault(f, {})
        got = episodes.get((suspect, epoch))
        if got is None:
            if len(episodes) >= EVIDENCE_REMEMBERED:
                del episodes[next(iter(episodes))]
            got = episodes[(suspect, epoch)] = {}
        got[witness] = raw  # the latest: the least likely void where it is relayed
        ready: list[tuple[int, wire.Claim]] = []
        pending = self._pending.get(f)
        if pending:
            for (claimant, new_epoch), (failed, heard) in list(pending.items()):
                claim = wire.Claim(failed, self._plan.slot(f), new_epoch)
                if (failed, new_epoch - 1) == (suspect, epoch) \
                        and self.certify(f, claimant, claim, floor):
                    # Its certificate came after it (a channel that reorders): the
                    # claim counts now, if it is still a fresh one.
                    del pending[(claimant, new_epoch)]
                    if now is not None and now - heard <= self._params.claim_hold:
                        ready.append((claimant, claim))
        return ready

    def _backers(self, f: str, suspect: int, epoch: int, claimant: int) -> list[int]:
        """The witnesses whose signed evidence backs `claimant` taking f over from
        `suspect` at `epoch`: the suspect's own LEAVE alone, or the warnings of distinct
        witnesses (the holders of the slots that watch f, rule 3, and the claimant
        itself as rule 9's own ears, once), never the suspect's."""
        got = self._evidence.get(f, {}).get((suspect, epoch))
        if not got:
            return []
        if suspect in got:
            return [suspect]
        return [w for w in got if w != suspect and (w == claimant or w in self.may_watch(f))]

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

    def certify(self, f: str, claimant: int, c: wire.Claim, floor: int) -> bool:
        """Does the evidence held back `claimant`'s CLAIM `c` of f? (`floor`: the epoch
        of f as known; certified takeovers older than it are forgotten first.)"""
        certified = self._certified.setdefault(f, set())
        if (claimant, c.epoch) in certified:
            return True
        if claimant not in self._plan.covered_by(f):
            return False
        backers = self._backers(f, c.failed, c.epoch - 1, claimant)
        if not backers or (backers != [c.failed] and len(backers) < self._params.quorum):
            return False
        if len(certified) >= CLAIMS_REMEMBERED:  # older takeovers matter no more
            certified.intersection_update({x for x in certified if x[1] >= floor})
        certified.add((claimant, c.epoch))
        return True

    def is_certified(self, f: str, claimant: int, epoch: int) -> bool:
        return (claimant, epoch) in self._certified.get(f, ())

    def hold_pending(self, f: str, claimant: int, c: wire.Claim, now: float) -> None:
        """Keep an uncertified claim a while, in case its certificate comes later."""
        pending = self._pending.setdefault(f, {})
        if len(pending) >= CLAIMS_REMEMBERED:
            del pending[next(iter(pending))]
        pending[(claimant, c.epoch)] = (c.failed, now)

    def cert_frames(self, f: str, suspect: int, epoch: int) -> tuple[bytes, ...]:
        """The certificate this robot can show for taking f over from `suspect`."""
        got = self._evidence.get(f, {}).get((suspect, epoch), {})
        backers = self._backers(f, suspect, epoch, self._robot_id)
        # Every backer, not just a quorum: a receiver may hold some of them void (a
        # warning its suspect refuted in its hearing, `record`).
        return tuple(got[w] for w in backers)

    def took_over(self, f: str, failed: int, old_epoch: int, epoch: int) -> None:
        """This robot holds f at `epoch` now: keep the certificate of its hold."""
        self._mine[f] = (failed, self.cert_frames(f, failed, old_epoch))
        self._certified.setdefault(f, set()).add((self._robot_id, epoch))

    def certificate(self, f: str | None) -> tuple[bytes, ...]:
        """The frames certifying this robot's hold of f (empty if none)."""
        return self._mine[f][1] if f is not None and f in self._mine else ()

    def relay(self, f: str, now: float) -> tuple[int, tuple[bytes, ...]] | None:
        """(failed, frames) of our hold of f to relay now, at most once per T_max."""
        mine = self._mine.get(f)
        if mine is None or now - self._relayed_at.get(f, -1e18) < self._params.t_max:
            return None
        self._relayed_at[f] = now
        return mine

    def restore(self, f: str, frames: tuple[bytes, ...], verifier: Verifier) -> None:
        """The certificate of a hold kept across a reboot: its frames that verify and
        name one and the same failed robot."""
        failed = None
        good: list[bytes] = []
        for raw in frames:
            try:
                got = wire.decode(bytes(raw), (), verifier)
            except wire.CodecError:
                continue
            if isinstance(got.msg, wire.Warn):
                who = got.msg.suspect
            elif isinstance(got.msg, wire.Leave):
                who = got.sender
            else:
                continue
            if failed is None or who == failed:
                failed = who
                good.append(bytes(raw))
        if failed is not None and f in self._plan.functions:
            self._mine[f] = (failed, tuple(good))

    def mark_alive(self, f: str, holder: int, epoch: int,
                   top: Callable[[int], int | None], own_seq: int) -> None:
        """f's holder is alive at `epoch` now (its heartbeat, or our own): the evidence
        against it so far is void, and so is any warning its witnesses sent before
        (`top`: a peer's highest seq accepted so far; `own_seq`: this robot's)."""
        episodes = self._evidence.get(f)
        if episodes:
            episodes.pop((holder, epoch), None)
        tops: dict[int, int] = {}
        for w in self.may_watch(f, claimants=True):
            seq = top(w) if w != self._robot_id else own_seq
            if seq is not None:
                tops[w] = seq
        self._alive[f] = ((holder, epoch), tops)

    def refuted(self, f: str, epoch: int, witness: int, seq: int) -> None:
        """This robot, holding f at `epoch`, heard `witness`'s warning (its `seq`) about
        itself live and refutes it: that warning backs no takeover of f here."""
        me = (self._robot_id, epoch)
        mark = self._alive.get(f)
        if mark is None or mark[0] != me:
            mark = (me, {})
            self._alive[f] = mark
        mark[1][witness] = max(mark[1].get(witness, -1), seq)
        self._evidence.get(f, {}).pop(me, None)


def cert_says(cert: wire.Cert) -> tuple[int, int, int] | None:
    """(witness, suspect, epoch) that a CERT's relayed frame says, if it is evidence: a
    WARN about its suspect, or a LEAVE, its sender's own."""
    inner = cert.inner
    msg = inner.msg
    if isinstance(msg, wire.Warn):
        return inner.sender, msg.suspect, msg.epoch
    if isinstance(msg, wire.Leave):
        return inner.sender, inner.sender, msg.epoch
    return None


__all__ = ["CLAIMS_REMEMBERED", "EVIDENCE_REMEMBERED", "EvidenceStore", "cert_says"]
