"""Wire codec (DESIGN section 2, "Messages"): round trips, size, garbage, auth, rotation."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmd.core import wire
from swarmd.core.drops import DropReason
from swarmd.core.wire import (
    Claim,
    CodecError,
    Frame,
    Heartbeat,
    Leave,
    Message,
    Warn,
    decode,
    encode,
    seq_seed,
)

KEY = b"k" * 32
OLD = b"o" * 32

MESSAGES: list[Message] = [
    Heartbeat(function=3, epoch=7, role=1, health=0),
    Heartbeat(function=0, epoch=0, role=2, health=2),
    Warn(suspect=2, function=2, epoch=5),
    Warn(suspect=2, function=2, epoch=5, belief=13),  # a doubt (DESIGN "Detection")
    Claim(failed=2, function=2, epoch=6),
    Leave(function=4, epoch=1, reason=int(wire.LeaveReason.FAULT)),
]


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
@pytest.mark.parametrize("key", [None, KEY], ids=["unsigned", "signed"])
def test_round_trip(msg: Message, key: bytes | None) -> None:
    frame = Frame(swarm_id=1543, sender=65535, seq=wire.SEQ_MAX, msg=msg)
    data = encode(frame, key)
    assert decode(data, (key,) if key else ()) == frame


def test_signed_heartbeat_fits_24_bytes() -> None:
    frame = Frame(0xFFFF, 0xFFFF, wire.SEQ_MAX, Heartbeat(127, 0xFFFF, 4, 2))
    assert len(encode(frame, KEY)) == 23  # a swarm of < 128 functions: one slot byte
    assert len(encode(frame)) == len(encode(frame, KEY)) - wire.TAG_LEN
    big = Frame(0xFFFF, 0xFFFF, wire.SEQ_MAX, Heartbeat(0xFFFF, 0xFFFF, 4, 2))
    assert len(encode(big, KEY)) == 25  # the largest swarm: a three-byte slot


@pytest.mark.parametrize(
    ("slot", "size"),
    [(0, 1), (1, 1), (0x7F, 1), (0x80, 2), (0xFF, 2), (0x100, 2), (0x7EFF, 2), (0x7F00, 3),
     (0xFFFE, 3), (0xFFFF, 3)],
)
def test_slot_field_boundaries(slot: int, size: int) -> None:
    assert wire.slot_size(slot) == size == len(wire.encode_slot(slot))
    for msg in (Heartbeat(slot, 1, 1, 0), Warn(9, slot, 1), Claim(9, slot, 2), Leave(slot, 1, 0)):
        data = encode(Frame(1, 2, 3, msg), KEY)
        assert decode(data, (KEY,)).msg == msg
        peeked = wire.peek(data)
        assert peeked is not None and (peeked.sender, peeked.slot) == (2, slot)


@pytest.mark.parametrize("field", [b"\x80\x05", b"\x80\x7f", b"\xff\x7e\xff", b"\xff\x00\x05"])
def test_overlong_slot_forms_are_malformed(field: bytes) -> None:
    """Only the shortest form is valid, so no slot has two encodings (a signed frame
    cannot be re-encoded into a different one that still means the same)."""
    head = encode(Frame(1, 2, 3, Heartbeat(5, 1, 1, 0)))[:wire.HEADER_LEN]
    data = head + field + b"\x00\x01\x01"
    with pytest.raises(CodecError) as info:
        decode(data)
    assert info.value.reason is DropReason.MALFORMED
    assert wire.peek(data) is None


@given(st.binary(max_size=40))
def test_peek_is_total(data: bytes) -> None:
    p = wire.peek(data)
    try:
        frame = decode(data)
    except CodecError:
        return
    assert p is not None and (p.swarm_id, p.sender, p.slot) == (
        frame.swarm_id, frame.sender, frame.msg.function)


def test_every_message_type_is_distinct_on_the_wire() -> None:
    types = {encode(Frame(1, 1, 1, m))[0] & 0x07 for m in MESSAGES}
    # CERT and REFUTE exist only in per-robot mode (tests/test_convergence.py).
    assert types == {t.value for t in wire.MsgType
                     if t not in (wire.MsgType.CERT, wire.MsgType.REFUTE)}


# Slots near the field's boundaries as often as anywhere else.
slots = st.one_of(st.integers(0, 0xFFFF), st.sampled_from([0, 0x7F, 0x80, 0x7EFF, 0x7F00, 0xFFFF]))
frames = st.builds(
    Frame,
    swarm_id=st.integers(0, 0xFFFF),
    sender=st.integers(0, 0xFFFF),
    seq=st.integers(0, wire.SEQ_MAX),
    msg=st.one_of(
        st.builds(Heartbeat, slots, st.integers(0, 0xFFFF), st.integers(0, 15),
                  st.integers(0, 15)),
        st.builds(Warn, st.integers(0, 0xFFFF), slots, st.integers(0, 0xFFFF),
                  st.integers(0, 255)),
        st.builds(Claim, st.integers(0, 0xFFFF), slots, st.integers(0, 0xFFFF)),
        st.builds(Leave, slots, st.integers(0, 0xFFFF), st.integers(0, 255)),
    ),
)


@given(frames, st.booleans())
def test_round_trip_property(frame: Frame, signed: bool) -> None:
    key = KEY if signed else None
    assert decode(encode(frame, key), (KEY,) if signed else ()) == frame


@given(st.binary(max_size=64), st.booleans())
def test_garbage_raises_only_codec_error(data: bytes, keyed: bool) -> None:
    wire.peek(data)  # total too: returns, never raises
    try:
        decode(data, (KEY,) if keyed else ())
    except CodecError as exc:
        assert exc.reason in {DropReason.MALFORMED, DropReason.VERSION, DropReason.AUTH}


@given(frames, st.integers(0, 24), st.integers(0, 255))
def test_flipped_byte_never_verifies_as_another_frame(frame: Frame, pos: int, xor: int) -> None:
    data = bytearray(encode(frame, KEY))
    pos %= len(data)
    data[pos] ^= xor or 1
    with pytest.raises(CodecError):
        decode(bytes(data), (KEY,))


MALFORMED, VERSION, AUTH = DropReason.MALFORMED, DropReason.VERSION, DropReason.AUTH


def _heartbeat(key: bytes | None = None) -> bytes:
    return encode(Frame(1, 2, 3, Heartbeat(1, 0, 1, 0)), key)


@pytest.mark.parametrize(
    ("data", "keys", "reason"),
    [
        (b"", (), MALFORMED),
        (_heartbeat()[:-1], (), MALFORMED),
        (_heartbeat() + b"\0", (), MALFORMED),
        (bytes([0x10 | 0x07]) + _heartbeat()[1:], (), MALFORMED),  # type 7 is no type
        (bytes([0x10]) + _heartbeat()[1:], (), MALFORMED),  # type 0 is no type
        (bytes([0x21]) + _heartbeat()[1:], (), VERSION),
        (bytes([0x01]) + _heartbeat()[1:], (), VERSION),
        (_heartbeat(), (KEY,), AUTH),  # unsigned on a keyed swarm
        (_heartbeat(KEY), (), AUTH),  # signed but no key to verify with
        (_heartbeat(KEY), (OLD,), AUTH),  # wrong key
        (_heartbeat(KEY)[:-1] + bytes([_heartbeat(KEY)[-1] ^ 1]), (KEY,), AUTH),
    ],
    ids=["empty", "short", "long", "type7", "type0", "v2", "v0", "unsigned-on-keyed",
         "signed-no-key", "wrong-key", "bad-tag"],
)
def test_rejections_name_their_reason(data: bytes, keys: tuple[bytes, ...],
                                      reason: DropReason) -> None:
    with pytest.raises(CodecError) as info:
        decode(data, keys)
    # The drop counter itself, not a name to be looked up (DESIGN section 2).
    assert info.value.reason is reason


def test_key_rotation_accepts_old_and_new() -> None:
    frame = Frame(1, 2, 3, Warn(4, 1, 0))
    for signer in (KEY, OLD):
        assert decode(encode(frame, signer), (KEY, OLD)) == frame
    with pytest.raises(CodecError):
        decode(encode(frame, OLD), (KEY,))


@pytest.mark.parametrize(
    "frame",
    [
        Frame(1, 1, wire.SEQ_MAX + 1, Heartbeat(1, 0, 1, 0)),
        Frame(1, 1, -1, Heartbeat(1, 0, 1, 0)),
        Frame(0x10000, 1, 1, Heartbeat(1, 0, 1, 0)),
        Frame(1, 1, 1, Heartbeat(0x10000, 0, 1, 0)),
        Frame(1, 1, 1, Claim(1, -1, 0)),
        Frame(1, 1, 1, Warn(0x10000, 1, 0)),
        Frame(1, 1, 1, Warn(1, 1, 0, belief=256)),
        Frame(1, 1, 1, Warn(1, 1, 0, belief=-1)),
    ],
)
def test_encode_refuses_out_of_range_fields(frame: Frame) -> None:
    with pytest.raises(ValueError):
        encode(frame)


@pytest.mark.parametrize("key", [None, KEY], ids=["unsigned", "shared key"])
def test_a_warning_carries_its_belief_byte(key: bytes | None) -> None:
    # DESIGN "Detection": WARN = suspect (2), slot, epoch (2), belief (1). A WARN without
    # the byte (the body before beliefs) is malformed, not read as some other belief.
    keys = (KEY,) if key else ()
    data = encode(Frame(7, 1, 9, Warn(2, 3, 4, belief=21)), key)
    assert len(data) == wire.HEADER_LEN + 2 + 1 + 2 + 1 + (wire.TAG_LEN if key else 0)
    assert decode(data, keys).msg == Warn(2, 3, 4, belief=21)
    short = data[:wire.HEADER_LEN + 5]
    if key:
        short += wire.tag(key, short)
    with pytest.raises(CodecError) as info:
        decode(short, keys)
    assert info.value.reason == "malformed"


def test_seq_seed_rises_with_time_and_clamps() -> None:
    assert seq_seed(1_700_000_000.0) < seq_seed(1_700_000_000.001)
    assert seq_seed(0.0) == 0
    assert seq_seed(1e30) == wire.SEQ_MAX
