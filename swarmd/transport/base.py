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
- `on_event(event)` reports channel conditions for the daemon's log and the monitor:
  one frozen dataclass per condition (`ChannelEvent`), e.g. `ChannelDown("xbee",
  port, reason)`; its `condition` names it (a `Channel`). Every transport reports
  through a `ChannelEvents`, which names its kind on send errors, counts them by a
  bounded `SendFailure` and keeps a raising callback out of its I/O path.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
from collections import Counter
from collections.abc import Callable, MutableMapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar, Protocol


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


class SendFailure(StrEnum):
    """Why a frame did not go out, by what the transports can meet: a fixed set, so the
    counters keyed by it (`send_error:<failure>`) stay few whatever the OS says; the
    error's own words travel beside it as `SendError.detail`, for the log."""

    NOT_OPEN = "not_open"
    """The transport is not open (before `start`, after `close`)."""
    DOWN = "down"
    """The radio is unplugged or not answering, or the network is down (ENETDOWN,
    ENODEV, ENXIO): the transport reports `transport_down` and reopens by itself."""
    OVERSIZE = "oversize"
    """Larger than the channel carries, even in fragments (or EMSGSIZE)."""
    NO_BUFFER = "no_buffer"
    """A queue or buffer is full: the XBee send queue, the serial write buffer, the
    socket's (EAGAIN, ENOBUFS). A newer heartbeat follows within a period."""
    UNREACHABLE = "unreachable"
    """No route to the group (ENETUNREACH, EHOSTUNREACH, EHOSTDOWN)."""
    PERMISSION = "permission"
    """Refused by the host (EPERM, EACCES: a firewall rule)."""
    REFUSED = "refused"
    """The radio reported a failed transmit status (its code in `SendError.status`)."""
    TIMEOUT = "timeout"
    """No transmit status in time, or a write that timed out (ETIMEDOUT)."""
    OSERROR = "oserror"
    """Any other error writing (another errno, or the serial library's own)."""


_FAILURES_BY_ERRNO = {
    errno.EAGAIN: SendFailure.NO_BUFFER, errno.ENOBUFS: SendFailure.NO_BUFFER,
    errno.ENETUNREACH: SendFailure.UNREACHABLE, errno.EHOSTUNREACH: SendFailure.UNREACHABLE,
    errno.EHOSTDOWN: SendFailure.UNREACHABLE,
    errno.EPERM: SendFailure.PERMISSION, errno.EACCES: SendFailure.PERMISSION,
    errno.EMSGSIZE: SendFailure.OVERSIZE,
    errno.ENETDOWN: SendFailure.DOWN, errno.ENODEV: SendFailure.DOWN,
    errno.ENXIO: SendFailure.DOWN,
    errno.ETIMEDOUT: SendFailure.TIMEOUT,
}


def failure_of(exc: BaseException) -> SendFailure:
    """The `SendFailure` an exception raised by a write falls under."""
    if isinstance(exc, BlockingIOError):
        return SendFailure.NO_BUFFER
    if isinstance(exc, TimeoutError):
        return SendFailure.TIMEOUT
    code = exc.errno if isinstance(exc, OSError) else None
    return _FAILURES_BY_ERRNO.get(code or 0, SendFailure.OSERROR)


@dataclass(frozen=True, slots=True)
class ChannelUp:
    """Open and carrying frames (again). Each transport subclasses it with what it
    opened (`UdpUp`, `SerialUp`, `XBeeUp`), and names its `kind`."""

    condition: ClassVar[Channel] = Channel.UP
    kind: ClassVar[str]


@dataclass(frozen=True, slots=True)
class ChannelDown:
    """Not carrying frames; `reason` says why in words (the transport retries)."""

    condition: ClassVar[Channel] = Channel.DOWN
    kind: str
    port: str
    reason: str


@dataclass(frozen=True, slots=True)
class ChannelError:
    """Something failed that does not stop the channel; `where` (receive, reopen) when
    the transport tells."""

    condition: ClassVar[Channel] = Channel.ERROR
    kind: str
    reason: str
    where: str | None = None


@dataclass(frozen=True, slots=True)
class SendError:
    """A frame that did not go out: `reason` is the bounded class it is counted by,
    `detail` the error's words; the frame's `size` and the channel's `limit` when it
    was too large, the radio's `status` code when the radio refused it."""

    condition: ClassVar[Channel] = Channel.SEND_ERROR
    kind: str
    reason: SendFailure
    detail: str
    size: int | None = None
    limit: int | None = None
    status: int | None = None


ChannelEvent = ChannelUp | ChannelDown | ChannelError | SendError
"""What `on_event` gets: one class per `Channel` condition."""


def describe(event: ChannelEvent) -> dict[str, Any]:
    """The event's fields for the daemon's log: `kind` first, then those that are set."""
    out: dict[str, Any] = {"kind": event.kind}
    for f in dataclasses.fields(event):
        value = getattr(event, f.name)
        if f.name != "kind" and value is not None:
            out[f.name] = value
    return out


FrameCallback = Callable[[bytes], None]
EventCallback = Callable[[ChannelEvent], None]


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
    `send_error` also counts it as `send_error:<failure>` and names the transport's
    `kind`. A callback that raises is logged, never propagated: it would otherwise
    surface in the transport's I/O path (a send, a status callback) and break it."""

    def __init__(self, kind: str, counters: Counter[str] | MutableMapping[str, int],
                 logger: logging.Logger) -> None:
        self.kind = kind
        self.counters = counters
        self.logger = logger
        self.callback: EventCallback | None = None
        """Set by the transport's `start`; events before it are dropped."""

    def emit(self, event: ChannelEvent) -> None:
        """Report one channel condition, e.g. `ChannelDown("serial", port, reason)`."""
        if self.callback is None:
            return
        try:
            self.callback(event)
        except Exception:
            self.logger.exception("on_event raised")

    def send_error(self, reason: SendFailure, detail: str, *, size: int | None = None,
                   limit: int | None = None, status: int | None = None) -> None:
        """A frame that could not go out: counted by `reason` and reported with
        `detail`, never raised (rules)."""
        key = f"send_error:{reason}"
        self.counters[key] = self.counters.get(key, 0) + 1
        self.emit(SendError(self.kind, reason, detail, size, limit, status))
