"""The XBee emulator driven by a second, independent client library (python-xbee).

digi-xbee is what swarmd uses; python-xbee (`xbee` on PyPI) speaks the legacy 802.15.4
frames other programs use: TX16 (0x01) to 0xFFFF to broadcast, answered by a TX status
(0x89), received as 0x80 / 0x81, and remote AT commands (0x17 -> 0x97). A swarmd
transport on the same emulated channel must hear that client, and the client must hear
swarmd.
"""

from __future__ import annotations

import queue
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_xbee_transport import Sink

from sim.xbee_emu import Medium
from swarmd.core import wire
from swarmd.core.roles import Health, Role
from swarmd.transport.xbee import XBeeTransport

xbee = pytest.importorskip("xbee", reason="python-xbee (the `xbee` package) not installed")
serial = pytest.importorskip("serial")

WAIT = 5.0  # s; a bound on waiting for an answer, not a timing assertion


class Client:
    """One python-xbee XBee (802.15.4 class) on an emulated radio, frames in a queue."""

    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, 9600, timeout=0.05)
        self.frames: queue.Queue[dict[str, Any]] = queue.Queue()
        self.xb = xbee.XBee(self.port, callback=self.frames.put, escaped=False)

    def next(self, name: str, timeout: float = WAIT) -> dict[str, Any]:
        """The next frame called `name` (others on the way are skipped)."""
        while True:
            frame = self.frames.get(timeout=timeout)
            if frame["id"] == name:
                return frame

    def at(self, command: bytes, value: bytes | None = None) -> dict[str, Any]:
        kwargs: dict[str, Any] = {"frame_id": b"\x07", "command": command}
        if value is not None:
            kwargs["parameter"] = value
        self.xb.at(**kwargs)
        return self.next("at_response")

    def close(self) -> None:
        self.xb.halt()
        self.port.close()


@pytest.fixture
def medium(tmp_path: Path) -> Iterator[Medium]:
    with Medium(3, protocol="802.15.4", directory=tmp_path) as m:
        yield m


@pytest.fixture
def clients(medium: Medium) -> Iterator[list[Client]]:
    made: list[Client] = []
    yield made
    for c in made:
        c.close()


def heartbeat(sender: int, seq: int) -> bytes:
    return wire.encode(wire.Frame(1, sender, seq, wire.Heartbeat(1, 0, Role.ACTIVE,
                                                                 Health.OK)))


async def test_tx16_broadcast_reaches_swarmd_and_swarmd_reaches_the_client(
        medium: Medium, clients: list[Client]) -> None:
    other = Client(medium.path(1))
    clients.append(other)
    # 64-bit source addressing, as every radio in a swarmd swarm must run (docs/radios.md):
    # with a 16-bit MY the frames arrive as 0x81, which stalls digi-xbee's reader.
    assert other.at(b"MY", b"\xff\xfe")["status"] == b"\x00"
    ours = XBeeTransport(port=medium.path(2), pan_id=0x607, role="router")
    sink = Sink()
    await ours.start(sink.frame, sink.event)
    try:
        frame = heartbeat(5, 100)
        other.xb.tx(frame_id=b"\x01", dest_addr=b"\xff\xff", data=frame)
        status = other.next("tx_status")
        assert status["frame_id"] == b"\x01" and status["status"] == b"\x00"
        await sink.until(lambda: sink.frames)
        assert sink.frames == [frame]
        assert wire.decode(sink.frames[0]).sender == 5

        back = heartbeat(6, 200)
        ours.send(back)
        got = other.next("rx_long_addr")
        assert got["rf_data"] == back
        assert got["source_addr"] == medium.radios[2].address64.to_bytes(8, "big")
        assert got["options"][0] & 0x02  # address broadcast
        await sink.until(lambda: ours.counters["delivered"] == 1)
    finally:
        await ours.close()


