"""COBS + CRC framing of byte-stream radios."""

from __future__ import annotations

import random

from hypothesis import given
from hypothesis import strategies as st

from swarmd.transport import framing

FRAMES = [
    b"\x11" * 23,  # a signed heartbeat's size
    b"\x00" * 10,  # all delimiters before COBS
    bytes(range(256)),  # every byte value, crosses the 254-byte COBS block
    b"\xff" * 254 + b"\x00" + b"\x01",  # a full block followed by a zero
    b"x",
    bytes([0x7E, 0x7D, 0x11, 0x13]) * 5,
]


def _stream_with_noise(seed: int) -> bytes:
    rng = random.Random(seed)
    out = bytearray()
    for frame in FRAMES:
        out += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
        out += framing.encode(frame)
    out += bytes(rng.randrange(256) for _ in range(7))
    return bytes(out)


def test_cobs_output_has_no_zero_and_round_trips() -> None:
    for frame in FRAMES:
        enc = framing.cobs_encode(frame)
        assert 0 not in enc
        assert framing.cobs_decode(enc) == frame


@given(st.binary(max_size=700))
def test_cobs_round_trip_any_bytes(data: bytes) -> None:
    assert framing.cobs_decode(framing.cobs_encode(data)) == data


def test_overhead_matches_encode() -> None:
    for frame in FRAMES:
        assert len(framing.encode(frame)) == len(frame) + framing.overhead(len(frame))


def test_stream_cut_at_every_offset_with_noise_yields_exactly_the_good_frames() -> None:
    stream = _stream_with_noise(7)
    for cut in range(len(stream) + 1):
        dec = framing.FrameDecoder()
        got = dec.feed(stream[:cut]) + dec.feed(stream[cut:])
        assert got == FRAMES, f"cut at {cut}"


def test_stream_fed_byte_by_byte_and_in_random_merges() -> None:
    for seed in range(20):
        stream = _stream_with_noise(seed)
        rng = random.Random(seed)
        dec = framing.FrameDecoder()
        got: list[bytes] = []
        i = 0
        while i < len(stream):
            n = rng.choice((1, 1, 2, 5, 64, 500))
            got += dec.feed(stream[i : i + n])
            i += n
        assert got == FRAMES


def test_corrupted_frame_is_dropped_and_counted_neighbours_survive() -> None:
    encoded = [framing.encode(f) for f in FRAMES]
    bad = bytearray(encoded[2])
    bad[40] ^= 0x5A  # inside the body of the 256-byte frame
    encoded[2] = bytes(bad)
    dec = framing.FrameDecoder()
    got = dec.feed(b"".join(encoded))
    assert got == FRAMES[:2] + FRAMES[3:]
    assert sum(dec.drops.values()) >= 1


def test_truncated_frame_then_good_frame() -> None:
    first = framing.encode(b"hello world")
    dec = framing.FrameDecoder()
    got = dec.feed(first[:-5] + framing.encode(b"second"))
    assert got == [b"second"]
    assert dec.drops["crc"] + dec.drops["cobs"] + dec.drops["short"] == 1


def test_overlong_run_without_delimiter_is_skipped() -> None:
    dec = framing.FrameDecoder(max_frame=32)
    got = dec.feed(b"\x05" * 200)
    got += dec.feed(b"\x05" * 10 + framing.encode(b"ok"))
    assert got == [b"ok"]
    assert dec.drops["overlong"] == 1


@given(st.lists(st.binary(min_size=1, max_size=80), max_size=8), st.binary(max_size=40))
def test_any_frames_any_noise_between(frames: list[bytes], noise: bytes) -> None:
    stream = b"".join(noise + framing.encode(f) for f in frames) + noise
    dec = framing.FrameDecoder()
    assert dec.feed(stream) == frames
