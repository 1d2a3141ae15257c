"""Replay protection: what each sender has been heard to send, per sender.

Senders seed their counter from the wall clock (`wire.seq_seed`) and persist a
high-water mark, so a restarted sender continues above what it sent before and needs no
special case. A receiver remembers, per sender, the last `WINDOW` sequence numbers it
accepted (exactly, as a set) and a floor: every seq at or below the floor counts as
seen (it rises to each seq the set forgets, the lowest first). A frame is new if it is
above the floor and not in the set: a channel that reorders (radio retries, jitter)
loses nothing, while a frame played back a second time, or one older than the last
`WINDOW` accepted, is dropped. MAVLink 2's strictly rising rule would drop the first of
two frames sent in the same instant (a WARN and a HEARTBEAT) if they swap in flight.

Why a set and not a sliding bitmap below the highest seq (DESIGN section 2, "Sequence
numbers"): with a bitmap one frame far ahead of a sender moves the whole window up, and
the sender's own next frames, all below it, are dropped as replays for as long as its
counter lags (a forger with the swarm key, or anyone on an unsigned swarm, mutes a robot
with one frame). Here a frame far ahead is one more remembered seq: the sender's next
frames are still above the floor and not in the set, so they are heard at once. The
floor only passes seqs that were accepted; when a flood of more than `WINDOW` frames in
a sender's name far ahead pushes it over a stretch never accepted, that stretch is kept
as a hole with a set of its own (`_Sender`), where the sender's own next frames are
still heard and replays still caught. In per-robot mode every frame that reaches the
filter is its sender's (signature or chain link), so nobody else can do even that.

Sequence numbers are bounded by the receiver's own clock (DESIGN section 2, "Sequence
numbers"): a sequence number is a clock (10 us units of wall time at the sender's start,
one more per frame), so no honest sender's counter is ahead of its wall clock by more
than its reservations (`JUMP`). A receiver knows its own clock without reading one: its
own `seq_start` (wall-clock seeded by the daemon) plus `RATE` times the monotonic time
elapsed since, both handed to the core. A frame whose seq is above that plus `AHEAD`
(the clock skew the swarm tolerates, `SKEW`, plus `JUMP`) is dropped as `seq_jump` and
moves nothing, whoever sent it and whether or not it is the first frame heard from that
sender; a restored `peer_seq` above the same bound is refused. So the 48-bit space
cannot be walked faster than real time (it lasts until 2104). A robot's own counter
moves only on what it sends itself: a frame in its name from elsewhere moves nothing
(`Node`, "own").
"""

from __future__ import annotations

import heapq

from swarmd.core.drops import DropReason

