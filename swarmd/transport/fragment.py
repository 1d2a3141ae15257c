"""Fragments: frames larger than a radio's payload, carried in pieces (sans-IO).

A per-robot signed WARN or CLAIM is 80 B, a CERT 92 B (docs/DESIGN.md, "Sizes"); a
DigiMesh broadcast carries 73 B, a transparent serial radio 64 B of swarmd frame. The
transports that meet such a limit (XBee, serial) `split` a frame that does not fit into
fragments and pass what they receive through a `Reassembler`; frames that fit go out
unchanged, so a heartbeat never pays anything. The core never sees a fragment.

Layout of one fragment (big-endian, 6 bytes of header)::

    0      1        3        5            6
    | 0xF1 | sender | msg id | idx | cnt  | piece of the frame |

- byte 0: 0xF1. A swarmd frame has version 1 in the high nibble of byte 0 (wire.py),
  so a fragment is told from a frame by its first byte, and a daemon that does not
  reassemble drops it as a counted `version` drop.
- sender: the robot id from the frame's own header (bytes 3-4, `wire.HEADER`).
- msg id: 16 random bits the sending transport draws for each message (`secrets`), so a
  listener cannot tell the next message's id from the last; (sender, msg id) names one
  message while its fragments are in flight.
- byte 5: the fragment's index (high nibble) and the message's fragment count (low
  nibble), 2..`MAX_FRAGMENTS`.

The pieces are of near-equal size (their lengths differ by at most one byte).

Hostile input is the design constraint (DESIGN: bad input never takes the daemon down):
`Reassembler.feed` never raises; memory is bounded (at most `MAX_PARTIAL` messages in
flight, the oldest evicted first, and at most `MAX_PER_SENDER` of one sender, that
sender's oldest evicted first; at most `MAX_FRAGMENTS` pieces of a message; a whole
message at most `MAX_FRAME` bytes); a partial message expires `EXPIRY` s after its first
fragment; a duplicate, an out-of-range index, a count that contradicts the message's
first fragment, or a message whose sender differs from the frame inside it is dropped
and counted in `drops` by reason.

Reassembly is not authentication. The reassembled frame goes to the core, which checks
its signature as it checks any frame. Anyone who can transmit can forge fragments, and a
forged fragment can at most spoil the one message whose (sender, msg id) it names: taken
in first, it makes that message fail its signature check or never complete, and the
genuine piece is then dropped as a duplicate. Since ids are random, a forger spoils only
a message it has seen a fragment of (its id), not the sender's next ones; a guess hits
one message in 65,536. Flooding fragments of made-up messages in one robot's name evicts
only that robot's partial messages (`MAX_PER_SENDER`), in many names the oldest of all
(a loss, like jamming); it never lets a frame through that the core would not accept
whole.
"""

from __future__ import annotations

import secrets
import struct
from collections import Counter, OrderedDict
from dataclasses import dataclass

from swarmd.transport.drops import FragmentDrop

MARKER = 0xF1
HEADER = struct.Struct(">BHHB")
HEADER_LEN = HEADER.size  # 6
MAX_FRAGMENTS = 8
"""Most pieces one frame is cut into (4 bits on the wire; 8 keeps a message's loss
chance low: every piece must arrive)."""
MAX_FRAME = 512
"""Largest frame carried in fragments, bytes (a swarmd frame is at most 96 B)."""
MIN_LIMIT = 24
"""Smallest payload limit fragments are made for: 18 B of frame per fragment, so a
92-byte CERT takes 6 fragments."""
MAX_PARTIAL = 32
"""Messages in reassembly at once; one more evicts the oldest."""
MAX_PER_SENDER = 4
"""Messages of one sender in reassembly at once; one more evicts that sender's oldest.
A daemon has at most one message in flight at a time (its fragments leave back to back);
4 leaves room for a retry and a reordering radio."""
EXPIRY = 2.0
"""s. A message not complete this long after its first fragment is dropped."""
MSG_ID_MASK = 0xFFFF
_SENDER = slice(3, 5)
"""Where a swarmd frame carries its sender (wire.HEADER: version|type, swarm, sender)."""


def new_msg_id() -> int:
    """A message id no listener can predict from the ones it heard (16 random bits). A
    counter would let anyone who heard one message spoil the sender's next ones with a
    forged fragment each; a random id also never repeats a restarted sender's last ids
    but by chance."""
    return secrets.randbits(16)


class FragmentError(ValueError):
    """A frame that cannot be split (too large for `MAX_FRAGMENTS` pieces or `MAX_FRAME`)."""


def is_fragment(datagram: bytes) -> bool:
    """Whether `datagram` starts like a fragment (not a swarmd frame)."""
    return bool(datagram) and datagram[0] == MARKER


