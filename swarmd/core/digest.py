"""A standby's view of the slots it covers, in the heartbeat it sends anyway (DESIGN
section 2, "Convergence", "How entries spread").

A heartbeat without a slot (function 0: a standby, a claimant, a rejoining or fenced
robot) has no epoch to carry, so its 16-bit epoch field carries a digest of the
sender's view instead: for each of the first `DIGEST_SLOTS` slots it covers, in plan
order, two bits, the epoch of its entry for that slot modulo 4. No byte is added.

A holder of slot g at epoch E that hears such a heartbeat showing anything but E mod 4
for g knows the sender's view of g is not its own, and answers at once (its entry, per
robot its certificate), so a stale standby learns within one standby period instead of
waiting for the unasked relay. The digest is never proof and moves no entry: it only
makes the side with the greater entry send it. What two bits cannot see (a lag of a
multiple of 4 epochs, a rival at the same epoch, a slot past the eighth) the existing
mechanisms still cover. Any 16-bit value is harmless: the worst a forged digest does is
make a holder answer, at the rate `Hearing._digest_heard` bounds.

A robot of the format before the digest sends 0: it shows "epoch 0 mod 4" for every
slot, so a holder at an epoch not a multiple of 4 answers it at that bounded rate.

Pure: no state, no I/O.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from swarmd.core.records import Holder

DIGEST_SLOTS = 8
"""Covered slots a digest shows: 2 bits each fill the 16-bit epoch field."""
_BITS = 2
_MASK = (1 << _BITS) - 1


def make(covered: Sequence[str], known: Mapping[str, Holder]) -> int:
    """The digest of our view (`known`) of the slots we cover, in plan order
    (`SwarmPlan.covered`): slot i's entry's epoch mod 4 in bits 2i and 2i + 1."""
    digest = 0
    for i, f in enumerate(covered[:DIGEST_SLOTS]):
        entry = known.get(f)
        if entry is not None:
            digest |= (entry.epoch & _MASK) << (_BITS * i)
    return digest


def shown(digest: int, covered: Sequence[str], f: str) -> int | None:
    """The two bits a sender covering `covered` (plan order) shows for slot `f` in
    `digest`, or None if the digest does not show f (not covered, or past the first
    `DIGEST_SLOTS`)."""
    try:
        i = covered.index(f, 0, DIGEST_SLOTS)
    except ValueError:
        return None
    return (digest >> (_BITS * i)) & _MASK


def differs(digest: int, covered: Sequence[str], f: str, epoch: int) -> bool:
    """Does `digest` show a view of f other than an entry at `epoch` (mod 4)?"""
    bits = shown(digest, covered, f)
    return bits is not None and bits != epoch & _MASK


__all__ = ["DIGEST_SLOTS", "differs", "make", "shown"]