WINDOW = 64
"""How many of a sender's accepted seqs are remembered exactly (a reordering channel
may bring a frame this many frames late and it still counts)."""
JUMP = 1 << 23
"""How far ahead of its wall clock an honest sender's counter may be: eight times the
daemon's sequence reservation (`swarmd.services.state.SEQ_RESERVE`, 10^6), because each restart
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
MARKS = 4 * WINDOW
"""Lone frames a hole keeps marked as seen (`_Sender.add`); past that, a new hole."""
UNKNOWN = -1
"""The floor of a sender heard for the first time (no state file): none until WINDOW of
its frames have been heard, so a first frame forged far ahead of it mutes it to nobody
(with a floor just below that frame, its own frames would all be older). The price: a
receiver that has no memory of a sender at all takes any of its first WINDOW frames it
has not seen, old ones played back included, where a floor just below the first frame
would drop those older than it (a receiver that remembers, `restore`, has its floor)."""
HOLES = 4
"""Holes kept per sender (`_Sender`): a flood that pushed the floor over a sender's
own next frames leaves them a hole to be heard in; only a forger that keeps more than
this many holes busy, between two frames of the sender, makes one be forgotten."""


def header_seq(data: bytes) -> int:
    """The sequence number in a frame's header (bytes 5-10, `wire.HEADER`), unverified:
    for `ReplayFilter.stale` before the frame is decoded (`wire.peek` checked its size),
    and the seq of a signed frame kept as evidence or relayed (`evidence.py`); 0 for no
    bytes (a message made here, never heard)."""
    return int.from_bytes(data[5:11], "big")


class _Seen:
    """One stretch of a sender's seqs: the floor (every seq at or below it counts as
    seen), the last `WINDOW` seqs accepted above it (a set for the test, a heap to
    forget the lowest first), and `end` (a hole's: only seqs below it belong here)."""

    __slots__ = ("end", "floor", "heap", "high", "marks", "seqs", "stamp", "top")

    def __init__(self, floor: int, end: int | None = None, stamp: int = 0) -> None:
        self.floor, self.end, self.stamp = floor, end, stamp
        self.seqs: set[int] = set()
        self.marks: set[int] = set()
        """A hole's: seqs inside it accepted before it was a hole (`_Sender.add`)."""
        self.heap: list[int] = []
        self.top: int | None = floor
        """`established()`, cached; `add` keeps it when it can tell the new one at once."""
        self.high = floor
        """The highest seq in `seqs` (the floor while it is empty)."""

    def holds(self, seq: int) -> bool:
        return seq > self.floor and (self.end is None or seq < self.end)

    def fresh(self, seq: int) -> bool:
        return seq > self.floor and seq not in self.seqs and seq not in self.marks

    def add(self, seq: int, stamp: int) -> _Seen | None:
        """Remember `seq`; the hole the floor jumped over to forget the lowest one, if
        it jumped over more than `WINDOW` seqs never accepted (`ReplayFilter.check`)."""
        self.top = self._top_after(seq)
        self.seqs.add(seq)
        heapq.heappush(self.heap, seq)
        self.stamp = stamp
        if seq > self.high:
            self.high = seq
        if len(self.heap) <= WINDOW:
            return None
        low = heapq.heappop(self.heap)
        self.seqs.discard(low)
        hole = _Seen(self.floor, low, stamp) \
            if self.floor != UNKNOWN and low - self.floor > WINDOW else None
        self.floor = low
        return hole

    def _top_after(self, seq: int) -> int | None:
        """`established()` once `seq` is added, where it follows without a sort; None
        where it takes one. A sender's next frame (the common case: every heartbeat
        heard asks for its sender's top, `Node._heard_word`) lands within `WINDOW`
        above the top of the highest cluster, which was the largest: that cluster grows
        by one and stays the largest (`add` then forgets the lowest seq, which shrinks
        one cluster by one at most), so `seq` is the new top. The first seq of an empty
        stretch is its own cluster."""
        if not self.seqs:
            return seq
        top = self.top
        return seq if top is not None and top == self.high and 0 < seq - top <= WINDOW \
            else None

    def established(self) -> int:
        """The highest seq of the sender's own run as far as the seqs tell: the top of
        the largest cluster of remembered seqs (no two neighbours more than `WINDOW`
        apart; a tie goes to the higher), else the floor. A lone frame far ahead (a
        forgery the set keeps) is not it; a restarted sender's new run is, once it has
        sent more than what is left of the old one."""
        if self.top is not None:
            return self.top
        best, best_n, n, prev = self.floor, 0, 0, None
        for s in sorted(self.seqs):
            n = 1 if prev is None or s - prev > WINDOW else n + 1
            if n >= best_n:
                best, best_n = s, n
            prev = s
        self.top = best
        return best


class _Sender:
    """What one sender has been heard to send: the stretch above the highest floor,
    and up to `HOLES` holes below it (stretches the floor jumped over, never accepted
    then), the least recently used forgotten first (its seqs then count as seen)."""

    __slots__ = ("holes", "main")

    def __init__(self, main: _Seen) -> None:
        self.main = main
        self.holes: list[_Seen] = []

    def stretch(self, seq: int) -> _Seen | None:
        """The stretch `seq` belongs to, None if it is older than all of them."""
        if self.main.holds(seq):
            return self.main
        for hole in self.holes:
            if hole.holds(seq):
                return hole
        return None

    def add(self, where: _Seen, seq: int, stamp: int) -> None:
        hole = where.add(seq, stamp)
        if hole is None:
            return
        last = self.holes[-1] if self.holes else None
        if where is self.main and last is not None and last.end == hole.floor \
                and len(last.marks) < MARKS:
            # The floor stepped from one lone frame far ahead to the next (a sparse
            # flood): one hole below them all, with those frames marked seen, so the
            # sender's own run keeps the hole it is heard in.
            last.marks.add(hole.floor)
            last.end = hole.end
            return
        self.holes.append(hole)
        if len(self.holes) > HOLES:
            self.holes.remove(min(self.holes, key=lambda h: h.stamp))

    def established(self) -> int:
        """The established top of the stretch that took the latest frame."""
        if not self.holes:  # a sender nobody flooded in its name: every heartbeat asks
            return self.main.established()
        return max([self.main, *self.holes], key=lambda h: h.stamp).established()


class ReplayFilter:
    __slots__ = ("origin", "since", "stamp", "state")

    def __init__(self, origin: int | None = None, since: float = 0.0) -> None:
        """`origin`: the receiver's own first seq (its wall clock at `since`, in seq
        units); None bounds nothing (the set alone)."""
        self.state: dict[int, _Sender] = {}
        self.origin = origin
        self.since = since
        self.stamp = 0
        """Frames accepted so far: which stretch of a sender took its latest frame."""

    def clock(self, now: float) -> int | None:
        """The receiver's own clock at `now`, in seq units (monotonic time since start:
        a wall clock stepped meanwhile moves nothing)."""
        if self.origin is None:
            return None
        return self.origin + int(RATE * max(0.0, now - self.since))

    def limit(self, now: float) -> int | None:
        """The highest seq any sender may have at `now` (None: unbounded)."""
        c = self.clock(now)
        return None if c is None else c + AHEAD

    def _beyond(self, seq: int, now: float) -> bool:
        """Is `seq` above `limit(now)`? The same sum, in one call: `stale` and `check`
        ask it of every frame heard."""
        origin = self.origin
        return origin is not None \
            and seq > origin + int(RATE * max(0.0, now - self.since)) + AHEAD

    def restore(self, sender: int, top: int) -> bool:
        """A peer's seq as persisted before a restart: it and everything below it count
        as seen, so an old frame stays old. One above the bound at our start is refused
        (False): an absurd value, kept, would mute the peer for good."""
        bound = self.limit(self.since)
        if bound is not None and top > bound:
            return False
        self.state[sender] = _Sender(_Seen(top))
        return True

    def stale(self, sender: int, seq: int, now: float) -> DropReason | None:
        """What `check` would say of a frame that is no longer new (`replay`, `seq_jump`),
        moving nothing: the cheap test a receiver makes before checking a signature, so
        a flood of played-back signed frames costs no signature check."""
        if self._beyond(seq, now):
            return DropReason.SEQ_JUMP
        known = self.state.get(sender)
        if known is None:
            return None
        where = known.stretch(seq)
        return DropReason.REPLAY if where is None or not where.fresh(seq) else None

    def accept(self, sender: int, seq: int, now: float | None = None) -> bool:
        return self.check(sender, seq, now) is None

    def check(self, sender: int, seq: int, now: float | None = None) -> DropReason | None:
        """None if the frame is new (and it is remembered), else the drop reason
        (`replay` or `seq_jump`). Without `now` (or an origin), seqs are not bounded."""
        if now is not None and self._beyond(seq, now):
            return DropReason.SEQ_JUMP
        known = self.state.get(sender)
        if known is None:
            # The first frame heard may be a forgery far ahead of the sender: until
            # WINDOW of its frames are heard, any not heard yet counts (`UNKNOWN`).
            known = self.state[sender] = _Sender(_Seen(UNKNOWN))
        where = known.stretch(seq)
        if where is None or not where.fresh(seq):
            return DropReason.REPLAY
        self.stamp += 1
        known.add(where, seq, self.stamp)
        return None

    def top(self, sender: int) -> int | None:
        """The sender's established top (`_Seen.established`), or None if unheard."""
        known = self.state.get(sender)
        return None if known is None else known.established()

    def tops(self) -> dict[int, int]:
        """Every sender's established top: what a restart persists (`peer_seq`), so a
        forged frame far ahead, kept, mutes nobody after the restart either."""
        return {r: known.established() for r, known in self.state.items()}