def sizes(frame_len: int, limit: int) -> list[int]:
    """Datagram sizes a `frame_len`-byte frame goes out as under `limit` (one entry:
    unsplit). Raises `FragmentError` if it cannot be carried."""
    if frame_len <= limit:
        return [frame_len]
    room = limit - HEADER_LEN
    if room <= 0 or frame_len > MAX_FRAME:
        raise FragmentError(f"a {frame_len} B frame cannot be split for a {limit} B limit")
    count = -(-frame_len // room)
    if count > MAX_FRAGMENTS:
        raise FragmentError(f"a {frame_len} B frame needs {count} fragments of a {limit} B "
                            f"limit, more than {MAX_FRAGMENTS}")
    base, extra = divmod(frame_len, count)
    return [HEADER_LEN + base + (1 if i < extra else 0) for i in range(count)]


def split(frame: bytes, limit: int, msg_id: int) -> list[bytes]:
    """`[frame]` when it fits `limit`, else its fragments, each at most `limit` bytes.
    Raises `FragmentError` when it cannot be carried (see `sizes`)."""
    lengths = sizes(len(frame), limit)
    if len(lengths) == 1:
        return [frame]
    sender = int.from_bytes(frame[_SENDER], "big") if len(frame) >= _SENDER.stop else 0
    out: list[bytes] = []
    at = 0
    count = len(lengths)
    for index, size in enumerate(lengths):
        piece = frame[at : at + size - HEADER_LEN]
        at += len(piece)
        out.append(HEADER.pack(MARKER, sender, msg_id & MSG_ID_MASK, index << 4 | count)
                   + piece)
    return out


@dataclass(slots=True)
class _Partial:
    count: int
    started: float
    pieces: list[bytes | None]
    size: int = 0
    have: int = 0


class Reassembler:
    """Whole frames out of received datagrams (see the module docstring).

    `feed(datagram, now)` returns the datagram itself when it is not a fragment, the
    whole frame when this fragment completes one, and None otherwise; `now` is any
    monotonic clock in seconds. `drops` counts what was thrown away, by reason: short,
    bad_count, bad_index, inconsistent, duplicate, too_large, sender_mismatch, expired,
    evicted, evicted_sender."""

    def __init__(self, *, max_partial: int = MAX_PARTIAL, expiry: float = EXPIRY,
                 max_per_sender: int = MAX_PER_SENDER) -> None:
        self.max_partial = max_partial
        self.max_per_sender = max_per_sender
        self.expiry = expiry
        self._partial: OrderedDict[tuple[int, int], _Partial] = OrderedDict()
        self._done: OrderedDict[tuple[int, int], float] = OrderedDict()
        """Messages completed within `expiry`: a late duplicate piece is not a new one."""
        self.drops: Counter[str] = Counter()
        self.completed = 0

    def __len__(self) -> int:
        """Messages in reassembly."""
        return len(self._partial)

    def feed(self, datagram: bytes, now: float) -> bytes | None:
        if not is_fragment(datagram):
            return datagram
        self._expire(now)
        if len(datagram) <= HEADER_LEN:
            self.drops[FragmentDrop.SHORT] += 1
            return None
        _, sender, msg_id, packed = HEADER.unpack_from(datagram)
        index, count = packed >> 4, packed & 0x0F
        if not 2 <= count <= MAX_FRAGMENTS:
            self.drops[FragmentDrop.BAD_COUNT] += 1
            return None
        if index >= count:
            self.drops[FragmentDrop.BAD_INDEX] += 1
            return None
        key = (sender, msg_id)
        if key in self._done:
            self.drops[FragmentDrop.DUPLICATE] += 1
            return None
        part = self._partial_for(key, count, now)
        if part is None:
            return None
        if part.pieces[index] is not None:
            self.drops[FragmentDrop.DUPLICATE] += 1
            return None
        piece = datagram[HEADER_LEN:]
        if part.size + len(piece) > MAX_FRAME:
            del self._partial[key]
            self.drops[FragmentDrop.TOO_LARGE] += 1
            return None
        part.pieces[index] = piece
        part.size += len(piece)
        part.have += 1
        if part.have < count:
            return None
        return self._complete(key, part, now)

    def _partial_for(self, key: tuple[int, int], count: int, now: float) -> _Partial | None:
        """The message `key` in reassembly, started (evicting to make room) if new;
        None when a piece disagrees with it on the count (dropped)."""
        part = self._partial.get(key)
        if part is None:
            mine = [k for k in self._partial if k[0] == key[0]]
            if len(mine) >= self.max_per_sender:
                del self._partial[mine[0]]  # arrival order: that sender's oldest
                self.drops[FragmentDrop.EVICTED_SENDER] += 1
            while len(self._partial) >= self.max_partial:
                self._partial.popitem(last=False)
                self.drops[FragmentDrop.EVICTED] += 1
            part = self._partial[key] = _Partial(count, now, [None] * count)
        elif part.count != count:
            self.drops[FragmentDrop.INCONSISTENT] += 1
            return None
        return part

    def _complete(self, key: tuple[int, int], part: _Partial, now: float) -> bytes | None:
        """The frame of a message with every piece in, if it is the sender's own."""
        del self._partial[key]
        self._remember(key, now)
        frame = b"".join(p for p in part.pieces if p is not None)
        if len(frame) < _SENDER.stop or int.from_bytes(frame[_SENDER], "big") != key[0]:
            self.drops[FragmentDrop.SENDER_MISMATCH] += 1
            return None
        self.completed += 1
        return frame

    def _remember(self, key: tuple[int, int], now: float) -> None:
        self._done[key] = now
        self._done.move_to_end(key)
        while len(self._done) > 2 * self.max_partial:
            self._done.popitem(last=False)

    def _expire(self, now: float) -> None:
        # Both maps are in arrival order, so the expired entries are at the front (a
        # clock that went back only delays expiry).
        while self._partial:
            key, part = next(iter(self._partial.items()))
            if now - part.started < self.expiry:
                break
            del self._partial[key]
            self.drops[FragmentDrop.EXPIRED] += 1
        while self._done:
            key, done = next(iter(self._done.items()))
            if now - done < self.expiry:
                break
            del self._done[key]
