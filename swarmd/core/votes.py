"""Warning counter of a standby for one slot (paper Fig. 9, DESIGN rule 3).

Counts *distinct* witnesses that warned about the same holder at the same epoch within
`window` seconds. A later warning from the same witness refreshes its time but never
counts twice. Warnings about another holder or epoch start a new count: the standby
follows the slot, not a robot id (rule 1).
"""

from __future__ import annotations


class VoteCounter:
    __slots__ = ("epoch", "subject", "window", "witnesses")

    def __init__(self, window: float) -> None:
        self.window = window
        self.subject: int | None = None
        self.epoch = -1
        self.witnesses: dict[int, float] = {}

    def add(self, witness: int, subject: int, epoch: int, now: float) -> int:
        """Record a warning; return the number of distinct witnesses in the window."""
        if (subject, epoch) != (self.subject, self.epoch):
            self.subject, self.epoch = subject, epoch
            self.witnesses = {}
        self.witnesses[witness] = now
        return self.count(now)

    def count(self, now: float) -> int:
        horizon = now - self.window
        self.witnesses = {w: t for w, t in self.witnesses.items() if t >= horizon}
        return len(self.witnesses)

    def clear(self) -> None:
        self.subject, self.epoch, self.witnesses = None, -1, {}
