"""XBeeTransport against emulated radios opened by the real digi-xbee library."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any, TypeVar

import pytest

from sim.xbee_emu import Medium
from swarmd.transport.base import ChannelDown, ChannelEvent, SendError, SendFailure
from swarmd.transport.xbee import RadioMismatch, XBeeTransport
from swarmd.transport.xbee_device import DeviceThread

NASTY = bytes([0x7E, 0x7D, 0x11, 0x13]) * 25
E = TypeVar("E", bound=ChannelEvent)


class Sink:
    """Frames and events one transport handed to the runtime."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.events: list[ChannelEvent] = []
        self.changed = asyncio.Event()

    def frame(self, data: bytes) -> None:
        self.frames.append(data)
        self.changed.set()

    def event(self, event: ChannelEvent) -> None:
        self.events.append(event)
        self.changed.set()

    def names(self) -> list[str]:
        return [e.condition for e in self.events]

    def last(self, kind: type[E]) -> E:
        """The latest event of class `kind` (the test waited for one)."""
        return [e for e in self.events if isinstance(e, kind)][-1]

    async def until(self, cond: Any, timeout: float = 5.0) -> None:
        async def loop() -> None:
            while not cond():
                self.changed.clear()
                # Counters change without a callback: look again every 20 ms too.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self.changed.wait(), 0.02)
        await asyncio.wait_for(loop(), timeout)


async def test_api_mode_2_escaping_end_to_end(tmp_path: Path) -> None:
    with Medium(2, api_mode=2, directory=tmp_path) as medium:
        tx = XBeeTransport(port=medium.path(1), api_mode=2, pan_id=0x607, role="coordinator")
        rx = XBeeTransport(port=medium.path(2), api_mode=2, pan_id=0x607, role="router")
        a, b = Sink(), Sink()
        await tx.start(a.frame, a.event)
        await rx.start(b.frame, b.event)
        try:
            assert tx.max_payload == 100
            frames = [NASTY[i:] for i in range(10)]  # 91..100 bytes of escapes
            for f in frames:
                tx.send(f)
            await b.until(lambda: len(b.frames) == len(frames))
            assert sorted(b.frames) == sorted(frames)  # callbacks may reorder
            await a.until(lambda: tx.counters["delivered"] == len(frames))
            # 802.15.4: the transport moved the radio to 64-bit source addressing.
            assert medium.radios[1].params["MY"] == b"\xff\xfe"
        finally:
            await tx.close()
            await rx.close()


async def test_config_mismatch_names_every_difference(tmp_path: Path) -> None:
    with Medium(1, protocol="zigbee", directory=tmp_path) as medium:
        tr = XBeeTransport(port=medium.path(1), protocol="802.15.4", api_mode=2,
                           pan_id=0x1234, channel=0x0F, role="router")
        with pytest.raises(RadioMismatch) as info:
            await tr.start(lambda _: None, lambda *_: None)
        text = str(info.value)
        for part in ("protocol: radio zigbee, config 802.15.4", "API mode (AP): radio 1",
                     "PAN id (ID): radio 0x0607, config 0x1234",
                     "channel (CH): radio 0x0C, config 0x0F",
                     "role (CE): radio coordinator, config router"):
            assert part in text
        assert len(info.value.differences) == 5


async def test_oversize_and_in_flight_bound(tmp_path: Path) -> None:
    with Medium(2, protocol="digimesh", directory=tmp_path, delay=0.05) as medium:
        tr = XBeeTransport(port=medium.path(1), protocol="digimesh", max_in_flight=2,
                           send_queue=3)
        sink = Sink()
        await tr.start(sink.frame, sink.event)
        try:
            tr.send(b"x" * 537)  # more than 8 fragments of 73 - 6 B (fragment.py)
            assert SendError("xbee", SendFailure.OVERSIZE, "oversize", size=537,
                             limit=73) in sink.events
            for i in range(10):
                tr.send(bytes([i]) * 10)
                assert len(tr._window.in_flight) <= 2
            # 2 in flight, 3 queued (the newest), 5 dropped oldest-first.
            assert tr.counters["send_error:no_buffer"] == 5
            await sink.until(lambda: tr.counters["delivered"] == 5)
        finally:
            await tr.close()


async def test_unplugged_radio_is_reported_and_recovers(tmp_path: Path) -> None:
    with Medium(2, directory=tmp_path) as medium:
        tx = XBeeTransport(port=medium.path(1), reopen_min=0.05, reopen_max=0.2,
                           watchdog_interval=0.05)
        rx = XBeeTransport(port=medium.path(2), reopen_min=0.05, reopen_max=0.2,
                           watchdog_interval=0.05)
        a, b = Sink(), Sink()
        await tx.start(a.frame, a.event)
        await rx.start(b.frame, b.event)
        try:
            medium.unplug(2)
            await b.until(lambda: "transport_down" in b.names())
            assert not rx.up
            tx.send(b"while down")  # nobody hears it; the sender is fine
            await asyncio.sleep(0.3)  # several failed reopen attempts (back-off)
            assert rx.counters["reopen_failed"] >= 1
            medium.replug(2)  # power-cycled: MY is back to 0 and must be set again
            await b.until(lambda: b.names().count("transport_up") == 2)
            tx.send(b"after")
            await b.until(lambda: b"after" in b.frames)
            assert b"while down" not in b.frames
            assert medium.radios[2].params["MY"] == b"\xff\xfe"
        finally:
            await tx.close()
            await rx.close()