def test_tx16_unicast_by_my_address_and_no_ack(medium: Medium,
                                               clients: list[Client]) -> None:
    a, b = Client(medium.path(1)), Client(medium.path(2))
    clients += [a, b]
    assert a.at(b"MY", b"\x00\x01")["status"] == b"\x00"
    assert b.at(b"MY", b"\x00\x02")["status"] == b"\x00"
    a.xb.tx(frame_id=b"\x02", dest_addr=b"\x00\x02", data=b"to two")
    assert a.next("tx_status")["status"] == b"\x00"
    got = b.next("rx")  # 0x81: the sender has a 16-bit MY
    assert got["source_addr"] == b"\x00\x01" and got["rf_data"] == b"to two"
    assert not got["options"][0] & 0x02
    # Nobody has MY=0x0009: the MAC gets no acknowledgement.
    a.xb.tx(frame_id=b"\x03", dest_addr=b"\x00\x09", data=b"to nobody")
    assert a.next("tx_status")["status"] == b"\x01"
    # TX64 (0x00) to radio 2's 64-bit address: status 0x89, received as 0x81 (MY set).
    a.xb.tx_long_addr(frame_id=b"\x04",
                      dest_addr=medium.radios[2].address64.to_bytes(8, "big"), data=b"64")
    assert a.next("tx_status")["status"] == b"\x00"
    assert b.next("rx")["rf_data"] == b"64"


def test_remote_at_command(medium: Medium, clients: list[Client]) -> None:
    a = Client(medium.path(1))
    clients.append(a)
    target = medium.radios[3].address64.to_bytes(8, "big")
    a.xb.remote_at(frame_id=b"\x05", dest_addr_long=target, command=b"NI")
    got = a.next("remote_at_response")
    assert (got["status"], got["parameter"], got["source_addr_long"]) == (
        b"\x00", b"robot3", target)
    # Options 0x02 applies at once; without it the change waits for AC.
    a.xb.remote_at(frame_id=b"\x06", dest_addr_long=target, options=b"\x00",
                   command=b"CH", parameter=b"\x0f")
    assert a.next("remote_at_response")["status"] == b"\x00"
    assert medium.radios[3].params["CH"] == b"\x0c"  # queued, not applied
    a.xb.remote_at(frame_id=b"\x07", dest_addr_long=target, options=b"\x02",
                   command=b"ID", parameter=b"\x12\x34")
    assert a.next("remote_at_response")["status"] == b"\x00"
    assert medium.radios[3].params["ID"] == b"\x12\x34"
    # Radio 3 is now on another PAN: it no longer hears radio 1, so no answer (0x04),
    # as for a radio that is not there at all.
    for fid, dest in ((b"\x08", target), (b"\x09", b"\x00\x13\xa2\x00\x00\x00\x00\x63")):
        a.xb.remote_at(frame_id=fid, dest_addr_long=dest, command=b"NI")
        assert a.next("remote_at_response")["status"] == b"\x04"


def test_a_frame_type_the_firmware_does_not_take_is_ignored(
        tmp_path: Path, medium: Medium, clients: list[Client]) -> None:
    a, b = Client(medium.path(1)), Client(medium.path(2))
    clients += [a, b]
    a.xb._write(b"\x11\x0a" + bytes(20))  # 0x11 explicit addressing: Zigbee only
    # The radio answers nothing and goes on: the next AT command is the next answer.
    assert a.at(b"NI")["parameter"] == b"robot1"
    assert medium.radios[1].counters["unsupported_frame"] == 1
    assert b.frames.empty()

    with Medium(2, protocol="zigbee", directory=tmp_path / "zb") as zigbee:
        c = Client(zigbee.path(1))
        try:
            c.xb.tx(frame_id=b"\x01", dest_addr=b"\xff\xff", data=b"legacy")  # 0x01
            assert c.at(b"NI")["parameter"] == b"robot1"
        finally:
            c.close()  # before its radio goes away
        assert zigbee.radios[1].counters["unsupported_frame"] == 1
        assert zigbee.delivered == 0
