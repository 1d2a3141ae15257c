"""A restarted holder listening before it resumes its slot (DESIGN rule 2 across a
reboot): `rejoin_hold` long, it stays a standby if it hears its slot held by another
robot or at a newer epoch. Pure decisions; the node acts on them."""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.core.records import Holder


@dataclass(frozen=True, slots=True)
class Rejoin:
    """Robot `me` listens until `until` before it resumes `function` at `epoch`."""

    me: int
    function: str
    epoch: int
    until: float

    def resumes(self, known: Holder) -> bool:
        """At the end of the hold, with the slot known as `known`: resume it? Not if it
        was heard at a newer epoch, or at ours by a lower id (rule 2's order)."""
        if known.epoch > self.epoch:
            return False
        return not (known.epoch == self.epoch and known.robot != self.me
                    and known.robot < self.me)

    def superseded(self, known: Holder, seen_epoch: int) -> bool:
        """Someone holds, warns about or claims the slot at `seen_epoch` (WARN and CLAIM
        do not move `known`: a liar must not, so their epoch comes in): newer than ours,
        or the slot held by another robot — stay a standby."""
        return seen_epoch > self.epoch or known.epoch > self.epoch or known.robot != self.me


__all__ = ["Rejoin"]
