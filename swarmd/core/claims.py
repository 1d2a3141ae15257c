"""The wait state and what a robot remembers of claims (paper Fig. 5's *wait*; DESIGN
rule 10). Pure: the node asks, these answer."""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.core.params import Params

CLAIMS_REMEMBERED = 16
"""Claims remembered per slot (rule 10); a flood of invented (claimant, epoch) pairs
pushes out the oldest, it cannot grow the node."""


@dataclass(slots=True)
class WaitState:
    """This robot claims `function` from `failed` (held at `old_epoch`) at `epoch`: it
    takes it over at `until` unless it backs off, and sends its claim again at `resend`."""

    function: str
    failed: int
    old_epoch: int
    epoch: int
    until: float
    resend: float
    lost: frozenset[tuple[str, int]] = frozenset()
    """Rule 9: the watchers (slot, holder) silent to us when our own ears made the
    quorum: the claim rests on their having failed with the suspect."""


class ClaimMemory:
    """DESIGN rule 10: a CLAIM is believed for `claim_hold + t_max` from the first time
    its (claimant, epoch) was heard for a slot; by then the claimant heartbeats at its
    new epoch or it is dead or stuck. A slot's memory is forgotten when its next holder
    heartbeats."""

    __slots__ = ("_horizon", "_seen")

    def __init__(self, params: Params) -> None:
        self._horizon = params.claim_horizon
        self._seen: dict[str, dict[tuple[int, int], float]] = {}

    def believed(self, f: str, claimant: int, epoch: int, now: float) -> bool:
        """Is this claim of f still believed at `now`? Its repeats neither extend the
        watchers' silence nor clear a standby's votes again."""
        seen = self._seen.setdefault(f, {})
        first = seen.get((claimant, epoch))
        if first is None:
            if len(seen) >= CLAIMS_REMEMBERED:
                del seen[min(seen, key=seen.__getitem__)]
            seen[(claimant, epoch)] = now
            return True
        return now - first <= self._horizon

    def forget(self, f: str) -> None:
        self._seen.pop(f, None)


__all__ = ["CLAIMS_REMEMBERED", "ClaimMemory", "WaitState"]
