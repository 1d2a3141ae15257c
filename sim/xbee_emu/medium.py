"""Software XBee radios on pseudo-terminals sharing one simulated medium.

Each radio is a pty pair: the emulator keeps the master, the client (digi-xbee, the
serial transport, minicom) opens the slave through a stable symlink such as
`/tmp/swarmd-xbee/robot1`. One thread owns every master and a timer heap:

    UART bytes -> FrameParser -> EmulatedRadio.handle -> replies (after ~2 ms) and
    transmissions -> channel (busy until the frame's airtime has passed) -> receive
    frames on every other radio with the same protocol, PAN id and channel.

Why the details:
- AT replies come ~2 ms after the request, never at once: digi-xbee has a lost wake-up
  race that makes an instant reply wait out its 4 s timeout (docs/radios.md).
- The emulator keeps its own slave fd open so the master never sees a hang-up while no
  client is attached; masters are non-blocking and a full pty buffer drops the frame
  (a real radio's UART buffer overflows the same way).
- `unplug(n)` closes the master and removes the symlink: a client reading the slave
  gets EIO, exactly as when a USB radio is pulled. `replug(n)` makes a new pty at the
  same symlink; the radio has power-cycled, so unsaved (no WR) settings are gone.
- The channel is one shared resource per (protocol, PAN, channel): a transmission
  starts when the previous one ended, so an overloaded swarm queues as on the air.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import heapq
import itertools
import os
import random
import selectors
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from sim.xbee_emu import api
from sim.xbee_emu.radio import (
    REMOTE_NO_RESPONSE,
    TX_OK,
    TX_PAYLOAD_TOO_LARGE,
    UNKNOWN16,
    EmulatedRadio,
    RemoteCommand,
    Reply,
    Transmit,
)
from swarmd.services.budget import airtime

DEFAULT_DIR = "/tmp/swarmd-xbee"
REPLY_DELAY = 0.002


@dataclass
class _Port:
    master: int
    slave: int
    slave_name: str
    parser: api.FrameParser


@dataclass(order=True)
class _Timer:
    at: float
    order: int
    action: Callable[[], None] = field(compare=False)


class Medium:
    """N emulated radios on ptys and the air between them. Use as a context manager or
    call `start()` / `stop()`; `path(n)` is radio n's device (n = 1..N)."""

    def __init__(
        self,
        count: int,
        *,
        protocol: str = "802.15.4",
        api_mode: int = 1,
        directory: str | os.PathLike[str] = DEFAULT_DIR,
        pan_id: int = 0x0607,
        channel: int = 0x0C,
        loss: float = 0.0,
        delay: float = 0.0,
        seed: int | None = None,
        reply_delay: float = REPLY_DELAY,
        transparent: bool = False,
    ) -> None:
        if count < 1:
            raise ValueError("need at least one radio")
        self.directory = Path(directory)
        self.reply_delay = reply_delay
        self.transparent = transparent
        """AP=0 radios: UART bytes go on the air as they come (one read = one RF packet)
        and come out of every other radio's UART raw; no API frames. This is what the
        serial transport is for (the paper's DH/DL broadcast setting)."""
        self.radios: dict[int, EmulatedRadio] = {
            n: EmulatedRadio(n, protocol, api_mode=api_mode, pan_id=pan_id, channel=channel,
                             coordinator=n == 1, loss=loss, delay=delay)
            for n in range(1, count + 1)
        }
        self._rng = random.Random(seed)
        self._ports: dict[int, _Port] = {}
        self._busy_until: dict[tuple[str, bytes, bytes], float] = {}
        self._lock = threading.RLock()

        # The medium's thread, not yet started: its timers, and the selector it waits
        # on with the pipe that wakes it.
        self._timers: list[_Timer] = []
        self._order = itertools.count()
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._selector.register(self._wake_r, selectors.EVENT_READ, 0)

        # Set once running: whether `start` made the directory, what the air carried.
        self._made_dir = False
        self.delivered = 0
        self.lost = 0
        self.uart_overflows = 0

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> Medium:
        self._made_dir = not self.directory.exists()
        self.directory.mkdir(parents=True, exist_ok=True)
        with self._lock:
            for n in self.radios:
                self._plug(n)
        self._thread = threading.Thread(target=self._run, name="xbee-medium", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stopping = True
        self._wake()
        if self._thread is not None:
            self._thread.join(timeout=5)
        with self._lock:
            for n in list(self._ports):
                self._unplug(n)
        self._selector.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self._made_dir:  # what start() made goes, if nobody put anything else in it
            with contextlib.suppress(OSError):
                self.directory.rmdir()

    def __enter__(self) -> Medium:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def path(self, n: int) -> str:
        """The stable device path of radio n (a symlink to its current pty)."""
        return str(self.directory / f"robot{n}")

    # -- faults -------------------------------------------------------------------------
    def unplug(self, n: int) -> None:
        """Pull radio n: its client gets I/O errors, the symlink disappears."""
        with self._lock:
            self._unplug(n)
        self._wake()

    def replug(self, n: int) -> None:
        """Put radio n back (power-cycled) at the same symlink."""
        with self._lock:
            if n in self._ports:
                return
            self.radios[n].power_cycle()
            self._plug(n)
        self._wake()

    def plugged(self, n: int) -> bool:
        return n in self._ports

    def set_loss(self, n: int, loss: float) -> None:
        self.radios[n].loss = loss

    def set_delay(self, n: int, delay: float) -> None:
        self.radios[n].delay = delay

    # -- ptys ---------------------------------------------------------------------------
    def _plug(self, n: int) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: a UART, not a terminal
        os.set_blocking(master, False)
        name = os.ttyname(slave)
        link = Path(self.path(n))
        tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(name)
        tmp.replace(link)  # atomic: a client never sees a missing or half-made link
        radio = self.radios[n]
        self._ports[n] = _Port(master, slave, name, api.FrameParser(radio.current_api_mode))
        self._selector.register(master, selectors.EVENT_READ, n)

    def _unplug(self, n: int) -> None:
        port = self._ports.pop(n, None)
        if port is None:
            return
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(port.master)
        with contextlib.suppress(FileNotFoundError):
            link = Path(self.path(n))
            if link.is_symlink() and os.readlink(link) == port.slave_name:
                link.unlink()
        for fd in (port.master, port.slave):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _wake(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            os.write(self._wake_w, b"x")

    def _write(self, n: int, frame: bytes) -> None:
        port = self._ports.get(n)
        if port is None:
            return
        data = api.encode(frame, self.radios[n].current_api_mode)
        try:
            written = os.write(port.master, data)
        except BlockingIOError:
            written = 0
        except OSError:
            return
        if written < len(data):
            self.uart_overflows += 1

    # -- the thread ---------------------------------------------------------------------
    def _at(self, delay: float, action: Callable[[], None]) -> None:
        heapq.heappush(self._timers, _Timer(time.monotonic() + delay, next(self._order), action))

    def _run(self) -> None:
        while not self._stopping:
            with self._lock:
                timeout = 0.2
                if self._timers:
                    timeout = max(0.0, min(timeout, self._timers[0].at - time.monotonic()))
            try:
                ready = self._selector.select(timeout)
            except (OSError, ValueError):
                ready = []  # an fd closed under us by unplug(); the loop goes on
            with self._lock:
                for key, _ in ready:
                    n = key.data
                    if n == 0:
                        with contextlib.suppress(BlockingIOError, OSError):
                            os.read(self._wake_r, 4096)
                        continue
                    self._read(n)
                now = time.monotonic()
                while self._timers and self._timers[0].at <= now:
                    heapq.heappop(self._timers).action()

    def _read(self, n: int) -> None:
        port = self._ports.get(n)
        if port is None:
            return
        try:
            data = os.read(port.master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:
                return  # no client attached right now
            raise
        radio = self.radios[n]
        if self.transparent:
            self._transparent(radio, data)
            return
        port.parser.api_mode = radio.current_api_mode
        for frame in port.parser.feed(data, time.monotonic()):
            for out in radio.handle(frame):
                match out:
                    case Reply(reply):
                        self._at(self.reply_delay, functools.partial(self._write, n, reply))
                    case Transmit():
                        self._transmit(radio, out)
                    case RemoteCommand():
                        self._remote(radio, out)
            port.parser.api_mode = radio.current_api_mode

    def _transparent(self, radio: EmulatedRadio, data: bytes) -> None:
        for start in range(0, len(data), radio.max_payload):
            packet = data[start : start + radio.max_payload]  # the radio packetises
            now = time.monotonic()
            net = radio.network
            begin = max(now, self._busy_until.get(net, 0.0))
            end = begin + airtime(radio.protocol, len(packet))
            self._busy_until[net] = end
            for m, peer in self.radios.items():
                if m == radio.number or m not in self._ports or peer.network != net:
                    continue
                if self._rng.random() < radio.loss or self._rng.random() < peer.loss:
                    self.lost += 1
                    continue
                self.delivered += 1
                self._at(end - now + radio.delay, functools.partial(self._write_raw, m, packet))

    def _write_raw(self, n: int, data: bytes) -> None:
        port = self._ports.get(n)
        if port is None:
            return
        try:
            written = os.write(port.master, data)
        except (BlockingIOError, OSError):
            written = 0
        if written < len(data):
            self.uart_overflows += 1

    def _transmit(self, radio: EmulatedRadio, request: Transmit) -> None:
        n = radio.number
        if len(request.data) > radio.payload_limit(request):
            refusal = radio.status_frame(request, TX_PAYLOAD_TOO_LARGE)
            if refusal is not None:
                self._at(self.reply_delay, functools.partial(self._write, n, refusal))
            return
        # The shared channel: start after the previous transmission on this network.
        now = time.monotonic()
        net = radio.network
        start = max(now, self._busy_until.get(net, 0.0))
        end = start + sum(airtime(radio.protocol, size) for size in radio.packets(request))
        self._busy_until[net] = end
        done = end - now + radio.delay
        broadcast = request.broadcast
        method = radio.delivery_method(request)
        addressees = [
            m for m, peer in self.radios.items()
            if m != n and m in self._ports and peer.network == net
            and (broadcast or peer.reached_by(request))
        ]
        delivered: list[int] = []
        for m in addressees:
            peer = self.radios[m]
            if self._rng.random() < radio.loss or self._rng.random() < peer.loss:
                self.lost += 1
                continue
            delivered.append(m)
            frame = peer.receive_frame(radio, request.data, broadcast, method)
            self.delivered += 1
            self._at(done, functools.partial(self._write, m, frame))
        status = self._tx_status(radio, request, addressees, delivered)
        if status is not None:
            self._at(max(done, self.reply_delay), functools.partial(self._write, n, status))

    def _tx_status(self, radio: EmulatedRadio, request: Transmit, addressees: list[int],
                   delivered: list[int]) -> bytes | None:
        """The transmit status frame the sender's UART gets (None: it asked for none)."""
        # Broadcasts are never acknowledged, so they always report success. A unicast
        # reports what its firmware reports when nobody acknowledged it (radio.py).
        broadcast = request.broadcast
        if broadcast or delivered:
            to16 = 0xFFFE
            if delivered and not broadcast and radio.protocol == "zigbee":
                to16 = self.radios[delivered[0]].my16  # where it was delivered
            return radio.status_frame(request, TX_OK, to16=to16)
        code, discovery = radio.unicast_failure(request, lost=bool(addressees))
        return radio.status_frame(request, code, discovery=discovery,
                                  to16=UNKNOWN16 if radio.protocol == "zigbee"
                                  else 0xFFFE)

    def _remote(self, radio: EmulatedRadio, request: RemoteCommand) -> None:
        """A remote AT command: over the air to its target(s), which run it and answer
        with a 0x97 to the requester. A unicast that reaches nobody answers status 0x04
        (no response) once the request and its answer would have had time to travel."""
        n = radio.number
        net = radio.network
        now = time.monotonic()
        start = max(now, self._busy_until.get(net, 0.0))
        end = start + airtime(radio.protocol, 15 + len(request.value))
        self._busy_until[net] = end
        done = end - now + radio.delay
        answered = False
        for m, peer in self.radios.items():
            if m == n or m not in self._ports or peer.network != net:
                continue
            if not request.broadcast and not peer.addressed_by(request.dest64,
                                                                 request.dest16):
                continue
            if self._rng.random() < radio.loss or self._rng.random() < peer.loss:
                self.lost += 1
                continue
            status, value = peer.remote_command(request)
            answered = True
            if request.frame_id:
                reply = peer.remote_response(request, status, value)
                back = done + airtime(peer.protocol, 15 + len(value)) + peer.delay
                self._at(max(back, self.reply_delay), functools.partial(self._write, n, reply))
        if not answered and not request.broadcast and request.frame_id:
            failed = (bytes((0x97, request.frame_id)) + request.dest64.to_bytes(8, "big")
                      + request.dest16.to_bytes(2, "big") + request.command
                      + bytes((REMOTE_NO_RESPONSE,)))
            self._at(max(2 * done, self.reply_delay), functools.partial(self._write, n, failed))
