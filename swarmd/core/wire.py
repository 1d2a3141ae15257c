"""Binary wire format: versioned, small, optionally authenticated frames.

Layout (big-endian)::

    0     1       3        5                 11      11+n
    | v|t | swarm | sender |  seq (48 bits)  | body  | tag (8 bytes, if signed) |

- byte 0: version in the high nibble (1), message type in bits 0-2, bit 3 set when the
  frame carries a tag. A signed HEARTBEAT is 11 + 4 + 8 = 23 bytes (DESIGN: <= 24, so
  it fits any XBee broadcast payload: Zigbee 92 B, 802.15.4 100 B, DigiMesh 73 B).
- body: HEARTBEAT `slot, epoch (16), role|health (8)` (with slot 0 the epoch field
  carries the sender's view of the slots it covers instead, `digest.py`), per robot
  followed by `n (8), link (8 bytes)` (its hash chain, `chain.py`: 24 bytes with no tag;
  an anchor carries the sender's signature in place of the tag, 88 bytes); WARN
  `robot (16), slot, epoch (16), belief (8)`; CLAIM `robot (16), slot, epoch (16)`;
  LEAVE `slot, epoch (16), reason (8)`; REFUTE `witness (16), slot, epoch (16), the
  witness's seq (48)`; CERT `slot, a relayed signed frame`.
- slot: a function's wire index (0 = none, 1..65535), variable length so that a swarm
  of fewer than 128 functions pays one byte as it always did: `0xxxxxxx` is 0..127 in
  one byte; a first byte 0x80..0xFE carries 15 bits `1hhhhhhh llllllll` (128..0x7EFF,
  two bytes); 0xFF is followed by the 16-bit slot (0x7F00..0xFFFF, three bytes). Only
  the shortest form is valid, so every slot has exactly one encoding.
- seq: a per-sender counter that rises with every frame sent. Senders seed it from
  their wall clock in 10 us units (as MAVLink 2 signing does), so a sender that
  restarted starts above anything it sent before. Receivers keep a sliding window per
  sender (`replay.py`, 64 frames): a frame above the highest seq seen, or within the
  window below it and not seen yet, is accepted (a channel that reorders loses
  nothing); a repeat, or a frame older than the window, is dropped as `replay`. The
  seeding is the runtime's job (`seq_seed`).
- tag: HMAC-SHA256 over everything before it, truncated to 8 bytes (MAVLink 2 uses 6).

`decode` raises only `CodecError` on any input, its `reason` the drop counter's
`DropReason` (DESIGN section 2: every refused frame is a counted drop);
`peek` reads sender, type and slot without verifying anything (the receiver's early
drop of frames about slots it does not care about: DESIGN section 2, "What a robot
hears") and returns None on anything it cannot read.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import NamedTuple

from swarmd.core.auth import SIGNATURE_LEN, Signer, Verifier
from swarmd.core.chain import LINK_LEN
from swarmd.core.drops import DropReason
from swarmd.core.errors import CodecError as CodecError

VERSION = 1
TAG_LEN = 8
KEY_LEN = 32
"""bytes. A swarm key's size (HMAC takes any length; a fixed size catches a wrong key
file). `swarmd.base.keys` reads and writes keys of this size; `Node.set_keys` checks it."""
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
    CERT = 5
    REFUTE = 6


class LeaveReason(IntEnum):
    SHUTDOWN = 0  # graceful stop (handover_on_stop)
    FAULT = 1  # the robot reported itself faulty (DESIGN rule 7)
    FENCED = 2  # it learnt its slot was taken over


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """The paper's health signal. `function` 0 means no function (standby).

    Per-robot mode adds the sender's chain link (`chain.py`): `n` its number modulo 256,
    `link` its `chain.LINK_LEN` bytes, `anchor` set when the sender's own signature
    covers the frame (then the link is where its chain stands)."""

    function: int
    epoch: int
    role: int
    health: int
    n: int = 0
    link: bytes = b""
    anchor: bool = False


@dataclass(frozen=True, slots=True)
class Warn:
    """The paper's warning (ping_id = sender, warn_id = suspect). `belief`: how strongly
    the sender suspects, its suspicion level in tenths (0..255, `belief.level_byte`;
    DESIGN "Detection"): a standby counts the warning only from its `suspect_level` up."""

    suspect: int
    function: int
    epoch: int
    belief: int = 255


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


@dataclass(frozen=True, slots=True)
class Cert:
    """One piece of a takeover's certificate: another robot's WARN, LEAVE, REFUTE or
    CLAIM frame about `function`, relayed verbatim by a claimant, a holder, or a robot
    showing an older view the takeover it missed. `inner` is that frame decoded and
    verified as it would be heard from its sender (per robot its own signature, with a
    shared key the swarm's tag); `raw` its bytes, to relay again."""

    function: int
    inner: Frame
    raw: bytes


@dataclass(frozen=True, slots=True)
class Refute:
    """The holder of `function` at `epoch` says (per robot under its own signature)
    that it was alive after `witness`'s warning number `seq` about it (DESIGN rule 4 made
    portable): that warning and every earlier one of `witness` about this holder at this
    epoch back no takeover, at any robot that has this frame."""

    witness: int
    function: int
    epoch: int
    seq: int


Message = Heartbeat | Warn | Claim | Leave | Cert | Refute

# Enum members read through their class cost ~120 ns each on CPython 3.11 (measured with
# timeit), a module constant ~10: the ones read for every frame heard, bound once.
_HEARTBEAT, _CERT = MsgType.HEARTBEAT, MsgType.CERT

STRONG = frozenset({MsgType.WARN, MsgType.CLAIM, MsgType.LEAVE, MsgType.REFUTE})
"""The frames that change state: in per-robot mode they carry their sender's own
signature (`SIGNATURE_LEN` bytes) instead of the swarm's HMAC tag."""
BACKERS = frozenset({MsgType.WARN, MsgType.LEAVE})
"""The frames that back a takeover's certificate. Relayed inside a CERT (or restored
from a state file), they are history: verified with every key their sender ever had,
one since retired or revoked included (`Verifier.verify`'s `history`; DESIGN, "Key
changes never rewrite history"). A CLAIM or REFUTE, and every frame heard first-hand,
needs a key in force."""

SLOT_MAX = 0xFFFF
_HB_TAIL = struct.Struct(">HB")
_PEEK = struct.Struct(">BHH")
_U16 = struct.Struct(">H")
_SLOT_AT = {MsgType.HEARTBEAT: 0, MsgType.WARN: 2, MsgType.CLAIM: 2, MsgType.LEAVE: 0,
            MsgType.CERT: 0, MsgType.REFUTE: 2}
"""Offset of the slot field in each body (after the 16-bit robot id in WARN, CLAIM and
REFUTE)."""
_TYPES: tuple[MsgType | None, ...] = (None, *MsgType, None)
"""Message type by the low 3 bits of byte 0 (0 and 7 are no type)."""
_FIXED_BODY = {MsgType.HEARTBEAT: 3, MsgType.WARN: 5, MsgType.CLAIM: 4, MsgType.LEAVE: 3,
               MsgType.REFUTE: 10}
_INNER_MIN = HEADER_LEN + 4 + SIGNATURE_LEN
"""Body bytes besides the slot field."""


def slot_size(slot: int) -> int:
    """Bytes the slot field takes on the wire (1, 2 or 3)."""
    if not 0 <= slot <= SLOT_MAX:
        raise ValueError(f"slot {slot} does not fit 16 bits")
    return 1 if slot < 0x80 else 2 if slot < 0x7F00 else 3


def encode_slot(slot: int) -> bytes:
    size = slot_size(slot)
    if size == 1:
        return bytes((slot,))
    if size == 2:
        return bytes((0x80 | (slot >> 8), slot & 0xFF))
    return b"\xff" + _U16.pack(slot)


def _read_slot(data: bytes, at: int) -> tuple[int, int] | None:
    """(slot, bytes used) at `at`, or None if truncated or not in its shortest form."""
    if at >= len(data):
        return None
    first = data[at]
    if first < 0x80:
        return first, 1
    if first < 0xFF:
        if at + 2 > len(data):
            return None
        slot = ((first & 0x7F) << 8) | data[at + 1]
        return (slot, 2) if slot >= 0x80 else None
    if at + 3 > len(data):
        return None
    slot = _U16.unpack_from(data, at + 1)[0]
    return (slot, 3) if slot >= 0x7F00 else None


@dataclass(frozen=True, slots=True)
class Frame:
    swarm_id: int
    sender: int
    seq: int
    msg: Message
    raw: bytes = field(default=b"", compare=False, repr=False)
    """The bytes it was decoded from, for a WARN, CLAIM, LEAVE or REFUTE (`STRONG`, in
    every auth mode: a takeover's certificate relays them) and a signed anchor; empty
    otherwise."""


_TYPE_OF: dict[type[Message], MsgType] = {
    Heartbeat: MsgType.HEARTBEAT, Warn: MsgType.WARN, Claim: MsgType.CLAIM,
    Leave: MsgType.LEAVE, Cert: MsgType.CERT, Refute: MsgType.REFUTE}
"""Each message class's type on the wire (`encode`)."""


def _body(msg: Message) -> bytes:
    match msg:
        case Heartbeat(function, epoch, role, health):
            return encode_slot(function) + _HB_TAIL.pack(
                epoch, (role & 0x0F) | ((health & 0x0F) << 4))
        case Warn(suspect, function, epoch, belief):
            if not 0 <= belief <= 0xFF:
                raise ValueError(f"belief {belief} does not fit 8 bits")
            return _U16.pack(suspect) + encode_slot(function) + _U16.pack(epoch) \
                + bytes((belief,))
        case Claim(failed, function, epoch):
            return _U16.pack(failed) + encode_slot(function) + _U16.pack(epoch)
        case Leave(function, epoch, reason):
            return encode_slot(function) + _HB_TAIL.pack(epoch, reason)
        case Cert(function, _, raw):
            return encode_slot(function) + raw
        case Refute(witness, function, epoch, seq):
            if not 0 <= seq <= SEQ_MAX:
                raise ValueError(f"seq {seq} does not fit 48 bits")
            return _U16.pack(witness) + encode_slot(function) + _U16.pack(epoch) \
                + seq.to_bytes(6, "big")
    raise TypeError(f"not a message: {msg!r}")  # pragma: no cover


def tag(key: bytes, data: bytes) -> bytes:
    # The one-shot C HMAC: every frame of a keyed swarm is tagged or checked here.
    return hmac.digest(key, data, hashlib.sha256)[:TAG_LEN]


def encode(frame: Frame, key: bytes | None = None, signer: Signer | None = None) -> bytes:
    """Serialise a frame; with `signer` (per-robot mode) a WARN, CLAIM or LEAVE carries
    its sender's own signature, any other frame the HMAC tag of `key` if given; a CERT
    never carries a tag of its own (what it relays is signed). Raises on out-of-range
    fields (that is misuse by our own code, never peer input)."""
    if not 0 <= frame.seq <= SEQ_MAX:
        raise ValueError(f"seq {frame.seq} does not fit 48 bits")
    mtype = _TYPE_OF[type(frame.msg)]
    if mtype == MsgType.CERT:
        key = None
    msg = frame.msg
    strong = signer is not None and (mtype in STRONG or (
        isinstance(msg, Heartbeat) and msg.anchor))
    first = (VERSION << 4) | int(mtype) | (_SIGNED if key or strong else 0)
    try:
        head = HEADER.pack(first, frame.swarm_id, frame.sender, frame.seq.to_bytes(6, "big"))
        body = _body(msg)
        if signer is not None and isinstance(msg, Heartbeat):
            if len(msg.link) != LINK_LEN or not 0 <= msg.n <= 0xFF:
                raise ValueError("a per-robot heartbeat carries its chain link")
            body += bytes((msg.n,)) + msg.link
    except (struct.error, ValueError) as exc:
        raise ValueError(f"field out of range in {frame!r}: {exc}") from exc
    data = head + body
    if strong:
        assert signer is not None
        return data + signer.sign(data)
    return data + tag(key, data) if key else data


def retag(data: bytes, key: bytes | None) -> bytes:
    """A frame of a shared-key or unsigned swarm (`data`, well formed) tagged with `key`
    instead (untagged if None). A tag proves only that a holder of the swarm key made
    the frame, so a robot that accepted a frame may vouch for it again under the key in
    force now: a proof it relays, or kept across a reboot, outlives a rotation of the
    key (docs/operations.md, "Rotating the swarm key")."""
    body = data[:-TAG_LEN] if data and data[0] & _SIGNED else data
    if len(body) < HEADER_LEN:
        return data  # no frame: `decode` refuses it as it is
    head = bytes((body[0] & ~_SIGNED | (_SIGNED if key else 0),))
    body = head + body[1:]
    return body + tag(key, body) if key else body


def decode(data: bytes, keys: Sequence[bytes] = (), verifier: Verifier | None = None,
           *, inner: bool = False) -> Frame:
    """Parse and verify a frame. With `keys`, an unsigned frame or one whose tag matches
    no key is rejected (several keys: a rotation window); without, a tagged one is.
    With `verifier` (per-robot mode) a WARN, CLAIM, LEAVE or REFUTE must carry its
    sender's own signature, a HEARTBEAT its chain link (an anchor: the signature in
    place of the tag; whether a link is the sender's is the receiver's to check,
    `chain.py`). A CERT relays one such frame about its slot, checked as that frame
    would be: its sender's signature per robot, else the swarm key's tag, else nothing."""
    if len(data) < HEADER_LEN + 1:
        raise CodecError(DropReason.MALFORMED, f"{len(data)} bytes is shorter than any frame")
    first, swarm_id, sender, seq_bytes = HEADER.unpack_from(data)
    version = first >> 4
    if version != VERSION:
        raise CodecError(DropReason.VERSION, f"version {version}, this node speaks {VERSION}")
    mtype = _TYPES[first & _TYPE_MASK]  # a table look-up, not an enum construction
    if mtype is None:
        raise CodecError(DropReason.MALFORMED, f"unknown message type {first & _TYPE_MASK}")
    signed = bool(first & _SIGNED)
    slot_at = HEADER_LEN + _SLOT_AT[mtype]
    got_slot = _read_slot(data, slot_at)
    if got_slot is None:
        raise CodecError(DropReason.MALFORMED,
                         f"{mtype.name} with a truncated or overlong slot field")
    slot, slot_len = got_slot
    if mtype == _CERT:
        return _decode_cert(data, swarm_id, sender, seq_bytes, slot, slot_len, signed,
                            keys, verifier, inner)
    linked = verifier is not None and mtype == _HEARTBEAT
    body_len = _FIXED_BODY[mtype] + slot_len + (1 + LINK_LEN if linked else 0)
    strong = verifier is not None and (mtype in STRONG or (
        linked and signed and len(data) == HEADER_LEN + body_len + SIGNATURE_LEN))
    auth_len = SIGNATURE_LEN if strong else TAG_LEN
    expected = HEADER_LEN + body_len + (auth_len if signed else 0)
    if len(data) != expected:
        raise CodecError(DropReason.MALFORMED,
                         f"{mtype.name} of {len(data)} bytes, expected {expected}")
    _verify(data, sender, mtype, signed, keys, verifier if strong else None,
            history=inner and mtype in BACKERS)
    msg = _message(data, mtype, slot, slot_at + slot_len, strong=strong, linked=linked)
    # The bytes of a frame a certificate may carry (`STRONG`), in every mode: relayed
    # as heard, they are checked again at each robot as the sender's own.
    return Frame(swarm_id, sender, int.from_bytes(seq_bytes, "big"), msg,
                 data if strong or mtype in STRONG else b"")


def _verify(data: bytes, sender: int, mtype: MsgType, signed: bool, keys: Sequence[bytes],
            verifier: Verifier | None, *, history: bool = False) -> None:
    """The sender's own signature (`verifier`: a frame that must carry one; `history`:
    a certificate's backer, `BACKERS`), else the swarm key's tag (`keys`), else nothing.
    Raises `CodecError(DropReason.AUTH)`."""
    if verifier is not None:
        if not signed:
            raise CodecError(DropReason.AUTH, f"{mtype.name} without its sender's signature")
        if not verifier.verify(sender, data[:-SIGNATURE_LEN], data[-SIGNATURE_LEN:],
                               history=history):
            raise CodecError(DropReason.AUTH, f"bad signature of robot {sender}")
    elif keys:
        if not signed:
            raise CodecError(DropReason.AUTH, "unsigned frame on a swarm with a key")
        signed_part, got = data[:-TAG_LEN], data[-TAG_LEN:]
        if not any(hmac.compare_digest(tag(k, signed_part), got) for k in keys):
            raise CodecError(DropReason.AUTH, "bad authentication tag")
    elif signed:
        raise CodecError(DropReason.AUTH, "signed frame but no swarm key configured")


def _message(data: bytes, mtype: MsgType, slot: int, after: int, *, strong: bool,
             linked: bool) -> Message:
    """The body of a verified frame; `after`: the offset past its slot field."""
    if mtype == _HEARTBEAT:  # almost every frame: before the match of the others
        epoch, rh = _HB_TAIL.unpack_from(data, after)
        # Positional, in the order of `Heartbeat`'s fields (function, epoch, role,
        # health; n, link, anchor): keywords cost a dataclass's __init__ ~0.4 us more.
        if not linked:
            return Heartbeat(slot, epoch, rh & 0x0F, rh >> 4)
        return Heartbeat(slot, epoch, rh & 0x0F, rh >> 4, data[after + 3],
                         data[after + 4:after + 4 + LINK_LEN], strong)
    match mtype:
        case MsgType.WARN:
            return Warn(suspect=_U16.unpack_from(data, HEADER_LEN)[0], function=slot,
                        epoch=_U16.unpack_from(data, after)[0], belief=data[after + 2])
        case MsgType.CLAIM:
            return Claim(failed=_U16.unpack_from(data, HEADER_LEN)[0], function=slot,
                         epoch=_U16.unpack_from(data, after)[0])
        case MsgType.LEAVE:
            epoch, reason = _HB_TAIL.unpack_from(data, after)
            return Leave(function=slot, epoch=epoch, reason=reason)
        case MsgType.REFUTE:
            return Refute(witness=_U16.unpack_from(data, HEADER_LEN)[0], function=slot,
                          epoch=_U16.unpack_from(data, after)[0],
                          seq=int.from_bytes(data[after + 2:after + 8], "big"))
    raise CodecError(DropReason.MALFORMED,
                     f"{mtype.name} has no body of its own")  # pragma: no cover


def _decode_cert(data: bytes, swarm_id: int, sender: int, seq_bytes: bytes, slot: int,
                 slot_len: int, signed: bool, keys: Sequence[bytes],
                 verifier: Verifier | None, inner: bool) -> Frame:
    if inner:
        raise CodecError(DropReason.MALFORMED, "a certificate inside a certificate")
    if signed:
        raise CodecError(DropReason.MALFORMED, "a certificate carries no tag of its own")
    raw = data[HEADER_LEN + slot_len:]
    if len(raw) < (_INNER_MIN if verifier is not None else HEADER_LEN + 4):
        raise CodecError(DropReason.MALFORMED, f"certificate of {len(data)} bytes is too short")
    # What it relays carries its own sender's signature (per robot) or the swarm key's
    # tag, checked like any frame heard; unsigned, nothing. Raises
    # CodecError(DropReason.AUTH) if forged.
    got = decode(raw, keys, verifier, inner=True)
    if not isinstance(got.msg, (Warn, Leave, Refute, Claim)) or got.msg.function != slot \
            or got.swarm_id != swarm_id:
        raise CodecError(DropReason.MALFORMED,
                         "a certificate relays a WARN, LEAVE, REFUTE or CLAIM of its slot")
    return Frame(swarm_id, sender, int.from_bytes(seq_bytes, "big"), Cert(slot, got, raw))


class Peek(NamedTuple):
    """What a receiver can read of a frame before verifying it (`peek`)."""

    swarm_id: int
    sender: int
    mtype: MsgType
    slot: int
    robot: int
    """WARN's suspect, CLAIM's failed robot or REFUTE's witness; 0 for HEARTBEAT, LEAVE
    and CERT."""


def peek(data: bytes) -> Peek | None:
    """Header and slot of a frame, unverified: None for anything `decode` would reject
    as malformed at a glance. Whatever it returns still goes through `decode` before it
    is believed; a receiver uses it only to drop frames it would ignore anyway."""
    # Runs on every frame a robot receives: table look-ups, no enum construction.
    if len(data) < HEADER_LEN + 3:
        return None
    first, swarm_id, sender = _PEEK.unpack_from(data)
    if first >> 4 != VERSION:
        return None
    mtype = _TYPES[first & _TYPE_MASK]
    if mtype is None:
        return None
    at = _SLOT_AT[mtype]
    byte = data[HEADER_LEN + at]
    if byte < 0x80:  # the common case: a swarm of fewer than 128 functions
        slot = byte
    else:
        got = _read_slot(data, HEADER_LEN + at)
        if got is None:
            return None
        slot = got[0]
    robot = (data[HEADER_LEN] << 8) | data[HEADER_LEN + 1] if at else 0
    # tuple.__new__ as `Peek._make` does: the named tuple's own __new__ is one more
    # Python call per frame.
    return tuple.__new__(Peek, (swarm_id, sender, mtype, slot, robot))


def seq_seed(unix_time: float) -> int:
    """The first sequence number of a sender started at `unix_time` (10 us units since
    2015-01-01, MAVLink 2's epoch), so a restarted sender is always newer. Pure: the
    runtime passes the clock in."""
    return max(0, min(SEQ_MAX, int((unix_time - 1_420_070_400.0) * 100_000)))
