"""Wire codec (DESIGN section 2, "Messages"): round trips, size, garbage, auth, rotation."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmd.core import wire
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
    frame = Frame(0xFFFF, 0xFFFF, wire.SEQ_MAX, Heartbeat(255, 0xFFFF, 4, 2))
    assert len(encode(frame, KEY)) <= 24
    assert len(encode(frame)) == len(encode(frame, KEY)) - wire.TAG_LEN


def test_every_message_type_is_distinct_on_the_wire() -> None:
    types = {encode(Frame(1, 1, 1, m))[0] & 0x07 for m in MESSAGES}
    assert types == {t.value for t in wire.MsgType}


frames = st.builds(
    Frame,
    swarm_id=st.integers(0, 0xFFFF),
    sender=st.integers(0, 0xFFFF),
    seq=st.integers(0, wire.SEQ_MAX),
    msg=st.one_of(
        st.builds(Heartbeat, st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 15),
                  st.integers(0, 15)),
        st.builds(Warn, st.integers(0, 0xFFFF), st.integers(0, 255), st.integers(0, 0xFFFF)),
        st.builds(Claim, st.integers(0, 0xFFFF), st.integers(0, 255), st.integers(0, 0xFFFF)),
        st.builds(Leave, st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 255)),
    ),
)


@given(frames, st.booleans())
def test_round_trip_property(frame: Frame, signed: bool) -> None:
    key = KEY if signed else None
    assert decode(encode(frame, key), (KEY,) if signed else ()) == frame


@given(st.binary(max_size=64), st.booleans())
def test_garbage_raises_only_codec_error(data: bytes, keyed: bool) -> None:
    try:
        decode(data, (KEY,) if keyed else ())
    except CodecError as exc:
        assert exc.reason in {"malformed", "version", "auth"}


@given(frames, st.integers(0, 22), st.integers(0, 255))
def test_flipped_byte_never_verifies_as_another_frame(frame: Frame, pos: int, xor: int) -> None:
    data = bytearray(encode(frame, KEY))
    pos %= len(data)
    data[pos] ^= xor or 1
    with pytest.raises(CodecError):
        decode(bytes(data), (KEY,))


def _heartbeat(key: bytes | None = None) -> bytes:
    return encode(Frame(1, 2, 3, Heartbeat(1, 0, 1, 0)), key)


@pytest.mark.parametrize(
    ("data", "keys", "reason"),
    [
        (b"", (), "malformed"),
        (_heartbeat()[:-1], (), "malformed"),
        (_heartbeat() + b"\0", (), "malformed"),
        (bytes([0x10 | 0x07]) + _heartbeat()[1:], (), "malformed"),  # type 7 is no type
        (bytes([0x10]) + _heartbeat()[1:], (), "malformed"),  # type 0 is no type
        (bytes([0x21]) + _heartbeat()[1:], (), "version"),
        (bytes([0x01]) + _heartbeat()[1:], (), "version"),
        (_heartbeat(), (KEY,), "auth"),  # unsigned on a keyed swarm
        (_heartbeat(KEY), (), "auth"),  # signed but no key to verify with
        (_heartbeat(KEY), (OLD,), "auth"),  # wrong key
        (_heartbeat(KEY)[:-1] + bytes([_heartbeat(KEY)[-1] ^ 1]), (KEY,), "auth"),
    ],
    ids=["empty", "short", "long", "type7", "type0", "v2", "v0", "unsigned-on-keyed",
         "signed-no-key", "wrong-key", "bad-tag"],
)
def test_rejections_name_their_reason(data: bytes, keys: tuple[bytes, ...], reason: str) -> None:
    with pytest.raises(CodecError) as info:
        decode(data, keys)
    assert info.value.reason == reason


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
        Frame(1, 1, 1, Heartbeat(256, 0, 1, 0)),
        Frame(1, 1, 1, Warn(0x10000, 1, 0)),
    ],
)
def test_encode_refuses_out_of_range_fields(frame: Frame) -> None:
    with pytest.raises(ValueError):
        encode(frame)


def test_seq_seed_rises_with_time_and_clamps() -> None:
    assert seq_seed(1_700_000_000.0) < seq_seed(1_700_000_000.001)
    assert seq_seed(0.0) == 0
    assert seq_seed(1e30) == wire.SEQ_MAX
