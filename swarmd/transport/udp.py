"""UDP multicast transport: the channel for `sim`, tests and Wi-Fi swarms.

Two sockets per daemon. The receiving one is bound to the group address so that it
receives only this group's datagrams, with SO_REUSEADDR and SO_REUSEPORT so that many
daemons on one host share the port (every one gets a copy of every multicast datagram).
The sending one is bound to the interface's address on a port of its own and sends to
the group with IP_MULTICAST_IF, TTL and loopback taken from the config; the defaults
(interface 127.0.0.1, TTL 1, loopback on) keep every frame on this host (DESIGN section
4: nothing the project starts by default may send to another address). The receiving
socket carries the same options, so nothing it could send would leave the host either.

With loopback on, the kernel hands every frame we send back to our receiving socket.
Sent from a socket of its own, our frames carry its address and port as their source, and
a filter on the receiving socket drops exactly those in the kernel (`socket_filter.py`,
Linux), so our own heartbeats no longer wake the daemon. A frame in our name from anyone
else (another daemon with our id) is never filtered: the core and the runtime judge it.
Given `unheard` (`SwarmPlan.unheard`), the same filter drops the heartbeats about slots
this robot does not hear, which the core would drop first thing (DESIGN section 2, "What
a robot hears"): the traffic of the rest of a swarm no longer wakes it either. Where no
filter can be attached (another platform; for our echoes, an interface of 0.0.0.0, which
gives our frames no single source address) those frames reach the core as before.
The transport reads only those header fields, for that filter; it never interprets frames.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
from dataclasses import dataclass
from typing import Any, ClassVar

from swarmd.core.plan import Unheard
from swarmd.transport import socket_filter
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
        unheard: Unheard | None = None,
        kernel_filter: bool = True,
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
        self.unheard = unheard
        self.kernel_filter = kernel_filter
        """False: no socket filter, every datagram on the group reaches `on_frame`, our
        own too (a simulated insider's radio records all it hears: sim/realtime)."""
        self.counters: dict[str, int] = {"sent": 0, "received": 0, "send_errors": 0,
                                         "receive_errors": 0}
        self._sock: socket.socket | None = None
        """The receiving socket, on the group."""
        self._out: socket.socket | None = None
        """The sending socket, on the interface's address and a port of its own."""
        self.echoes_filtered = False
        """Our own frames are dropped in the kernel (module docstring)."""
        self.unheard_filtered = False
        """The heartbeats of `unheard` are dropped in the kernel (module docstring)."""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_frame: FrameCallback | None = None
        self.send_reasons: dict[str, int] = {}
        """Send errors by `SendFailure` (`send_error:<failure>`); their total is in
        `counters`."""
        self._events = ChannelEvents("udp", self.send_reasons, log)

    @classmethod
    def from_config(cls, cfg: Any, *, unheard: Unheard | None = None,
                    kernel_filter: bool = True) -> UdpTransport:
        """Build from the robot file's `transport: {kind: udp, ...}` model; `unheard`:
        the heartbeats this robot's core drops unread (module docstring)."""
        return cls(group=cfg.group, port=cfg.port, interface=cfg.interface, ttl=cfg.ttl,
                   loopback=cfg.loopback, unheard=unheard, kernel_filter=kernel_filter)

    @property
    def max_payload(self) -> int:
        return MAX_PAYLOAD

    def _socket(self) -> socket.socket:
        """The receiving socket: bound to the group, joined on the interface."""
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
            self._multicast_options(sock)
        except OSError as exc:
            sock.close()
            raise self._open_error(exc) from exc
        return sock

    def _sender(self) -> socket.socket:
        """The sending socket: its own port on the interface's address, so that its
        datagrams' source is ours alone (module docstring). It reads nothing: a filter
        drops whatever reaches its port."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        try:
            sock.bind((self.interface, 0))
            self._multicast_options(sock)
        except OSError as exc:
            sock.close()
            raise self._open_error(exc) from exc
        socket_filter.attach(sock, socket_filter.DROP_ALL)
        return sock

    def _multicast_options(self, sock: socket.socket) -> None:
        """Where and how far a datagram sent on `sock` goes: the config's interface, TTL
        and loopback (the defaults keep it on this host)."""
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF,
                        socket.inet_aton(self.interface))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, self.ttl)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, int(self.loopback))
        sock.setblocking(False)

    def _open_error(self, exc: OSError) -> TransportError:
        return TransportError(
            f"cannot open udp multicast {self.group}:{self.port} on interface "
            f"{self.interface}: {exc}{_HINTS.get(exc.errno or 0, '')}")

    def _filter(self, sock: socket.socket, out: socket.socket) -> None:
        """Drop our own datagrams and the `unheard` heartbeats on `sock` in the kernel
        (module docstring); where that cannot be, a log line says why."""
        address, port = out.getsockname()
        own = None if address == "0.0.0.0" else (address, port)
        made = socket_filter.program(own, self.unheard)
        attached = made is not None and socket_filter.attach(sock, made.code)
        self.echoes_filtered = attached and own is not None
        self.unheard_filtered = attached and made is not None and made.unheard
        if not self.echoes_filtered:
            why = ("interface 0.0.0.0 gives our frames no single source address"
                   if own is None else "this system refuses a socket filter (SO_ATTACH_FILTER)")
            log.info("udp: our own frames come back through the multicast loopback and are "
                     f"dropped by the core: {why}", extra={"source": f"{address}:{port}"})
        if self.unheard is not None and not self.unheard_filtered:
            log.info("udp: the heartbeats of slots this robot does not hear reach the core, "
                     "which drops them: no socket filter for them here")

    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None:
        """Open the socket, join the group, deliver datagrams to `on_frame`."""
        self._on_frame = on_frame
        self._events.callback = on_event
        self._loop = asyncio.get_running_loop()
        self._sock = self._socket()
        try:
            self._out = self._sender()
        except TransportError:
            self._sock.close()
            self._sock = None
            raise
        if self.kernel_filter:
            self._filter(self._sock, self._out)
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
        out = self._out
        if out is None:
            self._fail_send(SendFailure.NOT_OPEN, "transport not open")
            return
        if len(frame) > MAX_PAYLOAD:
            self._fail_send(SendFailure.OVERSIZE, "oversize", size=len(frame),
                            limit=MAX_PAYLOAD)
            return
        try:
            out.sendto(frame, (self.group, self.port))
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
        """Leave the group and close both sockets."""
        if self._sock is not None:
            if self._loop is not None:
                self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        if self._out is not None:
            self._out.close()
            self._out = None
