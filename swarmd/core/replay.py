"""Replay protection: a sender's sequence number must rise (MAVLink 2 signing's rule).

Senders seed their counter from the wall clock (`wire.seq_seed`) and persist a
high-water mark, so a restarted sender continues above what it sent before and is
accepted without any special case; a frame recorded and played back later is not.
"""

from __future__ import annotations


class ReplayFilter:
    __slots__ = ("last",)

    def __init__(self) -> None:
        self.last: dict[int, int] = {}

    def accept(self, sender: int, seq: int) -> bool:
        prev = self.last.get(sender)
        if prev is not None and seq <= prev:
            return False
        self.last[sender] = seq
        return True
