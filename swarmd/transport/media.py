"""What each medium carries: the XBee protocol names and every payload limit.

The one table the transports, `swarmd check`'s channel budget (budget.py) and the XBee
emulator read, so a limit changes in one place.
"""

from __future__ import annotations

PROTOCOLS = ("zigbee", "802.15.4", "digimesh")
"""The XBee protocols swarmd runs over, by the names configs use."""

PROTOCOL_NAMES = {"ZIGBEE": "zigbee", "RAW_802_15_4": "802.15.4", "DIGI_MESH": "digimesh"}
"""digi-xbee's `XBeeProtocol` member names -> our protocol names."""

MAX_PAYLOAD = {"zigbee": 92, "802.15.4": 100, "digimesh": 73}
"""Largest broadcast payload per XBee protocol, unencrypted (Digi's XBee 3 manuals)."""

MAX_PAYLOAD_ENCRYPTED = {"zigbee": 74, "802.15.4": 95, "digimesh": 65}
"""The same with encryption on (EE=1): the security headers take the difference."""

SERIAL_MAX_PAYLOAD = 64
"""Largest datagram (a swarmd frame, or a fragment of a larger one: fragment.py) on a
transparent serial radio: after framing (+7 B) it still fits one RF packet of the
smallest radio payload in use (DigiMesh 73 B), so radios never split a datagram and
packets of two senders cannot interleave inside one."""

UDP_MAX_PAYLOAD = 1472
"""A UDP datagram that fits a 1500-byte Ethernet MTU (IPv4 20 B + UDP 8 B headers)."""
