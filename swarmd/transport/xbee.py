"""XBee radios in API mode through digi-xbee (issue 5 point 1; notes/xbee.md).

digi-xbee is a blocking library with its own threads, so this transport keeps it at
arm's length from the event loop (STYLE.md point 8):

- open, configure, close and every write to the radio run in ONE executor thread that
  this transport owns, never on the loop;
- the library calls us back on its thread pool (several at once, any order); a callback
  copies the payload into a bounded queue under a lock and wakes the loop with
  `call_soon_threadsafe`; the loop drains the queue and calls `on_frame` (base.py);
- broadcasts go out as raw 0x00 / 0x10 requests with our own frame ids, at most
  `max_in_flight` waiting for their transmit status at a time (frame ids wrap at 255,
  notes/xbee.md); more wait in a short queue whose oldest frame is dropped first: a
  newer heartbeat supersedes an older one. Every status is checked; a failed status or
  a missing one is counted and reported as `send_error`;
- the payload limit comes from the radio's protocol (and encryption, EE);
- 802.15.4 radios are set to MY=0xFFFE so frames arrive as 0x80 with the 64-bit source:
  16-bit sources (0x81) stall digi-xbee's reader 4 s a frame (xbee-python #296);
- at start the radio's protocol, API mode, PAN id, channel and role (CE) are compared
  with the config and every difference is named (TransportError);
- a radio that is pulled or stops answering is reported (`transport_down`) and reopened
  with exponential back-off (`reopen.py`) while the daemon keeps running (`transport_up`
  when back). A port that hung up (a pty whose emulator died, a USB adapter that lost
  its radio) is noticed even while the device node stays (we hold it open): the
  watchdog polls the fd for POLLHUP, and digi-xbee's reader, which spins logging
  "device reports readiness to read but returned no data" thousands of times a
  second, is muted for our ports and taken as the same sign (`_ReaderHangups`). That
  flood once filled the daemon's stdout pipe and blocked every thread that logged,
  the SIGTERM handler included;
- nothing here can hang the daemon's stop: the device thread is a daemon thread,
  `close()` gives digi-xbee's close `close_timeout` seconds and then abandons the
  thread (logged), and writes have a serial write timeout, so a radio that stopped
  reading its UART fails a write instead of blocking the thread forever.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import queue
import select
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from typing import Any, TypeVar

from swarmd.transport.base import (
    ChannelEvents,
    EventCallback,
    FrameCallback,
    TransportError,
)
from swarmd.transport.reopen import Reopener

log = logging.getLogger(__name__)

PROTOCOLS = ("zigbee", "802.15.4", "digimesh")
MAX_PAYLOAD = {"zigbee": 92, "802.15.4": 100, "digimesh": 73}
MAX_PAYLOAD_ENCRYPTED = {"zigbee": 74, "802.15.4": 95, "digimesh": 65}
BROADCAST64 = 0x000000000000FFFF
HANGUP_EVENTS = select.POLLHUP | select.POLLERR | select.POLLNVAL
_T = TypeVar("_T")


class _DeviceThread(Executor):
    """The one thread that talks to a radio: an executor like
    `ThreadPoolExecutor(1)` but on a *daemon* thread, never joined at exit.
    digi-xbee's close or open can block for good on a device in a bad state; a
    `ThreadPoolExecutor` thread stuck like that keeps `asyncio.run` (its default
    executor shutdown) and the interpreter's exit waiting forever, i.e. a daemon that
    needs SIGKILL. Abandoning a stuck daemon thread lets the process exit."""

    def __init__(self, name: str) -> None:
        self._jobs: queue.SimpleQueue[tuple[Future[Any], Callable[..., Any], tuple[Any, ...]]
                                      | None] = queue.SimpleQueue()
        self._closed = False
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def submit(self, fn: Callable[..., _T], /, *args: Any, **kwargs: Any) -> Future[_T]:
        if self._closed:
            raise RuntimeError("device thread closed")
        future: Future[_T] = Future()
        self._jobs.put((future, fn, args))
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Stop after the queued jobs; never waits (a stuck job would wait forever)."""
        self._closed = True
        self._jobs.put(None)

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            future, fn, args = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args))
            except BaseException as exc:
                future.set_exception(exc)


