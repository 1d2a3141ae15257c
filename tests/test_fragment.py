"""Fragments (transport/fragment.py): split and reassembly, hostile input, and per-robot
signed frames crossing a 73-byte DigiMesh medium and a 64-byte serial link."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_runtime import wait_until
from test_serial_transport import raw_pty

from sim.xbee_emu import Medium
from swarmd.base.identity import throwaway_identities
from swarmd.core import wire
from swarmd.transport import fragment, framing
from swarmd.transport.base import ChannelEvent, SendError
from swarmd.transport.fragment import (
    HEADER_LEN,
    MAX_FRAGMENTS,
    MAX_FRAME,
    MIN_LIMIT,
    FragmentError,
    Reassembler,
    split,
)
from swarmd.transport.serial import SerialTransport
from swarmd.transport.xbee import XBeeTransport

SWARM = 0x607
IDS = throwaway_identities([3, 4])
"""Real Ed25519 keys of robots 3 and 4; one verifier knows both."""


def _frame(size: int, sender: int = 0x0102) -> bytes:
    """A stand-in swarmd frame: version 1 in byte 0, `sender` at bytes 3-4."""
    head = bytes([0x12, 0x06, 0x07]) + sender.to_bytes(2, "big")
    return (head + bytes(i % 251 for i in range(size)))[:size] if size >= 5 else head[:size]


def _signed_frames() -> list[bytes]:
    """A per-robot signed WARN, CLAIM and the CERT relaying the WARN (80, 80, 92 B)."""
    ids = IDS
    warn = wire.encode(wire.Frame(SWARM, 3, 1000, wire.Warn(suspect=1, function=1, epoch=0)),
                       signer=ids[3].signer)
    claim = wire.encode(wire.Frame(SWARM, 4, 2000, wire.Claim(failed=1, function=1, epoch=1)),
                        signer=ids[4].signer)
    inner = wire.decode(warn, verifier=ids[3].verifier, inner=True)
    cert = wire.encode(wire.Frame(SWARM, 4, 2001, wire.Cert(1, inner, warn)),
                       signer=ids[4].signer)
    return [warn, claim, cert]


def _verifier() -> Any:
    return IDS[3].verifier


# -- split ------------------------------------------------------------------------------
def test_a_frame_that_fits_goes_out_unchanged() -> None:
    f = _frame(73)
    assert split(f, 73, 5) == [f]


def test_split_layout_and_sizes() -> None:
    f = _frame(92, sender=0xBEEF)
    parts = split(f, 73, 0x1234)
    assert [len(p) for p in parts] == [52, 52]
    for i, p in enumerate(parts):
        assert p[0] == fragment.MARKER and p[0] >> 4 != wire.VERSION
        assert p[1:3] == b"\xbe\xef"  # the frame's own sender
        assert p[3:5] == b"\x12\x34"
        assert p[5] == (i << 4 | 2)
    assert b"".join(p[HEADER_LEN:] for p in parts) == f


def test_split_refuses_what_cannot_be_carried() -> None:
    room = MIN_LIMIT - HEADER_LEN
    assert len(split(_frame(room * MAX_FRAGMENTS), MIN_LIMIT, 0)) == MAX_FRAGMENTS
    with pytest.raises(FragmentError):
        split(_frame(room * MAX_FRAGMENTS + 1), MIN_LIMIT, 0)
    with pytest.raises(FragmentError):
        split(_frame(MAX_FRAME + 1), 200, 0)  # 3 fragments, but over MAX_FRAME
    with pytest.raises(FragmentError):
        split(_frame(20), HEADER_LEN, 0)


# -- reassembly -------------------------------------------------------------------------
def test_non_fragments_pass_through() -> None:
    r = Reassembler()
    for d in (b"", b"\x11", _frame(23), b"\xf2garbage"):
        assert r.feed(d, 0.0) == d
    assert not r.drops


def test_bad_fragments_are_counted_by_reason() -> None:
    r = Reassembler()
    head = bytes([fragment.MARKER, 1, 2, 0, 9])
    assert r.feed(head, 0.0) is None  # header only
    assert r.feed(head + b"\x01x", 0.0) is None  # count 1
    assert r.feed(head + b"\x09x", 0.0) is None  # count 9 > MAX_FRAGMENTS
    assert r.feed(head + b"\x22x", 0.0) is None  # index 2 of 2
    parts = split(_frame(92), 73, 9)
    assert r.feed(parts[0], 0.0) is None
    assert r.feed(parts[0], 0.1) is None  # duplicate
    assert r.feed(parts[1][:5] + b"\x13" + parts[1][6:], 0.1) is None  # count 3 vs 2
    assert dict(r.drops) == {"short": 1, "bad_count": 2, "bad_index": 1, "duplicate": 1,
                             "inconsistent": 1}
    assert r.feed(parts[1], 0.2) == _frame(92)


def test_partial_messages_expire_and_are_evicted() -> None:
    r = Reassembler(max_partial=4, expiry=2.0, max_per_sender=8)  # one sender
    firsts = [split(_frame(92), 73, i)[0] for i in range(6)]
    for i, p in enumerate(firsts):
        r.feed(p, 0.1 * i)
    assert len(r) == 4 and r.drops["evicted"] == 2
    late = split(_frame(92), 73, 5)[1]
    assert r.feed(late, 2.4) == _frame(92)  # started at 0.5: still in time
    assert r.feed(_frame(23), 2.45) == _frame(23)
    r.feed(b"\xf1\x00\x00\x00\x00\x02x", 2.45)  # any fragment runs the expiry
    assert r.drops["expired"] == 3 and len(r) == 1


def test_a_fragment_whose_sender_differs_from_the_frame_is_dropped() -> None:
    parts = split(_frame(92, sender=7), 73, 1)
    forged = [p[:1] + b"\x00\x08" + p[3:] for p in parts]
    r = Reassembler()
    assert [r.feed(p, 0.0) for p in forged] == [None, None]
    assert r.drops["sender_mismatch"] == 1


def test_reassembled_signed_frames_still_verify_and_a_forged_piece_spoils_one() -> None:
    ver = _verifier()
    warn, claim, cert = _signed_frames()
    assert (len(warn), len(claim), len(cert)) == (81, 80, 93)  # WARN: its belief byte
    r = Reassembler()
    for f in (warn, claim, cert):
        out = [r.feed(p, 0.0) for p in split(f, 73, 11)]
        assert out[-1] == f
        wire.decode(out[-1], verifier=ver)
        r = Reassembler()
    # A forged first piece of the WARN's message: the frame fails its signature.
    parts = split(warn, 73, 12)
    forged = parts[0][:20] + bytes([parts[0][20] ^ 1]) + parts[0][21:]  # a body byte
    r = Reassembler()
    assert r.feed(forged, 0.0) is None
    spoilt = r.feed(parts[1], 0.0)
    assert spoilt is not None and spoilt != warn
    with pytest.raises(wire.CodecError):
        wire.decode(spoilt, verifier=ver)
    assert r.feed(parts[0], 0.0) is None and r.drops["duplicate"] == 1
    # The next message of the same sender is untouched.
    assert [r.feed(p, 0.0) for p in split(warn, 73, 13)][-1] == warn


@settings(max_examples=300)
@given(data=st.data(), size=st.integers(5, MAX_FRAME), limit=st.integers(MIN_LIMIT, 200),
       msg_id=st.integers(0, 0xFFFF))
def test_any_order_and_duplication_yields_the_frame_exactly_once(
        data: st.DataObject, size: int, limit: int, msg_id: int) -> None:
    frame = _frame(size, sender=data.draw(st.integers(0, 0xFFFF)))
    try:
        parts = split(frame, limit, msg_id)
    except FragmentError:
        assert -(-size // (limit - HEADER_LEN)) > MAX_FRAGMENTS
        return
    assert all(len(p) <= limit for p in parts)
    if len(parts) == 1:
        assert parts == [frame]
        return
    sent = data.draw(st.lists(st.sampled_from(parts), max_size=3 * len(parts)))
    sent = data.draw(st.permutations(sent + parts))
    r = Reassembler()
    got = [out for p in sent if (out := r.feed(p, 0.0)) is not None]
    assert got == [frame]
    assert len(r) == 0


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=120), max_size=200),
       st.lists(st.floats(0, 1.0), min_size=1, max_size=200))
def test_garbage_never_raises_and_memory_stays_bounded(
        datagrams: list[bytes], steps: list[float]) -> None:
    r = Reassembler(max_partial=8)
    now = 0.0
    for i, d in enumerate(datagrams):
        now += steps[i % len(steps)]
        d = b"\xf1" + d[1:] if i % 2 else d  # half of them look like fragments
        out = r.feed(d, now)
        assert out is None or out == d or len(out) <= MAX_FRAME
        assert len(r) <= 8
        assert len(r._done) <= 16
        assert all(p.size <= MAX_FRAME for p in r._partial.values())


# -- end to end -------------------------------------------------------------------------
class Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.events: list[ChannelEvent] = []

    def frame(self, data: bytes) -> None:
        self.frames.append(data)

    def event(self, event: ChannelEvent) -> None:
        self.events.append(event)


async def test_signed_frames_cross_a_digimesh_medium(tmp_path: Path) -> None:
    frames = _signed_frames()
    with Medium(2, protocol="digimesh", directory=tmp_path) as medium:
        tx = XBeeTransport(port=medium.path(1), protocol="digimesh")
        rx = XBeeTransport(port=medium.path(2), protocol="digimesh")
        a, b = Sink(), Sink()
        await tx.start(a.frame, a.event)
        await rx.start(b.frame, b.event)
        try:
            assert tx.max_payload == 73
            heartbeat = _frame(23)
            for f in (*frames, heartbeat):
                tx.send(f)
            await wait_until(lambda: len(b.frames) == 4, 10.0, "the four frames")
            assert sorted(b.frames) == sorted([*frames, heartbeat])
            ver = _verifier()
            for f in (g for g in b.frames if g != heartbeat):
                assert wire.decode(f, verifier=ver).sender in (3, 4)
            await wait_until(lambda: tx.counters["delivered"] == 7,  # 2 + 2 + 2 + 1
                             10.0, "seven deliveries")
            assert tx.counters["fragmented"] == 3
            assert not [e for e in a.events if isinstance(e, SendError)]
        finally:
            await tx.close()
            await rx.close()


def _pty_pair(tmp_path: Path) -> tuple[Path, Path, list[int]]:
    """Two pseudo-terminals whose masters a test copies into each other: a radio link."""
    link_a, link_b = tmp_path / "a", tmp_path / "b"
    return link_a, link_b, [*raw_pty(link_a), *raw_pty(link_b)]


async def test_signed_frames_cross_a_64_byte_serial_link(tmp_path: Path) -> None:
    frames = _signed_frames()
    link_a, link_b, fds = _pty_pair(tmp_path)
    master_a, master_b = fds[0], fds[2]
    os.set_blocking(master_a, False)
    tx = SerialTransport(port=str(link_a))  # default 64 B, as on an XBee in AP=0
    rx = SerialTransport(port=str(link_b))
    a, b = Sink(), Sink()
    await tx.start(a.frame, a.event)
    await rx.start(b.frame, b.event)
    written: list[int] = []

    def relay() -> bool:  # the air: what A's radio sends comes out of B's
        with contextlib.suppress(BlockingIOError):
            chunk = os.read(master_a, 4096)
            written.append(len(chunk))
            os.write(master_b, chunk)
        return len(b.frames) == len(frames)

    try:
        assert tx.max_payload == 64
        for f in frames:
            tx.send(f)
        await wait_until(relay, 10.0, "the relayed frames")
        assert b.frames == frames
        ver = _verifier()
        assert [wire.decode(f, verifier=ver).sender for f in b.frames] == [3, 4, 4]
        assert tx.counters["fragmented"] == 3
        assert rx.counters["received"] == 6  # datagrams: 2 fragments each
        os.write(master_b, framing.encode(b"\xf1\x00\x03\x00\x01\x01x"))  # count 1
        await wait_until(lambda: rx.counters["fragment_drop:bad_count"] == 1, 10.0,
                         "the bad-count drop")
        assert b.frames == frames
    finally:
        await tx.close()
        await rx.close()
        for fd in fds:
            os.close(fd)
