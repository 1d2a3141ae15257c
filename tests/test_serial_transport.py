"""SerialTransport on pseudo-terminals: framed frames out, good frames in, outages."""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import tty
from pathlib import Path
from typing import Any

from swarmd.transport import framing
from swarmd.transport.base import ChannelEvent
from swarmd.transport.serial import SerialTransport


class Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.events: list[str] = []

    def frame(self, data: bytes) -> None:
        self.frames.append(data)

    def event(self, event: ChannelEvent) -> None:
        self.events.append(event.condition)


def raw_pty(link: Path) -> tuple[int, int]:
    """A raw pseudo-terminal whose slave `link` names (the radio's serial port): the
    (master, slave) fds; the test plays the radio on the master."""
    master, slave = os.openpty()
    tty.setraw(slave)
    tmp = link.with_suffix(".tmp")
    tmp.symlink_to(os.ttyname(slave))
    tmp.replace(link)
    return master, slave


async def _until(cond: Any, timeout: float = 5.0) -> None:
    async def loop() -> None:
        while not cond():
            await asyncio.sleep(0.01)
    await asyncio.wait_for(loop(), timeout)


async def test_noisy_split_stream_yields_exactly_the_good_frames(tmp_path: Path) -> None:
    link = tmp_path / "radio"
    master, slave = raw_pty(link)
    tr = SerialTransport(port=str(link))
    sink = Sink()
    await tr.start(sink.frame, sink.event)
    try:
        rng = random.Random(5)
        frames = [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
                  for _ in range(40)]
        stream = b"".join(bytes(rng.randrange(256) for _ in range(rng.randrange(0, 9)))
                          + framing.encode(f) for f in frames)
        i = 0
        while i < len(stream):  # the radio hands bytes over in odd-sized pieces
            n = rng.choice((1, 3, 17, 100))
            os.write(master, stream[i : i + n])
            i += n
        await _until(lambda: len(sink.frames) == len(frames))
        assert sink.frames == frames
    finally:
        await tr.close()
        os.close(master)
        os.close(slave)


async def test_send_writes_framed_bytes_and_refuses_what_cannot_be_split(
        tmp_path: Path) -> None:
    link = tmp_path / "radio"
    master, slave = raw_pty(link)
    tr = SerialTransport(port=str(link), max_payload=32)
    sink = Sink()
    await tr.start(sink.frame, sink.event)
    try:
        tr.send(b"\x00hello\x00")
        tr.send(b"x" * 209)  # more than 8 fragments of 32 - 6 B (fragment.py)
        assert sink.events == ["transport_up", "send_error"]
        assert tr.counters["send_error:oversize"] == 1
        os.set_blocking(master, False)
        got = b""
        dec = framing.FrameDecoder()
        frames: list[bytes] = []

        def more() -> bool:
            nonlocal got
            with contextlib.suppress(BlockingIOError):
                frames.extend(dec.feed(os.read(master, 100)))
            return bool(frames)

        await _until(more)
        assert frames == [b"\x00hello\x00"]
    finally:
        await tr.close()
        os.close(master)
        os.close(slave)


async def test_lost_port_is_reported_and_reopened(tmp_path: Path) -> None:
    link = tmp_path / "radio"
    master, slave = raw_pty(link)
    tr = SerialTransport(port=str(link), reopen_min=0.05, reopen_max=0.1)
    sink = Sink()
    await tr.start(sink.frame, sink.event)
    try:
        os.close(master)  # the radio is pulled: reads fail
        os.close(slave)
        link.unlink()
        await _until(lambda: "transport_down" in sink.events)
        tr.send(b"x")
        assert tr.counters["send_error:down"] == 1
        master, slave = raw_pty(link)
        await _until(lambda: sink.events.count("transport_up") == 2)
        os.write(master, framing.encode(b"back"))
        await _until(lambda: sink.frames == [b"back"])
    finally:
        await tr.close()
        os.close(master)
        os.close(slave)


async def test_serial_transports_over_transparent_emulated_radios(tmp_path: Path) -> None:
    from sim.xbee_emu import Medium

    with Medium(3, directory=tmp_path, transparent=True) as medium:
        sinks = {n: Sink() for n in (1, 2, 3)}
        trs = {n: SerialTransport(port=medium.path(n)) for n in (1, 2, 3)}
        for n, tr in trs.items():
            await tr.start(sinks[n].frame, sinks[n].event)
        try:
            trs[1].send(b"from one\x00")
            trs[3].send(b"from three")
            await _until(lambda: len(sinks[2].frames) == 2)
            assert sorted(sinks[2].frames) == [b"from one\x00", b"from three"]
            assert sinks[1].frames == [b"from three"]
        finally:
            for tr in trs.values():
                await tr.close()
