"""The transport interface every channel implements.

A transport moves opaque frames (bytes from `swarmd.core.wire`) to every robot in range.
It never interprets them. The runtime owns exactly one transport:

    transport = UdpTransport(cfg)
    await transport.start(on_frame, on_event)   # on_frame(bytes) called on the loop thread
    transport.send(frame)                       # broadcast; never blocks the loop
    await transport.close()

Rules:
- `on_frame` and `on_event` are always called on the event loop thread (a transport
  that reads in another thread hands over with `loop.call_soon_threadsafe`).
- `send` is synchronous and non-blocking: it queues or writes at once. A frame that
  cannot go out (queue full, radio down, oversize) is counted and reported through
  `on_event`, never raised into the runtime (bad I/O never takes the daemon down).
- `max_payload` is the largest datagram the channel carries in one piece (bytes). The
  XBee and serial transports send a larger frame in fragments and reassemble it on
  receipt (`fragment.py`); `on_frame` only ever gets whole frames.
- `on_event(name, fields)` reports channel conditions for the event log and monitor,
  e.g. ("transport_down", {"reason": ...}), ("transport_up", {}).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any, Protocol

FrameCallback = Callable[[bytes], None]
EventCallback = Callable[[str, Mapping[str, Any]], None]


class TransportError(RuntimeError):
    """A transport could not be set up (bad config, no such device). Clear message."""


class Transport(Protocol):
    @property
    def max_payload(self) -> int: ...

    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None: ...

    def send(self, frame: bytes) -> None: ...

    async def close(self) -> None: ...


class ChannelEvents:
    """A transport's side of `on_event` (the rules above): `emit` passes an event on,
    `send_error` also counts it as `send_error:<reason>` and names the transport's
    `kind`. A callback that raises is logged, never propagated: it would otherwise
    surface in the transport's I/O path (a send, a status callback) and break it."""

    def __init__(self, kind: str, counters: Counter[str], logger: logging.Logger) -> None:
        self.kind = kind
        self.counters = counters
        self.logger = logger
        self.callback: EventCallback | None = None
        """Set by the transport's `start`; events before it are dropped."""

    def emit(self, name: str, fields: Mapping[str, Any]) -> None:
        """Report one channel condition, e.g. ("transport_down", {"reason": ...})."""
        if self.callback is None:
            return
        try:
            self.callback(name, fields)
        except Exception:
            self.logger.exception("on_event raised")

    def send_error(self, reason: str, **fields: Any) -> None:
        """A frame that could not go out: counted and reported, never raised (rules)."""
        self.counters[f"send_error:{reason}"] += 1
        self.emit("send_error", {"kind": self.kind, "reason": reason, **fields})
