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
- `on_event(condition, fields)` reports channel conditions (a `Channel`) for the
  daemon's log and the monitor, e.g. (Channel.DOWN, {"kind": ..., "reason": ...}). Every
  transport reports through a `ChannelEvents`, which names its kind on send errors and
  keeps a raising callback out of its I/O path.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Mapping, MutableMapping
from enum import StrEnum
from typing import Any, Protocol


class Channel(StrEnum):
    """A channel condition a transport reports (a `StrEnum`: its value is the name the
    daemon's log prints, `channel: transport_down`)."""

    UP = "transport_up"
    """Open and carrying frames (again)."""
    DOWN = "transport_down"
    """Not carrying frames (a radio unplugged); the transport retries by itself."""
    ERROR = "transport_error"
    """Something failed that does not stop the channel (an ICMP error on receive)."""
    SEND_ERROR = "send_error"
    """A frame could not go out (queue full, radio down, oversize); counted, dropped."""


FrameCallback = Callable[[bytes], None]
EventCallback = Callable[[Channel, Mapping[str, Any]], None]


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

    def __init__(self, kind: str, counters: Counter[str] | MutableMapping[str, int],
                 logger: logging.Logger) -> None:
        self.kind = kind
        self.counters = counters
        self.logger = logger
        self.callback: EventCallback | None = None
        """Set by the transport's `start`; events before it are dropped."""

    def emit(self, name: Channel, fields: Mapping[str, Any]) -> None:
        """Report one channel condition, e.g. (Channel.DOWN, {"reason": ...})."""
        if self.callback is None:
            return
        try:
            self.callback(name, fields)
        except Exception:
            self.logger.exception("on_event raised")

    def send_error(self, reason: str, **fields: Any) -> None:
        """A frame that could not go out: counted and reported, never raised (rules)."""
        key = f"send_error:{reason}"
        self.counters[key] = self.counters.get(key, 0) + 1
        self.emit(Channel.SEND_ERROR, {"kind": self.kind, "reason": reason, **fields})
