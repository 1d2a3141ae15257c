"""One XBee's digi-xbee device, kept off the event loop (DESIGN section 1: the loop never
blocks).

digi-xbee is a blocking library with threads of its own. `DeviceThread` runs open,
inspection, configuration, close and every write on ONE executor thread of its own
(`DaemonThreadExecutor`), and everything the library's threads report reaches the loop
through `call_soon_threadsafe`:

- received payloads (several callback threads at once, any order) are copied into a
  bounded queue under a lock, with one wake-up per batch; the loop drains it;
- transmit statuses go to the transport's `on_status(frame_id, status)`;
- a reader that found the port hung up goes to `on_hangup()`. On such a port (a pty whose
  emulator died, a USB adapter that lost its radio) every read returns no data and
  digi-xbee's reader logs a warning and retries, ~30,000 lines in half a second: enough
  to fill a daemon's stdout pipe and block every thread that logs, the SIGTERM handler
  included. `ReaderHangups`, a filter on the library's reader logger, mutes those lines
  for our ports and takes them as the sign. It is installed when a port is opened, not
  when this module is imported: importing swarmd changes no other program's logging.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import select
import threading
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from swarmd.transport.base import TransportError
from swarmd.transport.executor import DaemonThreadExecutor
from swarmd.transport.media import MAX_PAYLOAD, MAX_PAYLOAD_ENCRYPTED, PROTOCOL_NAMES

log = logging.getLogger("swarmd.transport.xbee")

HANGUP_EVENTS = select.POLLHUP | select.POLLERR | select.POLLNVAL
READER_LOGGER = "digi.xbee.reader"
UNKNOWN_STATUS = 0xFF
"""The status passed on for a transmit status code digi-xbee does not know."""
READ_GAP = 0.1
"""s. Inside a frame, longer than this without a byte drops the frame (`_open_device`).
At 9600 baud a byte takes about 1 ms; a USB adapter batches for up to 16 ms."""


class ReaderHangups(logging.Filter):
    """Mutes digi-xbee's reader on a hung-up port and tells the port's `DeviceThread`.

    The record arrives on the library's listener thread; when that thread belongs to
    one of our open radios the record is dropped (counted as `hangup_reads`) and the
    radio's owner is told. Other threads' records pass unchanged.

    One filter serves every radio of the process (the reader logger is global), so the
    map of listener threads is written by each radio's device thread and read on every
    listener thread: a lock guards it (a dict resized under a reader is no safe read)."""

    MESSAGE = "returned no data"

    def __init__(self) -> None:
        super().__init__()
        self._listeners: dict[threading.Thread, DeviceThread] = {}
        self._lock = threading.Lock()

    def watch(self, listener: threading.Thread, owner: DeviceThread) -> None:
        """Records of `listener` (a radio's reader thread) now go to `owner`."""
        with self._lock:
            self._listeners[listener] = owner

    def unwatch(self, listener: threading.Thread) -> None:
        with self._lock:
            self._listeners.pop(listener, None)

    def filter(self, record: logging.LogRecord) -> bool:
        with self._lock:
            owner = self._listeners.get(threading.current_thread())
        if owner is None or self.MESSAGE not in record.getMessage():
            return True
        owner._reader_hung_up()
        return False


_HANGUPS = ReaderHangups()


def install_hangup_filter() -> ReaderHangups:
    """Put the filter on digi-xbee's reader logger; once, however often called."""
    logging.getLogger(READER_LOGGER).addFilter(_HANGUPS)  # a no-op when already there
    return _HANGUPS


class RadioSetupError(TransportError):
    """The radio cannot run as configured: the daemon refuses to start (at start) or
    reports `transport_error` (on a reopen); retrying does not help."""


class RadioMismatch(RadioSetupError):
    """The radio's settings differ from the config; `differences` lists them."""

    def __init__(self, port: str, differences: list[str]) -> None:
        super().__init__(
            f"XBee on {port} does not match the config: " + "; ".join(differences)
            + f". Fix the config, or the radio with `swarmd xbee configure --port {port} "
            "... --write`."
        )
        self.differences = differences


class RadioRefused(RadioSetupError):
    """The radio answered a setting the transport makes with an error status."""

    def __init__(self, port: str, name: str, value: bytes, status: str) -> None:
        super().__init__(
            f"XBee on {port} refused {name}={value.hex().upper()} ({status}); its "
            f"firmware does not take that setting: check it with `swarmd xbee info "
            f"--port {port}`.")
        self.name = name


@dataclass(frozen=True, slots=True)
class RadioSettings:
    """What the config expects of the radio; None: whatever the radio has."""

    protocol: str
    api_mode: int
    pan_id: int | None = None
    channel: int | None = None
    role: str | None = None


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


class DeviceThread:
    """The digi-xbee device on `port` and the one thread that talks to it (module
    docstring). Loop-side methods: `open`, `write`, `close`, `close_soon`, `trouble`,
    `shutdown`; the callbacks are called on the loop."""

    def __init__(
        self,
        *,
        port: str,
        baud: int,
        settings: RadioSettings,
        write_timeout: float,
        receive_queue: int,
        counters: Counter[str],
        loop: asyncio.AbstractEventLoop,
        on_frame: Callable[[bytes], None],
        on_status: Callable[[int, int], None],
        on_hangup: Callable[[], None],
    ) -> None:
        self.port = port
        self.baud = baud
        self.settings = settings
        self.write_timeout = write_timeout
        self.counters = counters
        self.info: RadioInfo | None = None
        self._loop = loop
        self._on_frame = on_frame
        self._on_status = on_status
        self._on_hangup = on_hangup
        self._executor: DaemonThreadExecutor | None = DaemonThreadExecutor(f"xbee-{port}")
        self._device: Any = None
        self._device_node = ""
        # Incoming, filled on digi-xbee's threads, drained on the loop.
        self._rx_lock = threading.Lock()
        self._rx: deque[bytes] = deque()
        self._rx_max = receive_queue
        self._rx_scheduled = False
        # Hang-ups seen by digi-xbee's reader thread (ReaderHangups), for this device.
        self._hangup_reads = 0
        self._hangup_reported = False

    # -- loop side ----------------------------------------------------------------------
    async def open(self) -> RadioInfo:
        """Open and inspect the radio (`RadioMismatch` when it differs from the config)."""
        install_hangup_filter()
        self.info = await self._loop.run_in_executor(self._need_executor(),
                                                     self._open_device)
        return self.info

    def write(self, frame_id: int, frame: bytes) -> asyncio.Future[None]:
        """Broadcast `frame` with `frame_id` (its transmit status comes to `on_status`)."""
        return self._loop.run_in_executor(self._need_executor(), self._write, frame_id, frame)

    def close_soon(self) -> None:
        """Close the device on its thread, not waiting (the radio went down)."""
        if self._executor is not None:
            self._loop.run_in_executor(self._executor, self._close_device)

    async def close(self, timeout: float) -> bool:
        """Close the device, waiting at most `timeout` s: False when that did not finish
        (the daemon's stop must not wait on a wedged library; the thread is left)."""
        if self._executor is None:
            return True
        closing = self._loop.run_in_executor(self._executor, self._close_device)
        try:
            await asyncio.wait_for(closing, timeout)
        except TimeoutError:
            return False
        return True

    def shutdown(self) -> None:
        """Let the thread end after its queued jobs (never waits)."""
        if self._executor is not None:
            executor, self._executor = self._executor, None
            executor.shutdown(wait=False)

    def trouble(self) -> str | None:
        """Why the open port is unusable, or None. digi-xbee does not notice a pulled
        radio: a read returning no data (what Linux gives for an unplugged USB serial
        device or a closed pty) is logged and retried by its reader thread forever. The
        device node vanishing, or now naming another device, is the reliable sign."""
        dev = self._device
        if dev is None:
            return None
        if not _port_open(dev):
            return "serial port closed"
        if os.path.realpath(self.port) != self._device_node:
            return f"{self.port} disappeared (radio unplugged?)"
        if _hung_up(dev):
            # The node stays while we hold it open: a pty whose emulator died, a USB
            # adapter whose radio is gone. POLLHUP is the sign.
            return f"{self.port} hung up (radio or emulator gone?)"
        return None

    def _need_executor(self) -> DaemonThreadExecutor:
        if self._executor is None:
            raise TransportError("radio thread shut down")
        return self._executor

    def _drain(self) -> None:
        with self._rx_lock:
            batch = list(self._rx)
            self._rx.clear()
            self._rx_scheduled = False
        for data in batch:
            self.counters["received"] += 1
            try:
                self._on_frame(data)
            except Exception:  # the runtime's callback must not kill the transport
                log.exception("on_frame raised")

    def _reader_reported_hangup(self, dev: Any) -> None:
        self.counters["hangup_reads"] = self._hangup_reads
        if dev is not None and dev is self._device:
            self._on_hangup()

    def _call_soon(self, callback: Callable[..., None], *args: Any) -> None:
        """Wake the loop from another thread; a closed (or closing) loop is let be."""
        loop = self._loop
        if not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # loop closing under us
                loop.call_soon_threadsafe(callback, *args)

    # -- device thread ------------------------------------------------------------------
    def _open_device(self) -> RadioInfo:
        from digi.xbee.devices import XBeeDevice
        from digi.xbee.models.mode import OperatingMode

        self._close_device()
        dev = XBeeDevice(self.port, self.baud)
        try:
            dev.open()
            info = self._inspect(dev, OperatingMode)
            if info.protocol == "802.15.4":
                self._use_64bit_source(dev)
            dev.add_data_received_callback(self._on_data)
            dev.add_packet_received_callback(self._on_packet)
            self._set_port_timeouts(dev)
        except BaseException:
            try:
                dev.close()
            except Exception as exc:  # the set-up error below is the one to report
                self._ignored("close", exc)
            raise
        self._hangup_reported = False
        self._device = dev
        self._device_node = os.path.realpath(self.port)
        listener = getattr(dev, "_packet_listener", None)  # digi-xbee's reader thread
        if isinstance(listener, threading.Thread):
            _HANGUPS.watch(listener, self)
        return info

    def _use_64bit_source(self, dev: Any) -> None:
        """An 802.15.4 radio sends with 64-bit source addresses (MY = FFFE)."""
        my = bytes(dev.get_parameter("MY"))
        if int.from_bytes(my, "big") != 0xFFFE:
            # Applied (0x08), not written: redone on every open, the radio's saved
            # settings stay the user's.
            self._set(dev, "MY", b"\xff\xfe")
            log.info("XBee %s: MY %s -> FFFE (64-bit source addresses)",
                     self.port, my.hex().upper())

    def _set_port_timeouts(self, dev: Any) -> None:
        serial_port = getattr(dev, "serial_port", None)
        if serial_port is not None:
            # A radio that stops reading its UART fails the write (-> down, reopen)
            # instead of blocking this thread, and with it close(), for good.
            serial_port.write_timeout = self.write_timeout
            # digi-xbee's reader trusts a frame's length and reads that many bytes,
            # each with the port's read timeout (4 s by default): one corrupt
            # length (7E FF FF) kept the daemon deaf until 64 KiB or a 4 s silence
            # came, and a busy channel has no such silence. A byte that does not
            # come within READ_GAP ends the frame and the reader hunts for the
            # next 0x7E. (digi-xbee's own AT and send timeouts are separate.)
            serial_port.timeout = READ_GAP

    def _ignored(self, what: str, exc: Exception) -> None:
        """An error this thread goes on after: counted as `ignored:<what>`, and logged
        the first time for each `what` (a flapping radio would fill the journal)."""
        key = f"ignored:{what}"
        self.counters[key] += 1
        if self.counters[key] == 1:
            log.warning("xbee %s failed (%s: %s); going on, counted as %s", what,
                        type(exc).__name__, exc, key, extra={"port": self.port})

    def _set(self, dev: Any, name: str, value: bytes) -> None:
        """Set and apply one parameter; a refusal becomes `RadioRefused`."""
        from digi.xbee.exception import ATCommandException

        try:
            dev.set_parameter(name, value)
        except ATCommandException as exc:
            status = getattr(exc, "status", None)
            text = (f"AT status 0x{status.code:02X}, {status.description}"
                    if status is not None else str(exc))
            raise RadioRefused(self.port, name, value, text) from None

    def _inspect(self, dev: Any, operating_mode: Any) -> RadioInfo:
        want = self.settings
        found = dev.get_protocol()
        protocol = PROTOCOL_NAMES.get(getattr(found, "name", ""), str(found))
        mode = 2 if dev.operating_mode == operating_mode.ESCAPED_API_MODE else 1
        pan = int.from_bytes(bytes(dev.get_parameter("ID")), "big")
        channel = int.from_bytes(bytes(dev.get_parameter("CH")), "big")
        coordinator = int.from_bytes(bytes(dev.get_parameter("CE")), "big") == 1
        diffs: list[str] = []
        if protocol != want.protocol:
            diffs.append(f"protocol: radio {protocol}, config {want.protocol}")
        if mode != want.api_mode:
            diffs.append(f"API mode (AP): radio {mode}, config {want.api_mode}")
        if want.pan_id is not None and pan != want.pan_id:
            diffs.append(f"PAN id (ID): radio 0x{pan:04X}, config 0x{want.pan_id:04X}")
        if want.channel is not None and channel != want.channel:
            diffs.append(f"channel (CH): radio 0x{channel:02X}, config 0x{want.channel:02X}")
        if want.role is not None and coordinator != (want.role == "coordinator"):
            diffs.append(f"role (CE): radio {'coordinator' if coordinator else 'router'}, "
                         f"config {want.role}")
        if diffs:
            raise RadioMismatch(self.port, diffs)
        limit = MAX_PAYLOAD.get(protocol, 73)
        # EE and NP are optional refinements (not every firmware answers them): without
        # them the protocol's table value stands.
        try:
            if bytes(dev.get_parameter("EE")) not in (b"", b"\x00"):
                limit = MAX_PAYLOAD_ENCRYPTED.get(protocol, 65)
        except Exception as exc:
            self._ignored("read EE", exc)
        try:
            np_value = int.from_bytes(bytes(dev.get_parameter("NP")), "big")
            if 0 < np_value < limit:
                limit = np_value  # the radio knows best (e.g. source routing, encryption)
        except Exception as exc:
            self._ignored("read NP", exc)
        address = int(str(dev.get_64bit_addr()), 16)
        return RadioInfo(protocol, mode, pan, channel, coordinator, address, limit)

    def _close_device(self) -> None:
        dev, self._device = self._device, None
        if dev is not None:
            try:
                dev.close()
            except Exception as exc:  # a port already gone (unplugged): nothing to free
                self._ignored("close", exc)
            listener = getattr(dev, "_packet_listener", None)
            if isinstance(listener, threading.Thread):
                _HANGUPS.unwatch(listener)

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

    # -- digi-xbee's threads --------------------------------------------------------------
    def _on_data(self, message: Any) -> None:
        self._hand_over(bytes(message.data))

    def _on_packet(self, packet: Any) -> None:
        from digi.xbee.packets.aft import ApiFrameType

        if packet.get_frame_type() in (ApiFrameType.TRANSMIT_STATUS, ApiFrameType.TX_STATUS):
            # digi-xbee leaves a status code it does not know as None: still a failure.
            status = packet.transmit_status
            code = int(status.code) if status is not None else UNKNOWN_STATUS
            self._call_soon(self._on_status, packet.frame_id, code)

    def _hand_over(self, data: bytes) -> None:
        """Bounded queue, one wake-up per batch."""
        with self._rx_lock:
            if len(self._rx) >= self._rx_max:
                self._rx.popleft()  # the loop is behind: newest frames are worth most
                self.counters["receive_overflow"] += 1
            self._rx.append(data)
            if self._rx_scheduled:
                return
            self._rx_scheduled = True
        self._call_soon(self._drain)

    def _reader_hung_up(self) -> None:
        """On digi-xbee's reader thread (`ReaderHangups`): a read found the port hung
        up. Counted; the loop is told once per opened device."""
        self._hangup_reads += 1
        if self._hangup_reported:
            return
        self._hangup_reported = True
        self._call_soon(self._reader_reported_hangup, self._device)


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
