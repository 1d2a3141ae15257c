"""Binary wire format: versioned, small, optionally authenticated frames.

Layout (big-endian)::

    0     1       3        5                 11      11+n
    | v|t | swarm | sender |  seq (48 bits)  | body  | tag (8 bytes, if signed) |

- byte 0: version in the high nibble (1), message type in bits 0-2, bit 3 set when the
  frame carries a tag. A signed HEARTBEAT is 11 + 4 + 8 = 23 bytes (DESIGN: <= 24, so
  it fits any XBee broadcast payload: Zigbee 92 B, 802.15.4 100 B, DigiMesh 73 B).
- seq: a per-sender counter that rises with every frame sent. Senders seed it from
  their wall clock in 10 us units (as MAVLink 2 signing does), so a sender that
  restarted starts above anything it sent before. Receivers keep a sliding window per
  sender (`replay.py`, 64 frames): a frame above the highest seq seen, or within the
  window below it and not seen yet, is accepted (a channel that reorders loses
  nothing); a repeat, or a frame older than the window, is dropped as `replay`. The
  seeding is the runtime's job (`seq_seed`).
- tag: HMAC-SHA256 over everything before it, truncated to 8 bytes (MAVLink 2 uses 6).

`decode` raises only `CodecError` (with a machine-readable `reason`) on any input.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum

VERSION = 1
TAG_LEN = 8
KEY_LEN = 32
"""bytes. A swarm key's size (HMAC takes any length; a fixed size catches a wrong key
file). `swarmd.keys` reads and writes keys of this size; `Node.set_keys` checks it."""
HEADER = struct.Struct(">BHH6s")
HEADER_LEN = HEADER.size  # 11
SEQ_MAX = (1 << 48) - 1
_SIGNED = 0x08
_TYPE_MASK = 0x07


class MsgType(IntEnum):
    HEARTBEAT = 1
    WARN = 2
    CLAIM = 3
    LEAVE = 4


class LeaveReason(IntEnum):
    SHUTDOWN = 0  # graceful stop (handover_on_stop)
    FAULT = 1  # the robot reported itself faulty (DESIGN rule 7)
    FENCED = 2  # it learnt its slot was taken over


class CodecError(ValueError):
    """A frame that cannot be decoded or verified. `reason` names the drop counter."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """The paper's health signal. `function` 0 means no function (standby)."""

    function: int
    epoch: int
    role: int
    health: int


@dataclass(frozen=True, slots=True)
class Warn:
    """The paper's warning (ping_id = sender, warn_id = suspect)."""

    suspect: int
    function: int
    epoch: int


@dataclass(frozen=True, slots=True)
class Claim:
    """The paper's wait-state broadcast: `sender` claims `function` at `epoch`."""

    failed: int
    function: int
    epoch: int


@dataclass(frozen=True, slots=True)
class Leave:
    """Graceful exit or self-reported fault: hand over now, no timeout."""

    function: int
    epoch: int
    reason: int


Message = Heartbeat | Warn | Claim | Leave

_BODY: dict[MsgType, struct.Struct] = {
    MsgType.HEARTBEAT: struct.Struct(">BHB"),
    MsgType.WARN: struct.Struct(">HBH"),
    MsgType.CLAIM: struct.Struct(">HBH"),
    MsgType.LEAVE: struct.Struct(">BHB"),
}


@dataclass(frozen=True, slots=True)
class Frame:
    swarm_id: int
    sender: int
    seq: int
    msg: Message


def _type_of(msg: Message) -> MsgType:
    match msg:
        case Heartbeat():
            return MsgType.HEARTBEAT
        case Warn():
            return MsgType.WARN
        case Claim():
            return MsgType.CLAIM
        case Leave():
            return MsgType.LEAVE
    raise TypeError(f"not a message: {msg!r}")  # pragma: no cover - exhaustive above


