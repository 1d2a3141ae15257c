"""Replay protection: a sliding anti-replay window per sender (IPsec / DTLS style).

Senders seed their counter from the wall clock (`wire.seq_seed`) and persist a
high-water mark, so a restarted sender continues above what it sent before and needs no
special case. A receiver accepts a frame whose seq is above the highest seen from that
sender, or within `WINDOW` below it and not seen yet: a channel that reorders (radio
retries, jitter) loses nothing, while a frame played back a second time, or one older
than the window, is dropped. MAVLink 2's strictly rising rule would drop the first of
two frames sent in the same instant (a WARN and a HEARTBEAT) if they swap in flight.

Sequence numbers are bounded by the receiver's own clock (DESIGN section 2, "Sequence
numbers"): a sequence number is a clock (10 us units of wall time at the sender's start,
one more per frame), so no honest sender's counter is ahead of its wall clock by more
than its reservations (`JUMP`). A receiver knows its own clock without reading one: its
own `seq_start` (wall-clock seeded by the daemon) plus `RATE` times the monotonic time
elapsed since, both handed to the core. A frame whose seq is above that plus `AHEAD`
(the clock skew the swarm tolerates, `SKEW`, plus `JUMP`) is dropped as `seq_jump` and
moves nothing, whoever sent it and whether or not it is the first frame heard from that
sender; a restored `peer_seq` above the same bound is refused. So one forged frame at
seq 2^48-1 mutes nobody, a forger can push a sender's window at most `AHEAD` beyond the
receiver's clock however many frames it sends, and the 48-bit space cannot be walked
faster than real time (it lasts until 2104). The robot a forged frame names hears it too
(a broadcast) and moves its own counter above it (`Node`, "own") up to `follow_limit`.
"""

from __future__ import annotations

from swarmd.core.drops import DropReason

WINDOW = 64
JUMP = 1 << 23
"""How far ahead of its wall clock an honest sender's counter may be: eight times the
daemon's sequence reservation (`swarmd.state.SEQ_RESERVE`, 10^6), because each restart
that sends nothing before the next (a crash loop under systemd) resumes at the last
reservation, up to 10^6 above the last seq."""
RATE = 100_000
"""sequence units a second: the wall-clock seeding of `wire.seq_seed` (10 us)."""
SKEW = 3600 * RATE
"""How far a sender's wall clock may be ahead of the receiver's: one hour. Robots keep
time by NTP, GPS or an RTC (milliseconds to seconds apart); an hour also absorbs a crash
loop of about 450 restarts at systemd's `RestartSec=2`, each of which resumes at the
last reservation. Outside it (docs/operations.md, "Clocks"): a robot whose clock is
more than `SKEW` ahead is unheard, so it is suspected and replaced like a silent one
(and fenced when it hears the new holder); a robot whose clock is that far behind hears
nobody (every peer's frames count as `seq_jump`)."""
AHEAD = SKEW + JUMP
"""The most a sender's seq may be above the receiver's own clock."""
_FULL = (1 << WINDOW) - 1


class ReplayFilter:
    __slots__ = ("origin", "since", "state")

    def __init__(self, origin: int | None = None, since: float = 0.0) -> None:
        """`origin`: the receiver's own first seq (its wall clock at `since`, in seq
        units); None bounds nothing (the window alone)."""
        # sender -> (highest seq accepted, bitmap of the WINDOW seqs below and at it;
        # bit i set = highest - i seen)
        self.state: dict[int, tuple[int, int]] = {}
        self.origin = origin
        self.since = since

    def clock(self, now: float) -> int | None:
        """The receiver's own clock at `now`, in seq units (monotonic time since start:
        a wall clock stepped meanwhile moves nothing)."""
        if self.origin is None:
            return None
        return self.origin + int(RATE * max(0.0, now - self.since))

    def limit(self, now: float | None) -> int | None:
        """The highest seq any sender may have at `now` (None: unbounded)."""
        c = None if now is None else self.clock(now)
        return None if c is None else c + AHEAD

    def follow_limit(self, now: float) -> int | None:
        """How far this robot moves its own counter after a frame sent in its name: as far
        as a receiver whose clock is `SKEW` ahead of ours would accept."""
        c = self.limit(now)
        return None if c is None else c + SKEW

    def restore(self, sender: int, top: int) -> bool:
        """A peer's highest seq as persisted before a restart: it and the whole window
        below it count as seen, so an old frame stays old. One above the bound at our
        start is refused (False): an absurd value, kept, would mute the peer for good."""
        bound = self.limit(self.since)
        if bound is not None and top > bound:
            return False
        self.state[sender] = (top, _FULL)
        return True

    def accept(self, sender: int, seq: int, now: float | None = None) -> bool:
        return self.check(sender, seq, now) is None

    def check(self, sender: int, seq: int, now: float | None = None) -> DropReason | None:
        """None if the frame is new, else the drop reason (`replay` or `seq_jump`).
        Without `now` (or an origin), seqs are not bounded."""
        bound = self.limit(now)
        if bound is not None and seq > bound:
            return DropReason.SEQ_JUMP
        prev = self.state.get(sender)
        if prev is None:
            self.state[sender] = (seq, 1)
            return None
        top, seen = prev
        if seq > top:
            shift = seq - top
            seen = ((seen << shift) | 1) & _FULL if shift < WINDOW else 1
            self.state[sender] = (seq, seen)
            return None
        age = top - seq
        if age >= WINDOW or seen >> age & 1:
            return DropReason.REPLAY
        self.state[sender] = (top, seen | (1 << age))
        return None

    def top(self, sender: int) -> int | None:
        prev = self.state.get(sender)
        return None if prev is None else prev[0]