async def test_missing_radio_at_start_keeps_running_and_retries(tmp_path: Path) -> None:
    with Medium(1, directory=tmp_path) as medium:
        medium.unplug(1)
        tr = XBeeTransport(port=medium.path(1), reopen_min=0.05, reopen_max=0.1)
        sink = Sink()
        await tr.start(sink.frame, sink.event)  # does not raise
        try:
            assert sink.names() == ["transport_down"]
            tr.send(b"x")
            assert tr.counters["send_error:down"] == 1
            medium.replug(1)
            await sink.until(lambda: "transport_up" in sink.names())
            assert tr.up
        finally:
            await tr.close()


def emulator_killed(medium: Medium, n: int) -> None:
    """What SIGKILL of `swarmd xbee emulate` does to radio n: the pty master closes and
    nobody removes the symlink (the node stays while our transport holds it open)."""
    with medium._lock:
        port = medium._ports.pop(n)
        medium._selector.unregister(port.master)
        os.close(port.master)
        os.close(port.slave)


async def watched(port: str) -> tuple[XBeeTransport, Sink]:
    """A started transport with a fast watchdog and reopen, and its sink."""
    tr = XBeeTransport(port=port, reopen_min=0.05, reopen_max=0.1, watchdog_interval=0.05)
    sink = Sink()
    await tr.start(sink.frame, sink.event)
    return tr, sink


async def test_hung_up_port_is_reported_without_a_log_flood(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    # Audit reproducer: the emulator SIGKILLed under an idle daemon. digi-xbee's reader
    # logged ~30,000 warnings a second (the daemon's stdout pipe filled, every logging
    # thread blocked, SIGTERM hung) and no transport_down came.
    caplog.set_level(logging.WARNING, logger="digi.xbee.reader")
    with Medium(2, directory=tmp_path) as medium:
        tr, sink = await watched(medium.path(2))
        try:
            emulator_killed(medium, 2)
            await sink.until(lambda: "transport_down" in sink.names())
            assert not tr.up
            assert "hung up" in sink.last(ChannelDown).reason
            assert not [r for r in caplog.records if r.name == "digi.xbee.reader"]
            medium.replug(2)  # a new emulator on the same path
            await sink.until(lambda: sink.names().count("transport_up") == 2)
        finally:
            await asyncio.wait_for(tr.close(), 5)


async def test_hung_up_port_is_noticed_by_the_watchdog_alone(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The POLLHUP check does not depend on digi-xbee's log text: with the reader's
    # signal ignored, the watchdog still reports the port within an interval.
    monkeypatch.setattr(DeviceThread, "_reader_hung_up", lambda self: None)
    with Medium(1, directory=tmp_path) as medium:
        tr, sink = await watched(medium.path(1))
        try:
            emulator_killed(medium, 1)
            await sink.until(lambda: "transport_down" in sink.names())
            assert "hung up (radio or emulator gone?)" in sink.last(ChannelDown).reason
        finally:
            await asyncio.wait_for(tr.close(), 5)


async def test_close_is_bounded_when_the_library_hangs(tmp_path: Path) -> None:
    # digi-xbee's close blocking for good must not hold the daemon's stop (nor the
    # interpreter's exit: the device thread is a daemon thread).
    gate = threading.Event()
    with Medium(1, directory=tmp_path) as medium:
        tr = XBeeTransport(port=medium.path(1), close_timeout=0.2)
        await tr.start(lambda _: None, lambda *_: None)
        assert tr._radio is not None
        dev = tr._radio._device
        real_close = dev.close

        def stuck_close() -> None:
            gate.wait(10)
            real_close()

        dev.close = stuck_close
        device_threads = [t for t in threading.enumerate() if t.name.startswith("xbee-")]
        try:
            await asyncio.wait_for(tr.close(), 5)
            assert tr.counters["close_timeout"] == 1
            assert device_threads and all(t.daemon for t in device_threads)
        finally:
            gate.set()


def test_reader_filter_is_installed_on_open_not_on_import(tmp_path: Path) -> None:
    # Importing swarmd must leave another program's digi-xbee logging alone; opening a
    # port installs the filter, once however many ports open.
    script = (
        "import asyncio, logging, sys\n"
        "from sim.xbee_emu import Medium\n"
        "from swarmd.transport.xbee import XBeeTransport\n"
        "from swarmd.transport.xbee_device import ReaderHangups\n"
        "reader = logging.getLogger('digi.xbee.reader')\n"
        "def ours(): return sum(isinstance(f, ReaderHangups) for f in reader.filters)\n"
        "assert ours() == 0, 'installed at import'\n"
        "async def main():\n"
        "    with Medium(2, directory=sys.argv[1]) as medium:\n"
        "        trs = [XBeeTransport(port=medium.path(n)) for n in (1, 2)]\n"
        "        for tr in trs:\n"
        "            await tr.start(lambda _: None, lambda *_: None)\n"
        "        try:\n"
        "            assert ours() == 1, ours()\n"
        "        finally:\n"
        "            for tr in trs:\n"
        "                await tr.close()\n"
        "asyncio.run(main())\n"
    )
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
