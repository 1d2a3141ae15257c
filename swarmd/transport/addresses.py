"""Checks of the UDP transport's addresses, shared by the transport's constructor and
the robot file's validation (swarmd/config/robot.py), so both accept and refuse the same
values with the same words. Plain functions raising `ValueError`; no I/O."""

from __future__ import annotations

import ipaddress


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