class _ReaderHangups(logging.Filter):
    """Mutes digi-xbee's reader on a hung-up port and tells our transport.

    On a port whose other end is gone (pty master closed, USB adapter lost its
    device) every read returns no data and the library's reader logs a warning and
    loops: ~30,000 lines in half a second measured. The record arrives here on the
    listener thread; when that thread belongs to one of our open radios the record is
    dropped (counted as `hangup_reads`) and the transport is woken up to report the
    radio down. Other threads' records pass unchanged."""

    MESSAGE = "returned no data"

    def __init__(self) -> None:
        super().__init__()
        self.listeners: dict[threading.Thread, XBeeTransport] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        owner = self.listeners.get(threading.current_thread())
        if owner is None or self.MESSAGE not in record.getMessage():
            return True
        owner._reader_hung_up()
        return False


_HANGUPS = _ReaderHangups()
logging.getLogger("digi.xbee.reader").addFilter(_HANGUPS)


class RadioMismatch(TransportError):
    """The radio's settings differ from the config; `differences` lists them."""

    def __init__(self, port: str, differences: list[str]) -> None:
        super().__init__(
            f"XBee on {port} does not match the config: " + "; ".join(differences)
            + f". Fix the config, or the radio with `swarmd xbee configure --port {port} "
            "... --write`."
        )
        self.differences = differences


@dataclass(frozen=True, slots=True)
class RadioInfo:
    """What the radio said when opened."""

    protocol: str
    api_mode: int
    pan_id: int
    channel: int
    coordinator: bool
    address64: int
    max_payload: int


