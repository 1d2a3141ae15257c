"""Replay protection: a sliding anti-replay window per sender (IPsec / DTLS style).

Senders seed their counter from the wall clock (`wire.seq_seed`) and persist a
high-water mark, so a restarted sender continues above what it sent before and needs no
special case. A receiver accepts a frame whose seq is above the highest seen from that
sender, or within `WINDOW` below it and not seen yet: a channel that reorders (radio
retries, jitter) loses nothing, while a frame played back a second time, or one older
than the window, is dropped. MAVLink 2's strictly rising rule would drop the first of
two frames sent in the same instant (a WARN and a HEARTBEAT) if they swap in flight.
"""

from __future__ import annotations

WINDOW = 64


class ReplayFilter:
    __slots__ = ("state",)

    def __init__(self) -> None:
        # sender -> (highest seq accepted, bitmap of the WINDOW seqs below and at it;
        # bit i set = highest - i seen)
        self.state: dict[int, tuple[int, int]] = {}

    def accept(self, sender: int, seq: int) -> bool:
        prev = self.state.get(sender)
        if prev is None:
            self.state[sender] = (seq, 1)
            return True
        top, seen = prev
        if seq > top:
            shift = seq - top
            seen = ((seen << shift) | 1) & ((1 << WINDOW) - 1) if shift < WINDOW else 1
            self.state[sender] = (seq, seen)
            return True
        age = top - seq
        if age >= WINDOW or seen >> age & 1:
            return False
        self.state[sender] = (top, seen | (1 << age))
        return True
