"""The UDP transport's addresses: its defaults, written once here for the transport, the
robot file, `swarmd monitor` and the simulator, and the checks shared by the transport's
constructor and the robot file's validation (swarmd/config/robot.py), so both accept and
refuse the same values with the same words. Plain functions raising `ValueError`; no I/O."""

from __future__ import annotations

import ipaddress

DEFAULT_GROUP = "239.255.77.7"
"""An administratively scoped group (239.0.0.0/8, RFC 2365): never routed off-site."""
DEFAULT_PORT = 47007
DEFAULT_INTERFACE = "127.0.0.1"
"""Loopback unless the robot file names this robot's address on the swarm's network."""
DEFAULT_TTL = 1
"""One hop: frames never leave the local network (the swarm is one broadcast domain)."""


def multicast_group(value: str) -> str:
    """`value` if it is an IPv4 multicast group (224.0.0.0/4); `ValueError` otherwise.
    The transport binds to the group (module docstring of udp.py): a unicast address
    there would receive nothing."""
    try:
        addr = ipaddress.IPv4Address(value)
    except ValueError:
        raise ValueError(f"{value!r} is not an IPv4 address") from None
    if not addr.is_multicast:
        raise ValueError(f"{value} is not a multicast group (224.0.0.0/4)")
    return value


def interface_address(value: str) -> str:
    """`value` if it is an IPv4 address: IP_MULTICAST_IF takes the address of the
    interface to send from, not its name (``eth0``)."""
    try:
        ipaddress.IPv4Address(value)
    except ValueError:
        raise ValueError(f"{value!r} is not an IPv4 interface address (IP_MULTICAST_IF "
                         "takes the interface's address, e.g. 127.0.0.1, not its name)"
                         ) from None
    return value
