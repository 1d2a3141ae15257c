"""UDP multicast transport: the channel for `sim`, tests and Wi-Fi swarms.

One socket per daemon, bound to the group address so that it receives only this group's
datagrams, with SO_REUSEADDR and SO_REUSEPORT so that many daemons on one host share the
port (every one gets a copy of every multicast datagram). Sending goes to the group with
IP_MULTICAST_IF, TTL and loopback taken from the config; the defaults (interface
127.0.0.1, TTL 1, loopback on) keep every frame on this host (DESIGN section 4: nothing
the project starts by default may send to another address).

The transport never interprets frames; a daemon hears its own frames back (loopback) and
the core drops them by sender id.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
from dataclasses import dataclass
from typing import Any, ClassVar

from swarmd.transport.addresses import (
    DEFAULT_GROUP,
    DEFAULT_INTERFACE,
    DEFAULT_PORT,
    DEFAULT_TTL,
    interface_address,
    multicast_group,
)
from swarmd.transport.base import (
    ChannelError,
    ChannelEvents,
    ChannelUp,
    EventCallback,
    FrameCallback,
    SendFailure,
    TransportError,
    failure_of,
)
from swarmd.transport.media import UDP_MAX_PAYLOAD

log = logging.getLogger(__name__)

# Never fragmented on any real link (media.py). swarmd frames are ~23 bytes, far below.
MAX_PAYLOAD = UDP_MAX_PAYLOAD


# Datagrams read per readiness event: under a flood this bounds how long one read keeps
# the loop (the runtime's queue absorbs the batch); when idle it is one read.
READ_BATCH = 32
RECV_SIZE = 2048  # > MAX_PAYLOAD; a larger datagram is truncated and fails to decode


_HINTS = {
    errno.ENODEV: " (transport.interface must be an IPv4 address of this host's "
                  "interfaces, e.g. 127.0.0.1 or the robot's Wi-Fi address)",
    errno.EADDRNOTAVAIL: " (transport.interface must be an IPv4 address of this host)",
    errno.EADDRINUSE: " (another program holds transport.port without SO_REUSEPORT; "
                      "pick another port or stop it)",
}
"""Set-up errors whose errno alone does not tell the operator which field to fix."""


@dataclass(frozen=True, slots=True)
class UdpUp(ChannelUp):
    """The socket is open on `group`:`port`, sending through `interface`."""

    kind: ClassVar[str] = "udp"
    group: str
    port: int
    interface: str


class UdpTransport:
    """Broadcast frames to an IPv4 multicast group. See the module docstring."""

    def __init__(
        self,
        *,
        group: str = DEFAULT_GROUP,
        port: int = DEFAULT_PORT,
        interface: str = DEFAULT_INTERFACE,
        ttl: int = DEFAULT_TTL,
        loopback: bool = True,
    ) -> None:
        try:
            multicast_group(group)
        except ValueError as exc:
            raise TransportError(f"udp group {exc}") from None
        try:
            interface_address(interface)
        except ValueError as exc:
            raise TransportError(f"udp interface {exc}") from None
        if not 0 < port < 65536:
            raise TransportError(f"udp port {port} is out of range 1..65535")
        if not 0 <= ttl <= 255:
            raise TransportError(f"udp ttl {ttl} is out of range 0..255")
        self.group = group
        self.port = port
        self.interface = interface
        self.ttl = ttl
        self.loopback = loopback
        self.counters: dict[str, int] = {"sent": 0, "received": 0, "send_errors": 0,
                                         "receive_errors": 0}
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_frame: FrameCallback | None = None
        self.send_reasons: dict[str, int] = {}
        """Send errors by `SendFailure` (`send_error:<failure>`); their total is in
        `counters`."""
        self._events = ChannelEvents("udp", self.send_reasons, log)

    @classmethod
    def from_config(cls, cfg: Any) -> UdpTransport:
        """Build from the robot file's `transport: {kind: udp, ...}` model."""
        return cls(group=cfg.group, port=cfg.port, interface=cfg.interface, ttl=cfg.ttl,
                   loopback=cfg.loopback)

    @property
    def max_payload(self) -> int:
        return MAX_PAYLOAD

    def _socket(self) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            # Several daemons on one host (sim, tests) all bind the same group:port.
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            # Binding the group (not INADDR_ANY) filters out other groups on the port.
            sock.bind((self.group, self.port))
            iface = socket.inet_aton(self.interface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                            socket.inet_aton(self.group) + iface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, iface)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, self.ttl)
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, int(self.loopback))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise TransportError(
                f"cannot open udp multicast {self.group}:{self.port} on interface "
                f"{self.interface}: {exc}{_HINTS.get(exc.errno or 0, '')}"
            ) from exc
        return sock

    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None:
        """Open the socket, join the group, deliver datagrams to `on_frame`."""
        self._on_frame = on_frame
        self._events.callback = on_event
        self._loop = asyncio.get_running_loop()
        self._sock = self._socket()
        # A plain reader rather than asyncio's datagram transport: that one allocates a
        # 256 KiB buffer per datagram, which dominates an idle daemon's CPU time
        # (bench/bench_daemon.py); our frames are tens of bytes.
        self._loop.add_reader(self._sock.fileno(), self._read_ready)
        self._events.emit(UdpUp(self.group, self.port, self.interface))

    def _read_ready(self) -> None:
        sock, on_frame, counters = self._sock, self._on_frame, self.counters
        if sock is None:
            return
        for _ in range(READ_BATCH):
            try:
                data = sock.recv(RECV_SIZE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. ICMP errors reported on the socket
                self._error("receive", exc)
                return
            counters["received"] += 1
            if on_frame is not None:
                on_frame(data)

    def send(self, frame: bytes) -> None:
        """Broadcast one frame to the group; errors are counted and reported, never raised."""
        if self._sock is None:
            self._fail_send(SendFailure.NOT_OPEN, "transport not open")
            return
        if len(frame) > MAX_PAYLOAD:
            self._fail_send(SendFailure.OVERSIZE, "oversize", size=len(frame),
                            limit=MAX_PAYLOAD)
            return
        try:
            self._sock.sendto(frame, (self.group, self.port))
        except BlockingIOError:
            # Socket buffer full: drop rather than queue. A heartbeat is only worth
            # sending now; the next one follows within a period.
            self._fail_send(SendFailure.NO_BUFFER, "socket buffer full")
            return
        except OSError as exc:
            self._fail_send(failure_of(exc), str(exc))
            return
        self.counters["sent"] += 1

    def _fail_send(self, reason: SendFailure, detail: str, *, size: int | None = None,
                   limit: int | None = None) -> None:
        self.counters["send_errors"] += 1
        self._events.send_error(reason, detail, size=size, limit=limit)

    def _error(self, where: str, exc: Exception) -> None:
        # ICMP errors and the like arrive here; they never stop the socket, so count
        # them and tell the daemon's log (transport contract).
        self.counters["receive_errors"] += 1
        self._events.emit(ChannelError("udp", str(exc), where))

    async def close(self) -> None:
        """Leave the group and close the socket."""
        if self._sock is not None:
            if self._loop is not None:
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
