"""Transparent serial radios through pyserial-asyncio.

For an XBee in transparent mode (AP=0, the paper's DH/DL 0x0000/0xFFFF broadcast
setting on every robot) or a SiK telemetry radio: whatever is written comes out of
every other radio's UART as a byte stream, packetised, merged and maybe corrupted by
the radios. Frames are therefore COBS-delimited and CRC-checked (`framing.py`), so the
receiver yields exactly the good frames and counts the rest. A swarmd frame larger than
`max_payload` (a per-robot signed frame on a radio with small packets) goes out in
fragments, each framed on its own, and is put back together on receipt (`fragment.py`;
drops counted as `fragment_drop:<reason>`).

The port is opened on the event loop by pyserial-asyncio (non-blocking fd, no thread).
A lost port (USB pulled) is reported as `transport_down` and reopened with back-off
(`reopen.py`).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any, ClassVar

from swarmd.transport import fragment, framing
from swarmd.transport.base import (
    ChannelDown,
    ChannelEvents,
    ChannelUp,
    EventCallback,
    FrameCallback,
    SendFailure,
    TransportError,
    failure_of,
)
from swarmd.transport.media import SERIAL_MAX_PAYLOAD
from swarmd.transport.reopen import Reopener

log = logging.getLogger(__name__)

DEFAULT_MAX_PAYLOAD = SERIAL_MAX_PAYLOAD
"""Largest datagram (a frame or a fragment; media.py: one RF packet after framing)."""


@dataclass(frozen=True, slots=True)
class SerialUp(ChannelUp):
    """`port` is open at `baud`, carrying datagrams of up to `max_payload` bytes."""

    kind: ClassVar[str] = "serial"
    port: str
    baud: int
    max_payload: int


class _Protocol(asyncio.Protocol):
    def __init__(self, owner: SerialTransport) -> None:
        self.owner = owner

    def data_received(self, data: bytes) -> None:
        self.owner._on_bytes(data)

    def connection_lost(self, exc: Exception | None) -> None:
        self.owner._on_lost(exc)


class SerialTransport:
    """Broadcast frames over a transparent serial radio (see the module docstring)."""

    def __init__(
        self,
        *,
        port: str,
        baud: int = 57600,
        max_payload: int = DEFAULT_MAX_PAYLOAD,
        write_buffer_limit: int = 4096,
        reopen_min: float = 0.5,
        reopen_max: float = 10.0,
    ) -> None:
        if not 1 <= max_payload <= framing.MAX_FRAME:
            raise TransportError(f"max_payload must be 1..{framing.MAX_FRAME}")
        self.port = port
        self.baud = baud
        self._max_payload = max_payload
        self.write_buffer_limit = write_buffer_limit
        self.reopen_min = reopen_min
        self.reopen_max = reopen_max
        self.counters: Counter[str] = Counter()
        self._events = ChannelEvents("serial", self.counters, log)
        self.decoder = framing.FrameDecoder(max_frame=max(max_payload, 255))
        self._transport: asyncio.Transport | None = None
        self._on_frame: FrameCallback | None = None
        self._closing = False
        self._reopener: Reopener | None = None
        self._reassembler = fragment.Reassembler()

    @classmethod
    def from_config(cls, cfg: Any) -> SerialTransport:
        """Build from `swarmd.config.SerialTransportConfig` (duck-typed)."""
        return cls(port=cfg.port, baud=cfg.baud,
                   max_payload=getattr(cfg, "max_payload", DEFAULT_MAX_PAYLOAD))

    @property
    def max_payload(self) -> int:
        return self._max_payload

    @property
    def up(self) -> bool:
        return self._transport is not None

    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None:
        """Open the port. A missing port is reported and retried, not raised: the
        daemon keeps running until the radio is plugged in."""
        self._on_frame, self._events.callback = on_frame, on_event
        self._reopener = Reopener(f"serial {self.port}", self._open, self.counters,
                                  minimum=self.reopen_min, maximum=self.reopen_max,
                                  logger=log)
        try:
            await self._open()
        except Exception as exc:
            self._events.emit(ChannelDown("serial", self.port, f"cannot open: {exc}"))
            self._reopener.lost()
        self._reopener.start()

    async def _open(self) -> None:
        import serial_asyncio

        loop = asyncio.get_running_loop()
        transport, _ = await serial_asyncio.create_serial_connection(
            loop, lambda: _Protocol(self), self.port, baudrate=self.baud)
        self._transport = transport
        self.decoder = framing.FrameDecoder(max_frame=max(self._max_payload, 255))
        self._events.emit(SerialUp(self.port, self.baud, self._max_payload))

    async def close(self) -> None:
        self._closing = True
        if self._reopener is not None:
            await self._reopener.close()
        transport, self._transport = self._transport, None
        if transport is not None:
            transport.close()
            await asyncio.sleep(0)  # let connection_lost run before the loop goes

    def send(self, frame: bytes) -> None:
        """Write one framed broadcast (in fragments if it exceeds `max_payload`); never
        blocks and never raises (base.py)."""
        try:
            datagrams = fragment.split(frame, self._max_payload, fragment.new_msg_id())
        except fragment.FragmentError:
            self._events.send_error(SendFailure.OVERSIZE, "oversize", size=len(frame),
                                    limit=self._max_payload)
            return
        transport = self._transport
        if transport is None:
            self._events.send_error(SendFailure.DOWN, "radio down")
            return
        if transport.get_write_buffer_size() > self.write_buffer_limit:
            # The radio's flow control or baud rate cannot keep up: shed load rather
            # than queue stale heartbeats without bound.
            self._events.send_error(SendFailure.NO_BUFFER, "write buffer full")
            return
        if len(datagrams) > 1:
            self.counters["fragmented"] += 1
        try:
            # One write: the fragments of a frame leave back to back.
            transport.write(b"".join(framing.encode(d) for d in datagrams))
        except Exception as exc:
            self._events.send_error(failure_of(exc), f"write failed: {exc}")
            return
        self.counters["sent"] += 1

    def _on_bytes(self, data: bytes) -> None:
        before = sum(self.decoder.drops.values())
        r = self._reassembler
        dropped_fragments = sum(r.drops.values())
        for datagram in self.decoder.feed(data):
            self.counters["received"] += 1
            frame = r.feed(datagram, time.monotonic())
            if frame is not None and self._on_frame is not None:
                try:
                    self._on_frame(frame)
                except Exception:
                    log.exception("on_frame raised")
        if sum(r.drops.values()) != dropped_fragments:
            for reason, n in r.drops.items():
                self.counters[f"fragment_drop:{reason}"] = n
        dropped = sum(self.decoder.drops.values()) - before
        if dropped:
            self.counters["bad_chunks"] += dropped

    def _on_lost(self, exc: Exception | None) -> None:
        self._transport = None
        if self._closing:
            return
        reason = str(exc) if exc else "port closed"
        log.warning("serial %s down: %s", self.port, reason)
        self._events.emit(ChannelDown("serial", self.port, reason))
        if self._reopener is not None:
            self._reopener.lost()

