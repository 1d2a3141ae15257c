"""The UDP multicast port of a real-time swarm, leased for as long as the swarm runs, so
that two swarms on one machine (two users' `swarmd sim`, tests running in parallel)
never hear each other.

Why a lease and not "a port that is free now": the robots of a swarm bind the group
address, `group:port`, with SO_REUSEADDR and SO_REUSEPORT (swarmd/transport/udp.py), and
the kernel lets any other socket with those options join them. A port found by binding
`127.0.0.1:0` and closing the socket again was wrong twice over:

- such a probe does not see sockets bound to the group address (a different address), so
  it could name the port a running swarm already uses;
- once the probe closed, nothing kept the next run from being handed the same port
  before, or while, the first run's robots bound it.

Either way both runs' robots shared one channel: robot 3 of one run heard robot 3 of
the other as itself, or as a rival holder of its function.

`PortLease` keeps a socket bound to `127.0.0.1:port` without any reuse option for the
run's lifetime: the kernel hands that port to no other lease (nor to any other bind of
127.0.0.1 or of every address on it) until the lease is released. The robots bind the
group address, which does not overlap 127.0.0.1, so the lease is not in their way, and
it receives no multicast. A port is only taken if nothing holds `group:port` either
(a swarm started with an explicit port, or the robots of a run that is still ending).
"""

from __future__ import annotations

import errno
import socket
from types import TracebackType

from swarmd.transport.addresses import DEFAULT_GROUP

ATTEMPTS = 64
"""Ports tried before giving up; each is one the kernel picked from its ephemeral range,
so a miss means that port's group address is in use, which is rare."""


class PortLease:
    """A UDP port for one swarm on `group`, held until `release()` (or the `with` block,
    or the process) ends. `port` is the port to write into the robots' files."""

    def __init__(self, group: str = DEFAULT_GROUP) -> None:
        self.group = group
        for _ in range(ATTEMPTS):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                # No SO_REUSEADDR / SO_REUSEPORT: an option on either socket would let
                # another lease's bind of port 0 be handed this port.
                sock.bind(("127.0.0.1", 0))
                port: int = sock.getsockname()[1]
                if _group_port_free(group, port):
                    self.port = port
                    self._sock: socket.socket | None = sock
                    return
            except BaseException:
                sock.close()
                raise
            sock.close()
        raise OSError(errno.EADDRINUSE,
                      f"no free UDP port for multicast group {group} after {ATTEMPTS} tries")

    def release(self) -> None:
        """Give the port back; idempotent. Its robots should be gone by now."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> PortLease:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.release()

    def __repr__(self) -> str:
        state = "held" if self._sock is not None else "released"
        return f"PortLease({self.group}:{self.port}, {state})"


def _group_port_free(group: str, port: int) -> bool:
    """Whether no socket is bound to `group:port` (or to every address on `port`): a bind
    without reuse options fails with EADDRINUSE next to any such socket, whatever its
    options."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((group, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                return False
            raise
    return True
