"""Replay protection: a sliding anti-replay window per sender (IPsec / DTLS style).

Senders seed their counter from the wall clock (`wire.seq_seed`) and persist a
high-water mark, so a restarted sender continues above what it sent before and needs no
special case. A receiver accepts a frame whose seq is above the highest seen from that
sender, or within `WINDOW` below it and not seen yet: a channel that reorders (radio
retries, jitter) loses nothing, while a frame played back a second time, or one older
than the window, is dropped. MAVLink 2's strictly rising rule would drop the first of
two frames sent in the same instant (a WARN and a HEARTBEAT) if they swap in flight.

Jumps are bounded (DESIGN section 2, "Sequence numbers"): a sequence number is a clock
(10 us units at the sender's start, one more per frame), so between two frames a sender
can legitimately move it up by the time that passed (`RATE` a second, a restart
included) plus `JUMP`, the most a restart within the same instant may skip (a daemon
resumes at its persisted reservation, at most `swarmd.state.SEQ_RESERVE` = 10^6 ahead
of what it sent, once per restart); a frame further ahead is dropped as
`seq_jump` and moves nothing. One forged frame at seq 2^48-1 therefore cannot mute a
robot; a forger can only push a sender's window by `JUMP` beyond the time that passed
(2^25 forged frames to exhaust 48 bits), and the robot it names, which hears that frame
too, moves its own counter above it (`Node`, "own").
"""

from __future__ import annotations

WINDOW = 64
JUMP = 1 << 23
"""How far beyond the elapsed time one frame may move a sender's counter: eight times
the daemon's sequence reservation (`swarmd.state.SEQ_RESERVE`, 10^6), because each
restart that sends nothing before the next (a crash loop under systemd) moves the
reservation once more. A forger still needs 2^25 frames to walk a counter to 2^48."""
RATE = 100_000
"""sequence units a second: the wall-clock seeding of `wire.seq_seed` (10 us)."""
_FULL = (1 << WINDOW) - 1
_UNBOUNDED = float("-inf")


class ReplayFilter:
    __slots__ = ("state",)

    def __init__(self) -> None:
        # sender -> (highest seq accepted, bitmap of the WINDOW seqs below and at it;
        # bit i set = highest - i seen, time it was accepted)
        self.state: dict[int, tuple[int, int, float]] = {}

    def restore(self, sender: int, top: int) -> None:
        """A peer's highest seq as persisted before a restart: it and the whole window
        below it count as seen, so an old frame stays old. How long ago that was is
        unknown here (no wall clock in the core), so the next jump above it is not
        bounded: the peer may have restarted meanwhile."""
        self.state[sender] = (top, _FULL, _UNBOUNDED)

    def accept(self, sender: int, seq: int, now: float | None = None) -> bool:
        return self.check(sender, seq, now) is None

    def check(self, sender: int, seq: int, now: float | None = None) -> str | None:
        """None if the frame is new, else the drop reason (`replay` or `seq_jump`).
        Without `now`, jumps are not bounded."""
        prev = self.state.get(sender)
        t = 0.0 if now is None else now
        if prev is None:
            self.state[sender] = (seq, 1, t)
            return None
        top, seen, at = prev
        if seq > top:
            shift = seq - top
            if now is not None and at != _UNBOUNDED \
                    and shift > JUMP + int(RATE * max(0.0, now - at)):
                return "seq_jump"
            seen = ((seen << shift) | 1) & _FULL if shift < WINDOW else 1
            self.state[sender] = (seq, seen, t)
            return None
        age = top - seq
        if age >= WINDOW or seen >> age & 1:
            return "replay"
        self.state[sender] = (top, seen | (1 << age), at)
        return None

    def top(self, sender: int) -> int | None:
        prev = self.state.get(sender)
        return None if prev is None else prev[0]
