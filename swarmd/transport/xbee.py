"""XBee radios in API mode through digi-xbee (docs/radios.md).

digi-xbee is a blocking library with its own threads, so this transport keeps it at
arm's length from the event loop (DESIGN section 1: the loop never blocks). Three parts:

- `xbee_device.DeviceThread`: open, configure, close and every write run on ONE
  executor thread per radio, never on the loop; what the library's threads report
  (frames, transmit statuses, a hung-up reader) reaches the loop through
  `call_soon_threadsafe`;
- `window.SendWindow` (sans-IO): broadcasts go out as raw 0x00 / 0x10 requests with our
  own frame ids, at most `max_in_flight` waiting for their transmit status at a time;
  more wait in a short queue whose oldest frame is dropped first: a newer heartbeat
  supersedes an older one. Every status is checked; a failed status or a missing one is
  counted and reported as `send_error`; three missing in a row take the radio down;
- this module: the lifecycle, on the loop.

Also:
- the payload limit comes from the radio's protocol (and encryption, EE; media.py); a
  frame larger than it (a per-robot signed frame on DigiMesh) goes out in fragments and
  received fragments are put back together (`fragment.py`), counted as
  `fragment_drop:<reason>` when dropped;
- 802.15.4 radios are set to MY=0xFFFE so frames arrive as 0x80 with the 64-bit source:
  16-bit sources (0x81) stall digi-xbee's reader 4 s a frame (xbee-python #296);
- at start the radio's protocol, API mode, PAN id, channel and role (CE) are compared
  with the config and every difference is named (`RadioMismatch`);
- a radio that is pulled or stops answering is reported (`transport_down`) and reopened
  with exponential back-off (`reopen.py`) while the daemon keeps running (`transport_up`
  when back). A port that hung up (a pty whose emulator died, a USB adapter that lost
  its radio) is noticed even while the device node stays (we hold it open): the
  watchdog polls the fd for POLLHUP, and digi-xbee's reader, which then logs "device
  reports readiness to read but returned no data" thousands of times a second, is muted
  for our ports and taken as the same sign (`xbee_device.ReaderHangups`);
- nothing here can hang the daemon's stop: the device thread is a daemon thread,
  `close()` gives digi-xbee's close `close_timeout` seconds and then abandons the
  thread (logged), and writes have a serial write timeout, so a radio that stopped
  reading its UART fails a write instead of blocking the thread forever.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any, ClassVar

from swarmd.transport import fragment
from swarmd.transport.base import (
    ChannelDown,
    ChannelError,
    ChannelEvents,
    ChannelUp,
    EventCallback,
    FrameCallback,
    SendFailure,
    TransportError,
)
from swarmd.transport.media import MAX_PAYLOAD, PROTOCOLS
from swarmd.transport.reopen import Reopener
from swarmd.transport.window import SendWindow
from swarmd.transport.xbee_device import (
    DeviceThread,
    RadioInfo,
    RadioMismatch,
    RadioRefused,
    RadioSettings,
    RadioSetupError,
)

__all__ = ["RadioInfo", "RadioMismatch", "RadioRefused", "RadioSetupError", "XBeeTransport",
           "XBeeUp"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class XBeeUp(ChannelUp):
    """The radio on `port` is open: what it reported at start (hex as XCTU shows it)."""

    kind: ClassVar[str] = "xbee"
    port: str
    protocol: str
    pan_id: str
    channel: str
    address: str
    max_payload: int


def _check_options(protocol: str, api_mode: int, role: str | None, max_in_flight: int) -> None:
    """Raise TransportError for an option digi-xbee or the radio cannot work with."""
    if protocol not in PROTOCOLS:
        raise TransportError(f"unknown XBee protocol {protocol!r}; one of {PROTOCOLS}")
    if api_mode not in (1, 2):
        raise TransportError(f"api_mode must be 1 or 2 (digi-xbee needs API mode), "
                             f"got {api_mode}")
    if role not in (None, "coordinator", "router"):
        raise TransportError(f"role must be coordinator or router, got {role!r}")
    if not 1 <= max_in_flight <= 64:
        raise TransportError("max_in_flight must be 1..64 (frame ids wrap at 255)")


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
        _check_options(protocol, api_mode, role, max_in_flight)
        self.port = port
        self.baud = baud
        self.protocol = protocol
        self.api_mode = api_mode
        self.pan_id = pan_id
        self.channel = channel
        self.role = role
        self.max_in_flight = max_in_flight
        self.status_timeout = status_timeout
        self.receive_queue = receive_queue
        self.reopen_min = reopen_min
        self.reopen_max = reopen_max
        self.watchdog_interval = watchdog_interval
        self.close_timeout = close_timeout
        """s. How long `close()` waits for digi-xbee's close before abandoning it."""
        self.counters: Counter[str] = Counter()
        self._events = ChannelEvents("xbee", self.counters, log)
        self._max_payload = MAX_PAYLOAD[protocol]
        self._init_radio_state(SendWindow(max_in_flight=max_in_flight, queue_size=send_queue,
                                          status_timeout=status_timeout))

    def _init_radio_state(self, window: SendWindow) -> None:
        """The radio (none open yet), whether it is up, and what is in flight on it."""
        self.info: RadioInfo | None = None
        self._radio: DeviceThread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._up = False
        self._closing = False
        self._down_since = 0.0
        self._reopener: Reopener | None = None
        self._watchdog: asyncio.TimerHandle | None = None
        self._window = window
        self._status_timer: asyncio.TimerHandle | None = None
        self._reassembler = fragment.Reassembler()
        self._on_frame: FrameCallback | None = None

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

    # -- lifecycle ----------------------------------------------------------------------
    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None:
        """Open the radio and check it against the config. A radio whose settings
        differ raises `RadioMismatch`, one that refuses a setting the transport makes
        `RadioRefused` (both `RadioSetupError`: the daemon does not start); a missing
        or silent one is reported as `transport_down` and retried in the background
        (the daemon keeps running)."""
        self._loop = asyncio.get_running_loop()
        self._events.callback = on_event
        self._on_frame = on_frame
        self._radio = DeviceThread(
            port=self.port, baud=self.baud,
            settings=RadioSettings(self.protocol, self.api_mode, self.pan_id, self.channel,
                                   self.role),
            write_timeout=self.status_timeout, receive_queue=self.receive_queue,
            counters=self.counters, loop=self._loop, on_frame=self._received,
            on_status=self._on_status, on_hangup=self._reader_reported_hangup)
        self._reopener = Reopener(f"XBee {self.port}", self._open, self.counters,
                                  minimum=self.reopen_min, maximum=self.reopen_max,
                                  describe=_describe, on_failure=self._reopen_failed,
                                  on_success=self._reopened, logger=log)
        try:
            await self._open()
        except RadioSetupError:
            self._radio.shutdown()
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
        if self._radio is not None:
            if not await self._radio.close(self.close_timeout):
                self.counters["close_timeout"] += 1
                log.error("XBee %s: closing the radio did not finish in %.1f s; "
                          "abandoned (its thread is left behind)", self.port,
                          self.close_timeout)
            self._radio.shutdown()

    async def _open(self) -> None:
        assert self._radio is not None
        info = await self._radio.open()
        self.info = info
        self._max_payload = info.max_payload
        self._up = True
        self._events.emit(XBeeUp(self.port, info.protocol, f"0x{info.pan_id:04X}",
                                 f"0x{info.channel:02X}", f"{info.address64:016X}",
                                 info.max_payload))

    def _reopen_failed(self, exc: Exception) -> None:
        if isinstance(exc, RadioSetupError):
            self._events.emit(ChannelError("xbee", str(exc)))

    def _reopened(self) -> None:
        log.warning("XBee %s back after %.1f s", self.port, time.monotonic() - self._down_since)

    def _went_down(self, reason: str) -> None:
        if not self._up and self._down_since:
            return
        self._up = False
        self._down_since = time.monotonic()
        self.counters["outages"] += 1
        log.warning("XBee %s down: %s", self.port, reason)
        self._events.emit(ChannelDown("xbee", self.port, reason))
        self._drop_in_flight("radio down")
        if self._radio is not None:
            self._radio.close_soon()
        if self._reopener is not None:
            self._reopener.lost()

    def _arm_watchdog(self) -> None:
        assert self._loop is not None
        self._watchdog = self._loop.call_later(self.watchdog_interval, self._check_alive)

    def _check_alive(self) -> None:
        """Notice a pulled radio even while nothing is being sent (`DeviceThread.trouble`)."""
        if self._closing:
            return
        if self._up and self._radio is not None:
            reason = self._radio.trouble()
            if reason is not None:
                self._went_down(reason)
        self._arm_watchdog()

    def _reader_reported_hangup(self) -> None:
        if self._up and not self._closing:
            self._went_down(f"{self.port} hung up (reads return no data: radio or "
                            "emulator gone?)")

    # -- send -------------------------------------------------------------------------------
    def send(self, frame: bytes) -> None:
        """Queue one broadcast (in fragments if it exceeds the payload limit); never
        blocks and never raises (base.py)."""
        try:
            datagrams = fragment.split(frame, self._max_payload, fragment.new_msg_id())
        except fragment.FragmentError:
            self._events.send_error(SendFailure.OVERSIZE, "oversize", size=len(frame),
                                    limit=self._max_payload)
            return
        if not self._up:
            self._events.send_error(SendFailure.DOWN, "radio down")
            return
        if len(datagrams) > 1:
            self.counters["fragmented"] += 1
        for datagram in datagrams:
            if self._window.offer(datagram):
                self._events.send_error(SendFailure.NO_BUFFER, "queue full")
        self._pump()

    def _received(self, datagram: bytes) -> None:
        """On the loop (DeviceThread hands over): fragments in, whole frames out."""
        assert self._loop is not None
        r = self._reassembler
        before = sum(r.drops.values())
        frame = r.feed(datagram, self._loop.time())
        if sum(r.drops.values()) != before:
            for reason, n in r.drops.items():
                self.counters[f"fragment_drop:{reason}"] = n
        if frame is not None and self._on_frame is not None:
            self._on_frame(frame)

    def _pump(self) -> None:
        if self._up:
            assert self._loop is not None and self._radio is not None
            for frame_id, frame in self._window.take(self._loop.time()):
                self._radio.write(frame_id, frame).add_done_callback(self._after_write)
                self.counters["sent"] += 1
        self._arm_status_timer()

    def _arm_status_timer(self) -> None:
        """One timer, at the window's next status deadline."""
        deadline = self._window.next_deadline()
        timer = self._status_timer
        if timer is not None and not timer.cancelled() and timer.when() == deadline:
            return
        if timer is not None:
            timer.cancel()
        self._status_timer = None
        if deadline is not None:
            assert self._loop is not None
            self._status_timer = self._loop.call_at(deadline, self._on_status_timeout)

    def _after_write(self, future: asyncio.Future[None]) -> None:
        if future.cancelled():
            return
        exc = future.exception()
        if exc is not None and self._up:
            self._went_down(f"write failed: {_describe(exc)}")

    def _on_status(self, frame_id: int, status: int) -> None:
        if not self._window.status(frame_id):
            return  # late status of a frame already given up
        if status == 0:
            self.counters["delivered"] += 1
        else:
            self._events.send_error(
                SendFailure.REFUSED,
                _STATUS_TEXT.get(status, f"transmit status 0x{status:02X}"), status=status)
        self._pump()

    def _on_status_timeout(self) -> None:
        assert self._loop is not None
        self._status_timer = None
        for _ in self._window.expire(self._loop.time()):
            self._events.send_error(SendFailure.TIMEOUT, "no transmit status")
        if self._window.stalled:
            self._went_down("radio stopped answering (no transmit status 3 times)")
        else:
            self._pump()

    def _drop_in_flight(self, reason: str) -> None:
        lost = self._window.reset()
        if lost:
            self.counters[f"lost ({reason})"] += lost
        if self._status_timer is not None:
            self._status_timer.cancel()
            self._status_timer = None


_STATUS_TEXT = {
    0x01: "MAC ACK failure", 0x02: "CCA failure (channel busy)", 0x21: "network ACK failure",
    0x22: "not joined to network", 0x23: "self-addressed", 0x24: "address not found",
    0x25: "route not found", 0x26: "no neighbour relayed the broadcast",
    0x31: "internal resource error", 0x32: "resource error (no free buffers)",
    0x74: "payload too large", 0x75: "indirect message unrequested",
    0xFF: "transmit status unknown to digi-xbee",
}
"""Names of the delivery statuses in the XBee 3 guides' Transmit Status (0x8B / 0x89)."""


def _describe(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if type(exc).__name__ not in text else text