class XBeeTransport:
    """Broadcast frames through a local XBee in API mode (see the module docstring)."""

    def __init__(
        self,
        *,
        port: str,
        baud: int = 9600,
        protocol: str = "802.15.4",
        api_mode: int = 1,
        pan_id: int | None = None,
        channel: int | None = None,
        role: str | None = None,
        max_in_flight: int = 8,
        send_queue: int = 16,
        receive_queue: int = 256,
        status_timeout: float = 2.0,
        reopen_min: float = 0.5,
        reopen_max: float = 10.0,
        watchdog_interval: float = 0.5,
        close_timeout: float = 3.0,
    ) -> None:
        if protocol not in PROTOCOLS:
            raise TransportError(f"unknown XBee protocol {protocol!r}; one of {PROTOCOLS}")
        if api_mode not in (1, 2):
            raise TransportError(f"api_mode must be 1 or 2 (digi-xbee needs API mode), "
                                 f"got {api_mode}")
        if role not in (None, "coordinator", "router"):
            raise TransportError(f"role must be coordinator or router, got {role!r}")
        if not 1 <= max_in_flight <= 64:
            raise TransportError("max_in_flight must be 1..64 (frame ids wrap at 255)")
        self.port = port
        self.baud = baud
        self.protocol = protocol
        self.api_mode = api_mode
        self.pan_id = pan_id
        self.channel = channel
        self.role = role
        self.max_in_flight = max_in_flight
        self.status_timeout = status_timeout
        self.reopen_min = reopen_min
        self.reopen_max = reopen_max
        self.watchdog_interval = watchdog_interval
        self.close_timeout = close_timeout
        """s. How long `close()` waits for digi-xbee's close before abandoning it."""
        self.info: RadioInfo | None = None
        self.counters: Counter[str] = Counter()
        self._events = ChannelEvents("xbee", self.counters, log)
        self._max_payload = MAX_PAYLOAD[protocol]
        self._executor: _DeviceThread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_frame: FrameCallback | None = None
        self._device: Any = None
        self._device_node = ""
        self._up = False
        self._closing = False
        self._down_since = 0.0
        self._reopener: Reopener | None = None
        self._watchdog: asyncio.TimerHandle | None = None
        # Outgoing: frames waiting for a slot, and frame id -> status deadline timer.
        self._queue: deque[bytes] = deque(maxlen=send_queue)
        self._in_flight: dict[int, asyncio.TimerHandle] = {}
        self._next_id = 0
        self._timeouts_in_row = 0
        # Incoming, filled on digi-xbee's threads, drained on the loop.
        self._rx_lock = threading.Lock()
        self._rx: deque[bytes] = deque()
        self._rx_max = receive_queue
        self._rx_scheduled = False
        # Hang-ups seen by digi-xbee's reader thread (_ReaderHangups), for this device.
        self._hangup_reads = 0
        self._hangup_reported = False

    @classmethod
    def from_config(cls, cfg: Any) -> XBeeTransport:
        """Build from `swarmd.config.XBeeTransportConfig` (duck-typed)."""
        return cls(port=cfg.port, baud=cfg.baud, protocol=cfg.protocol,
                   api_mode=cfg.api_mode, pan_id=cfg.pan_id, channel=cfg.channel,
                   role=cfg.role, max_in_flight=cfg.max_in_flight)

    @property
    def max_payload(self) -> int:
        return self._max_payload

    @property
    def up(self) -> bool:
        return self._up

    # -- lifecycle (loop side) ----------------------------------------------------------
    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None:
        """Open the radio and check it against the config. A radio whose settings
        differ raises `RadioMismatch`; a missing or silent one is reported as
        `transport_down` and retried in the background (the daemon keeps running)."""
        self._loop = asyncio.get_running_loop()
        self._on_frame, self._events.callback = on_frame, on_event
        self._executor = _DeviceThread(f"xbee-{self.port}")
        self._reopener = Reopener(f"XBee {self.port}", self._open, self.counters,
                                  minimum=self.reopen_min, maximum=self.reopen_max,
                                  describe=_describe, on_failure=self._reopen_failed,
                                  on_success=self._reopened, logger=log)
        try:
            await self._open()
        except RadioMismatch:
            self._shutdown_executor()
            raise
        except Exception as exc:  # no device, timeout, wrong mode: keep running, retry
            self._went_down(f"cannot open {self.port}: {_describe(exc)}")
        self._reopener.start()
        self._arm_watchdog()

    async def close(self) -> None:
        self._closing = True
        if self._watchdog is not None:
            self._watchdog.cancel()
        if self._reopener is not None:
            await self._reopener.close()
        self._drop_in_flight("closed")
        self._up = False
        if self._executor is not None:
            closing = asyncio.get_running_loop().run_in_executor(self._executor,
                                                                 self._close_device)
            try:
                # Bounded: the daemon's stop must not wait on a wedged library (module
                # docstring); the device thread is a daemon thread, left behind.
                await asyncio.wait_for(closing, self.close_timeout)
            except TimeoutError:
                self.counters["close_timeout"] += 1
                log.error("XBee %s: closing the radio did not finish in %.1f s; "
                          "abandoned (its thread is left behind)", self.port,
                          self.close_timeout)
        self._shutdown_executor()

    def _shutdown_executor(self) -> None:
        if self._executor is not None:
            executor, self._executor = self._executor, None
            executor.shutdown(wait=False)

    async def _open(self) -> None:
        assert self._executor is not None and self._loop is not None
        info = await self._loop.run_in_executor(self._executor, self._open_device)
        self.info = info
        self._max_payload = info.max_payload
        self._up = True
        self._timeouts_in_row = 0
        self._events.emit("transport_up", {
            "kind": "xbee", "port": self.port, "protocol": info.protocol,
            "pan_id": f"0x{info.pan_id:04X}", "channel": f"0x{info.channel:02X}",
            "address": f"{info.address64:016X}", "max_payload": info.max_payload,
        })

    def _reopen_failed(self, exc: Exception) -> None:
        if isinstance(exc, RadioMismatch):
            self._events.emit("transport_error", {"kind": "xbee", "reason": str(exc)})

    def _reopened(self) -> None:
        log.warning("XBee %s back after %.1f s", self.port, time.monotonic() - self._down_since)

    def _went_down(self, reason: str) -> None:
        if not self._up and self._down_since:
            return
        self._up = False
        self._down_since = time.monotonic()
        self.counters["outages"] += 1
        log.warning("XBee %s down: %s", self.port, reason)
        self._events.emit("transport_down", {"kind": "xbee", "port": self.port, "reason": reason})
        self._drop_in_flight("radio down")
        self._queue.clear()
        if self._executor is not None and self._loop is not None:
            self._loop.run_in_executor(self._executor, self._close_device)
        if self._reopener is not None:
            self._reopener.lost()

    def _arm_watchdog(self) -> None:
        assert self._loop is not None
        self._watchdog = self._loop.call_later(self.watchdog_interval, self._check_alive)

    def _check_alive(self) -> None:
        """Notice a pulled radio even while nothing is being sent. digi-xbee does not:
        a read returning no data (what Linux gives for an unplugged USB serial device
        or a closed pty) is logged and retried by its reader thread forever. The device
        node vanishing, or now naming another device, is the reliable sign."""
        if self._closing:
            return
        dev = self._device
        if self._up and dev is not None:
            if not _port_open(dev):
                self._went_down("serial port closed")
            elif os.path.realpath(self.port) != self._device_node:
                self._went_down(f"{self.port} disappeared (radio unplugged?)")
            elif _hung_up(dev):
                # The node stays while we hold it open: a pty whose emulator died, a
                # USB adapter whose radio is gone. POLLHUP is the sign.
                self._went_down(f"{self.port} hung up (radio or emulator gone?)")
        self._arm_watchdog()

    def _reader_hung_up(self) -> None:
        """On digi-xbee's reader thread (`_ReaderHangups`): a read found the port hung
        up. Counted; the loop is told once per opened device."""
        self._hangup_reads += 1
        if self._hangup_reported:
            return
        self._hangup_reported = True
        loop, dev = self._loop, self._device
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # loop closing under us
                loop.call_soon_threadsafe(self._reader_reported_hangup, dev)

    def _reader_reported_hangup(self, dev: Any) -> None:
        self.counters["hangup_reads"] = self._hangup_reads
        if self._up and dev is not None and dev is self._device and not self._closing:
            self._went_down(f"{self.port} hung up (reads return no data: radio or "
                            "emulator gone?)")

    # -- executor-thread side -----------------------------------------------------------
    def _open_device(self) -> RadioInfo:
        from digi.xbee.devices import XBeeDevice
        from digi.xbee.models.mode import OperatingMode

        self._close_device()
        dev = XBeeDevice(self.port, self.baud)
        try:
            dev.open()
            info = self._inspect(dev, OperatingMode)
            if info.protocol == "802.15.4":
                my = bytes(dev.get_parameter("MY"))
                if int.from_bytes(my, "big") != 0xFFFE:
                    # Applied (0x08), not written: redone on every open, the radio's saved
                    # settings stay the user's.
                    dev.set_parameter("MY", b"\xff\xfe")
                    log.info("XBee %s: MY %s -> FFFE (64-bit source addresses)",
                             self.port, my.hex().upper())
            dev.add_data_received_callback(self._on_data)
            dev.add_packet_received_callback(self._on_packet)
            serial_port = getattr(dev, "serial_port", None)
            if serial_port is not None:
                # A radio that stops reading its UART fails the write (-> down, reopen)
                # instead of blocking this thread, and with it close(), for good.
                serial_port.write_timeout = self.status_timeout
        except BaseException:
            with contextlib.suppress(Exception):
                dev.close()
            raise
        self._hangup_reported = False
        self._device = dev
        self._device_node = os.path.realpath(self.port)
        listener = getattr(dev, "_packet_listener", None)  # digi-xbee's reader thread
        if isinstance(listener, threading.Thread):
            _HANGUPS.listeners[listener] = self
        return info

    def _inspect(self, dev: Any, operating_mode: Any) -> RadioInfo:
        from digi.xbee.models.protocol import XBeeProtocol

        names = {XBeeProtocol.ZIGBEE: "zigbee", XBeeProtocol.RAW_802_15_4: "802.15.4",
                 XBeeProtocol.DIGI_MESH: "digimesh"}
        protocol = names.get(dev.get_protocol(), str(dev.get_protocol()))
        mode = 2 if dev.operating_mode == operating_mode.ESCAPED_API_MODE else 1
        pan = int.from_bytes(bytes(dev.get_parameter("ID")), "big")
        channel = int.from_bytes(bytes(dev.get_parameter("CH")), "big")
        coordinator = int.from_bytes(bytes(dev.get_parameter("CE")), "big") == 1
        diffs: list[str] = []
        if protocol != self.protocol:
            diffs.append(f"protocol: radio {protocol}, config {self.protocol}")
        if mode != self.api_mode:
            diffs.append(f"API mode (AP): radio {mode}, config {self.api_mode}")
        if self.pan_id is not None and pan != self.pan_id:
            diffs.append(f"PAN id (ID): radio 0x{pan:04X}, config 0x{self.pan_id:04X}")
        if self.channel is not None and channel != self.channel:
            diffs.append(f"channel (CH): radio 0x{channel:02X}, config 0x{self.channel:02X}")
        if self.role is not None and coordinator != (self.role == "coordinator"):
            diffs.append(f"role (CE): radio {'coordinator' if coordinator else 'router'}, "
                         f"config {self.role}")
        if diffs:
            raise RadioMismatch(self.port, diffs)
        limit = MAX_PAYLOAD.get(protocol, 73)
        with contextlib.suppress(Exception):
            if bytes(dev.get_parameter("EE")) not in (b"", b"\x00"):
                limit = MAX_PAYLOAD_ENCRYPTED.get(protocol, 65)
        with contextlib.suppress(Exception):
            np_value = int.from_bytes(bytes(dev.get_parameter("NP")), "big")
            if 0 < np_value < limit:
                limit = np_value  # the radio knows best (e.g. source routing, encryption)
        address = int(str(dev.get_64bit_addr()), 16)
        return RadioInfo(protocol, mode, pan, channel, coordinator, address, limit)

    def _close_device(self) -> None:
        dev, self._device = self._device, None
        if dev is not None:
            with contextlib.suppress(Exception):
                dev.close()
            listener = getattr(dev, "_packet_listener", None)
            if isinstance(listener, threading.Thread):
                _HANGUPS.listeners.pop(listener, None)

    def _write(self, frame_id: int, frame: bytes) -> None:
        from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress
        from digi.xbee.packets.common import TransmitPacket
        from digi.xbee.packets.raw import TX64Packet

        dev = self._device
        if dev is None:
            raise TransportError("radio not open")
        dest = XBee64BitAddress.BROADCAST_ADDRESS
        packet: Any
        if self.info is not None and self.info.protocol == "802.15.4":
            packet = TX64Packet(frame_id, dest, 0, rf_data=frame, op_mode=dev.operating_mode)
        else:
            packet = TransmitPacket(frame_id, dest, XBee16BitAddress.UNKNOWN_ADDRESS, 0, 0,
                                    rf_data=frame, op_mode=dev.operating_mode)
        dev.send_packet(packet, sync=False)

    # -- digi-xbee callback threads -----------------------------------------------------
    def _on_data(self, message: Any) -> None:
        self._hand_over(bytes(message.data))

    def _on_packet(self, packet: Any) -> None:
        from digi.xbee.packets.aft import ApiFrameType

        if packet.get_frame_type() in (ApiFrameType.TRANSMIT_STATUS, ApiFrameType.TX_STATUS):
            loop = self._loop
            if loop is not None and not loop.is_closed():
                status = int(packet.transmit_status.code)
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(self._on_status, packet.frame_id, status)

    def _hand_over(self, data: bytes) -> None:
        """Runs on a library thread: bounded queue, one wake-up per batch."""
        with self._rx_lock:
            if len(self._rx) >= self._rx_max:
                self._rx.popleft()  # the loop is behind: newest frames are worth most
                self.counters["receive_overflow"] += 1
            self._rx.append(data)
            if self._rx_scheduled:
                return
            self._rx_scheduled = True
        loop = self._loop
        if loop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # loop closing under us
                loop.call_soon_threadsafe(self._drain)

    # -- loop side: receive -------------------------------------------------------------
    def _drain(self) -> None:
        with self._rx_lock:
            batch = list(self._rx)
            self._rx.clear()
            self._rx_scheduled = False
        for data in batch:
            self.counters["received"] += 1
            if self._on_frame is not None:
                try:
                    self._on_frame(data)
                except Exception:  # the runtime's callback must not kill the transport
                    log.exception("on_frame raised")

    # -- loop side: send ----------------------------------------------------------------
    def send(self, frame: bytes) -> None:
        """Queue one broadcast; never blocks and never raises (base.py)."""
        if len(frame) > self._max_payload:
            self._events.send_error("oversize", size=len(frame), limit=self._max_payload)
            return
        if not self._up:
            self._events.send_error("radio down")
            return
        if len(self._queue) == self._queue.maxlen:
            self._events.send_error("queue full")  # deque drops the oldest on append
        self._queue.append(frame)
        self._pump()

    def _pump(self) -> None:
        while self._queue and self._up and len(self._in_flight) < self.max_in_flight:
            frame = self._queue.popleft()
            frame_id = self._allocate_id()
            assert self._loop is not None and self._executor is not None
            self._in_flight[frame_id] = self._loop.call_later(
                self.status_timeout, self._on_status_timeout, frame_id)
            future = self._loop.run_in_executor(self._executor, self._write, frame_id, frame)
            future.add_done_callback(self._after_write)
            self.counters["sent"] += 1

    def _allocate_id(self) -> int:
        while True:
            self._next_id = self._next_id % 255 + 1  # 1..255: id 0 would ask for no status
            if self._next_id not in self._in_flight:
                return self._next_id

    def _after_write(self, future: asyncio.Future[None]) -> None:
        if future.cancelled():
            return
        exc = future.exception()
        if exc is not None and self._up:
            self._went_down(f"write failed: {_describe(exc)}")

    def _on_status(self, frame_id: int, status: int) -> None:
        timer = self._in_flight.pop(frame_id, None)
        if timer is None:
            return  # late status of a frame already given up
        timer.cancel()
        self._timeouts_in_row = 0
        if status == 0:
            self.counters["delivered"] += 1
        else:
            self._events.send_error(_STATUS_TEXT.get(status, f"transmit status 0x{status:02X}"),
                             status=status)
        self._pump()

    def _on_status_timeout(self, frame_id: int) -> None:
        if self._in_flight.pop(frame_id, None) is None:
            return
        self._timeouts_in_row += 1
        self._events.send_error("no transmit status")
        if self._timeouts_in_row >= 3:
            self._went_down("radio stopped answering (no transmit status 3 times)")
        else:
            self._pump()

    def _drop_in_flight(self, reason: str) -> None:
        for timer in self._in_flight.values():
            timer.cancel()
            self.counters[f"lost ({reason})"] += 1
        self._in_flight.clear()


_STATUS_TEXT = {
    0x01: "MAC ACK failure", 0x02: "CCA failure (channel busy)", 0x21: "network ACK failure",
    0x22: "not joined to network", 0x74: "payload too large", 0x75: "indirect message unrequested",
}


def _port_open(dev: Any) -> bool:
    try:
        return bool(dev.comm_iface.is_interface_open)
    except Exception:
        return False


def _hung_up(dev: Any) -> bool:
    """The serial port's fd reports a hang-up (poll, no wait; on the loop thread)."""
    fd = getattr(getattr(dev, "serial_port", None), "fd", None)
    if not isinstance(fd, int):
        return False
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    try:
        return any(ev & HANGUP_EVENTS for _, ev in poller.poll(0))
    except OSError:
        return True


def _describe(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if type(exc).__name__ not in text else text