def _body_fields(msg: Message) -> tuple[int, ...]:
    match msg:
        case Heartbeat(function, epoch, role, health):
            return (function, epoch, (role & 0x0F) | ((health & 0x0F) << 4))
        case Warn(suspect, function, epoch) | Claim(suspect, function, epoch):
            return (suspect, function, epoch)
        case Leave(function, epoch, reason):
            return (function, epoch, reason)
    raise TypeError(f"not a message: {msg!r}")  # pragma: no cover


def tag(key: bytes, data: bytes) -> bytes:
    return hmac.new(key, data, hashlib.sha256).digest()[:TAG_LEN]


def encode(frame: Frame, key: bytes | None = None) -> bytes:
    """Serialise a frame; sign it when `key` is given. Raises on out-of-range fields
    (that is misuse by our own code, never peer input)."""
    if not 0 <= frame.seq <= SEQ_MAX:
        raise ValueError(f"seq {frame.seq} does not fit 48 bits")
    mtype = _type_of(frame.msg)
    first = (VERSION << 4) | int(mtype) | (_SIGNED if key else 0)
    try:
        head = HEADER.pack(first, frame.swarm_id, frame.sender, frame.seq.to_bytes(6, "big"))
        body = _BODY[mtype].pack(*_body_fields(frame.msg))
    except struct.error as exc:
        raise ValueError(f"field out of range in {frame!r}: {exc}") from exc
    data = head + body
    return data + tag(key, data) if key else data


def decode(data: bytes, keys: Sequence[bytes] = ()) -> Frame:
    """Parse and verify a frame. With `keys`, an unsigned frame or one whose tag matches
    no key is rejected; several keys serve key rotation (accept old and new for a
    window). Without keys, a signed frame is rejected: it cannot be verified."""
    if len(data) < HEADER_LEN + 1:
        raise CodecError("malformed", f"{len(data)} bytes is shorter than any frame")
    first, swarm_id, sender, seq_bytes = HEADER.unpack_from(data)
    version = first >> 4
    if version != VERSION:
        raise CodecError("version", f"version {version}, this node speaks {VERSION}")
    try:
        mtype = MsgType(first & _TYPE_MASK)
    except ValueError:
        raise CodecError("malformed", f"unknown message type {first & _TYPE_MASK}") from None
    signed = bool(first & _SIGNED)
    body_struct = _BODY[mtype]
    expected = HEADER_LEN + body_struct.size + (TAG_LEN if signed else 0)
    if len(data) != expected:
        raise CodecError("malformed", f"{mtype.name} of {len(data)} bytes, expected {expected}")
    if keys:
        if not signed:
            raise CodecError("auth", "unsigned frame on a swarm with a key")
        signed_part, got = data[:-TAG_LEN], data[-TAG_LEN:]
        if not any(hmac.compare_digest(tag(k, signed_part), got) for k in keys):
            raise CodecError("auth", "bad authentication tag")
    elif signed:
        raise CodecError("auth", "signed frame but no swarm key configured")
    a, b, c = body_struct.unpack_from(data, HEADER_LEN)
    msg: Message
    match mtype:
        case MsgType.HEARTBEAT:
            msg = Heartbeat(function=a, epoch=b, role=c & 0x0F, health=c >> 4)
        case MsgType.WARN:
            msg = Warn(suspect=a, function=b, epoch=c)
        case MsgType.CLAIM:
            msg = Claim(failed=a, function=b, epoch=c)
        case MsgType.LEAVE:
            msg = Leave(function=a, epoch=b, reason=c)
    return Frame(swarm_id, sender, int.from_bytes(seq_bytes, "big"), msg)


def seq_seed(unix_time: float) -> int:
    """The first sequence number of a sender started at `unix_time` (10 us units since
    2015-01-01, MAVLink 2's epoch), so a restarted sender is always newer. Pure: the
    runtime passes the clock in."""
    return max(0, min(SEQ_MAX, int((unix_time - 1_420_070_400.0) * 100_000)))
