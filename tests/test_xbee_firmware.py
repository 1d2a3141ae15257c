"""The XBee emulator answers as each firmware's user guide says (docs/radios.md tables).

Every item runs on every emulated firmware in API mode 1 and 2, with two independent
clients: raw API frames written to the radio's pty, and digi-xbee's device classes
(`Raw802Device`, `ZigBeeDevice`, `DigiMeshDevice`).
"""

from __future__ import annotations

import functools
import os
import select
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from sim.xbee_emu import Medium, api

WAIT = 3.0  # s; a bound on waiting for an answer, not a timing assertion
NOBODY = 0x0013A200DEADBEEF  # a 64-bit address no radio has
BROADCAST = 0x000000000000FFFF

FIRMWARES = ["802.15.4", "zigbee", "digimesh"]
CASES = [(fw, mode) for fw in FIRMWARES for mode in (1, 2)]
IDS = [f"{fw}-api{mode}" for fw, mode in CASES]


class Raw:
    """A client that writes API frames to a radio's pty and reads what comes back."""

    def __init__(self, path: str, api_mode: int) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self.api_mode = api_mode
        self.parser = api.FrameParser(api_mode)
        self.frames: list[bytes] = []

    def send(self, frame: bytes) -> None:
        self.write(api.encode(frame, self.api_mode))

    def write(self, raw: bytes) -> None:
        os.write(self.fd, raw)

    def expect(self, match: Callable[[bytes], bool], timeout: float = WAIT) -> bytes:
        """The first frame (read so far or still to come) that `match` accepts."""
        deadline = time.monotonic() + timeout
        while True:
            for i, frame in enumerate(self.frames):
                if match(frame):
                    return self.frames.pop(i)
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no matching frame; got {self.frames}")
            ready, _, _ = select.select([self.fd], [], [], left)
            if ready:
                self.frames += self.parser.feed(os.read(self.fd, 4096))

    def at(self, fid: int, command: bytes, value: bytes = b"", *,
           queued: bool = False) -> tuple[int, bytes]:
        """(status, value) of a local AT command (0x08, or 0x09 when `queued`)."""
        self.send(bytes((0x09 if queued else 0x08, fid)) + command + value)
        reply = self.expect(lambda f: f[:2] == bytes((0x88, fid)))
        assert reply[2:4] == command
        return reply[4], reply[5:]

    def transmit(self, fid: int, dest64: int, data: bytes, *, dest16: int = 0xFFFE,
                 options: int = 0) -> bytes:
        """Send a 0x10 Transmit Request; its 0x8B Transmit Status."""
        self.send(bytes((0x10, fid)) + dest64.to_bytes(8, "big") + dest16.to_bytes(2, "big")
                  + bytes((0, options)) + data)
        return self.expect(lambda f: f[:2] == bytes((0x8B, fid)))

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def opened() -> Iterator[list[Any]]:
    """Clients a test opened, closed at the end even when it fails."""
    made: list[Any] = []
    yield made
    for client in reversed(made):
        client.close()


def raw(medium: Medium, n: int, opened: list[Any]) -> Raw:
    client = Raw(medium.path(n), medium.radios[n].current_api_mode)
    opened.append(client)
    return client


def device(medium: Medium, n: int, opened: list[Any]) -> Any:
    """digi-xbee's device class for the medium's firmware, opened on radio n."""
    from digi.xbee.devices import DigiMeshDevice, Raw802Device, ZigBeeDevice

    cls = {"802.15.4": Raw802Device, "zigbee": ZigBeeDevice,
           "digimesh": DigiMeshDevice}[medium.radios[n].protocol]
    dev = cls(medium.path(n), 9600)
    dev.open()
    opened.append(dev)
    return dev


def status_of(frame: bytes) -> tuple[int, int, int]:
    """(16-bit field, delivery status, discovery status) of a 0x8B."""
    return int.from_bytes(frame[2:4], "big"), frame[5], frame[6]


# -- unicast to an address nobody has ---------------------------------------------------
# Digi: 802.15.4 "No ACK" (0x01); Zigbee 0x24 after an address discovery when only the
# 64-bit address is known, 0x21 for a 16-bit address nobody has, 0x23 to itself;
# DigiMesh 0x25 after a route discovery, 0x01 with point-to-multipoint (MAC ACKs only).
NOBODY_STATUS = {"802.15.4": (0xFFFE, 0x01, 0x00), "zigbee": (0xFFFD, 0x24, 0x01),
                 "digimesh": (0xFFFE, 0x25, 0x02)}


@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_unicast_to_nobody_raw(tmp_path: Path, opened: list[Any], firmware: str,
                               mode: int) -> None:
    with Medium(2, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        a = raw(medium, 1, opened)
        assert status_of(a.transmit(1, NOBODY, b"anyone?")) == NOBODY_STATUS[firmware]
        # Delivered: status 0, and on Zigbee the 16-bit address it went to.
        to2 = medium.radios[2].address64
        where, status, _ = status_of(a.transmit(2, to2, b"hi"))
        assert status == 0x00
        assert where == (medium.radios[2].my16 if firmware == "zigbee" else 0xFFFE)
        if firmware == "zigbee":
            unknown64 = 0xFFFFFFFFFFFFFFFF
            assert status_of(a.transmit(3, unknown64, b"x", dest16=0x4321)) == (
                0xFFFD, 0x21, 0x00)
            assert status_of(a.transmit(4, medium.radios[1].address64, b"me"))[1] == 0x23
            assert status_of(a.transmit(9, unknown64, b"me", dest16=0x0000))[1] == 0x23
            # 16-bit addressing reaches the radio that has that network address.
            assert status_of(a.transmit(5, unknown64, b"16", dest16=0x1002))[1] == 0x00
            # 64-bit 0 is the coordinator (radio 1); radio 2 sends to it.
            b = raw(medium, 2, opened)
            assert status_of(b.transmit(6, 0, b"coord"))[1] == 0x00
        if firmware == "digimesh":
            assert status_of(a.transmit(7, NOBODY, b"p2mp", options=0x40)) == (
                0xFFFE, 0x01, 0x00)
        # A broadcast is never acknowledged: always 0x00.
        assert status_of(a.transmit(8, BROADCAST, b"all"))[1] == 0x00


@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_unicast_to_nobody_digi_xbee(tmp_path: Path, opened: list[Any], firmware: str,
                                     mode: int) -> None:
    from digi.xbee.exception import TransmitException
    from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress

    with Medium(2, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        dev = device(medium, 1, opened)

        def send(address: int, data: bytes) -> None:
            to = XBee64BitAddress.from_hex_string(f"{address:016X}")
            if firmware == "zigbee":
                dev.send_data_64_16(to, XBee16BitAddress.UNKNOWN_ADDRESS, data)
            else:
                dev.send_data_64(to, data)

        with pytest.raises(TransmitException) as info:
            send(NOBODY, b"x")
        assert info.value.status.code == NOBODY_STATUS[firmware][1]
        send(medium.radios[2].address64, b"delivered")  # raises unless status 0x00


# -- CH and SC ------------------------------------------------------------------------
@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_channel_range_and_zigbee_scan_channels(tmp_path: Path, opened: list[Any],
                                                firmware: str, mode: int) -> None:
    ok, error, invalid_command, invalid_parameter = 0, 1, 2, 3
    with Medium(1, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        a = raw(medium, 1, opened)
        if firmware == "zigbee":
            assert a.at(1, b"CH", b"\x0f") == (error, b"")  # read-only
            assert a.at(2, b"SC") == (ok, b"\x7f\xff")
            assert a.at(3, b"SC", b"\x00\x00") == (invalid_parameter, b"")
            assert a.at(4, b"SC", b"\x00\x10") == (ok, b"")  # only channel 15
            assert a.at(5, b"CH") == (ok, b"\x0f")  # the network moved there
            assert a.at(6, b"SC", b"\x80\x10") == (ok, b"")  # 15 still allowed: stays
            assert a.at(7, b"CH") == (ok, b"\x0f")
        else:
            for bad in (b"\x05", b"\x0a", b"\x1b", b"\xff"):
                assert a.at(1, b"CH", bad) == (invalid_parameter, b"")
            assert a.at(2, b"CH", b"\x0b") == (ok, b"")
            assert a.at(3, b"CH", b"\x1a") == (ok, b"")
            assert a.at(4, b"CH") == (ok, b"\x1a")
            if firmware == "802.15.4":  # association scans only; CH stays
                assert a.at(5, b"SC") == (ok, b"\x1f\xfe")
                assert a.at(6, b"SC", b"\x00\x01") == (ok, b"")
                assert a.at(7, b"CH") == (ok, b"\x1a")
            else:
                assert a.at(5, b"SC")[0] == invalid_command  # DigiMesh has none


@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_channel_through_digi_xbee(tmp_path: Path, opened: list[Any], firmware: str,
                                   mode: int) -> None:
    from digi.xbee.exception import ATCommandException
    from digi.xbee.models.status import ATCommandStatus

    with Medium(1, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        dev = device(medium, 1, opened)
        with pytest.raises(ATCommandException) as info:
            dev.set_parameter("CH", b"\x05")
        expected = ATCommandStatus.ERROR if firmware == "zigbee" else (
            ATCommandStatus.INVALID_PARAMETER)
        assert info.value.status == expected
        if firmware == "zigbee":
            dev.set_parameter("SC", b"\x20\x00")  # channel 24 only
            assert bytes(dev.get_parameter("CH")) == b"\x18"
        else:
            dev.set_parameter("CH", b"\x19")
            assert bytes(dev.get_parameter("CH")) == b"\x19"


# -- payload limits and NP -------------------------------------------------------------
# Broadcast limit, unicast limit, NP as read (Zigbee in API mode: 0xFF).
LIMITS = {"802.15.4": (100, 100, 100), "zigbee": (92, 255, 255), "digimesh": (73, 73, 73)}


@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_payload_limits_and_np(tmp_path: Path, opened: list[Any], firmware: str,
                               mode: int) -> None:
    broadcast, unicast, np_value = LIMITS[firmware]
    with Medium(2, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        a, b = raw(medium, 1, opened), raw(medium, 2, opened)
        assert a.at(1, b"NP") == (0, np_value.to_bytes(2, "big"))
        to2 = medium.radios[2].address64
        assert status_of(a.transmit(2, BROADCAST, b"b" * broadcast))[1] == 0x00
        assert status_of(a.transmit(3, BROADCAST, b"b" * (broadcast + 1)))[1] == 0x74
        assert status_of(a.transmit(4, to2, b"u" * unicast))[1] == 0x00
        assert status_of(a.transmit(5, to2, b"u" * (unicast + 1)))[1] == 0x74
        # The fragmented Zigbee unicast arrives whole, as the receiver reassembles it.
        got = b.expect(lambda f: f[0] in (0x80, 0x81, 0x90) and f.endswith(b"u" * unicast))
        assert got.count(b"u") == unicast


def test_zigbee_fragmented_unicast_through_digi_xbee(tmp_path: Path,
                                                     opened: list[Any]) -> None:
    from digi.xbee.exception import TransmitException
    from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress

    with Medium(2, protocol="zigbee", api_mode=2, directory=tmp_path) as medium:
        a, b = device(medium, 1, opened), device(medium, 2, opened)
        got: list[bytes] = []
        b.add_data_received_callback(lambda m: got.append(bytes(m.data)))
        there = XBee64BitAddress.from_hex_string(f"{medium.radios[2].address64:016X}")
        payload = bytes(range(255))  # every byte value, escapes included
        a.send_data_64_16(there, XBee16BitAddress.UNKNOWN_ADDRESS, payload)
        with pytest.raises(TransmitException) as info:
            a.send_data_broadcast(b"x" * 93)
        assert info.value.status.code == 0x74
        assert bytes(a.get_parameter("NP")) == b"\x00\xff"
        deadline = time.monotonic() + WAIT
        while not got and time.monotonic() < deadline:
            time.sleep(0.01)
        assert got == [payload]


# -- 0x09 queued values are applied by the next 0x08 ---------------------------------
@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_queued_value_applied_by_next_at_command(tmp_path: Path, opened: list[Any],
                                                 firmware: str, mode: int) -> None:
    with Medium(1, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        a = raw(medium, 1, opened)
        assert a.at(1, b"NI", b"queued", queued=True) == (0, b"")
        assert a.at(2, b"NI", queued=True) == (0, b"robot1")  # 0x09 query: not applied
        assert a.at(3, b"NI") == (0, b"queued")  # a 0x08 query applies it first
        assert a.at(4, b"ID", b"\x12\x34", queued=True) == (0, b"")
        assert a.at(5, b"AC") == (0, b"")
        assert a.at(6, b"ID", queued=True) == (0, b"\x12\x34")


@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_queued_value_through_digi_xbee(tmp_path: Path, opened: list[Any],
                                        firmware: str, mode: int) -> None:
    with Medium(1, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        dev = device(medium, 1, opened)
        dev.set_parameter("NI", b"later", apply=False)  # 0x09
        assert medium.radios[1].params["NI"] == b"robot1"
        assert bytes(dev.get_parameter("NI", apply=True)) == b"later"  # 0x08 query


# -- API framing: a corrupt length does not leave the radio deaf -----------------------
@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_corrupt_length_does_not_deafen_the_radio(tmp_path: Path, opened: list[Any],
                                                  firmware: str, mode: int) -> None:
    with Medium(1, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        a = raw(medium, 1, opened)
        a.write(b"\x7e\xff\xff")  # longer than any frame: dropped at once
        assert a.at(1, b"NI") == (0, b"robot1")
        a.write(b"\x7e\x00\x40\x08")  # plausible length, then the line goes quiet
        parser = medium._ports[1].parser
        deadline = time.monotonic() + WAIT
        while not parser._buf and time.monotonic() < deadline:
            time.sleep(0.01)  # until the radio has read them: the silence starts there
        time.sleep(3 * api.INTER_CHAR_TIMEOUT)
        assert a.at(2, b"NI") == (0, b"robot1")
        drops = medium._ports[1].parser.drops
        assert drops["length"] == 1
        assert drops["timeout" if mode == 1 else "truncated"] == 1


def test_api1_parser_resyncs_only_on_a_start_after_a_silence() -> None:
    good = api.encode(b"\x08\x01NI", 1)
    gap = api.INTER_CHAR_TIMEOUT
    parser = api.FrameParser(1)
    # A plausible wrong length swallows what follows at once (no silence: data) ...
    assert parser.feed(b"\x7e\x00\x40" + good, now=0.0) == []
    # ... and a start delimiter after a silence begins a new frame.
    assert parser.feed(good, now=1.0) == [b"\x08\x01NI"]
    assert parser.drops["timeout"] == 1
    # A frame that pauses longer than the gap but goes on with data is kept.
    assert parser.feed(good[:4], now=2.0) + parser.feed(good[4:], now=2.0 + 3 * gap) == [
        b"\x08\x01NI"]
    # A zero or oversize length is dropped at once; the next frame comes through.
    assert parser.feed(b"\x7e\x00\x00" + b"\x7e\x02\x01" + good, now=4.0) == [
        b"\x08\x01NI"]
    assert parser.drops["length"] == 2


async def test_daemon_receive_side_resyncs_after_a_corrupt_length(
        tmp_path: Path, opened: list[Any]) -> None:
    # digi-xbee reads the daemon's side: a byte that does not come within its port
    # timeout (0.1 s) ends the frame it is reading, and it hunts for the next 0x7E.
    import asyncio

    from test_xbee_transport import Sink

    from swarmd.transport.xbee import XBeeTransport

    with Medium(2, protocol="802.15.4", api_mode=1, directory=tmp_path) as medium:
        ours = XBeeTransport(port=medium.path(2))
        sink = Sink()
        await ours.start(sink.frame, sink.event)
        try:
            medium._write_raw(2, b"\x7e\xff\xff")  # what a UART bit error could give
            assert ours._radio is not None
            port = ours._radio._device.serial_port
            await sink.until(lambda: port.in_waiting == 0)  # digi-xbee's reader has them
            await asyncio.sleep(3 * api.INTER_CHAR_TIMEOUT)
            other = raw(medium, 1, opened)
            other.at(1, b"MY", b"\xff\xfe")
            assert status_of(other.transmit(2, BROADCAST, b"after the glitch"))[1] == 0
            await sink.until(lambda: sink.frames == [b"after the glitch"])
            assert ours.up
        finally:
            await ours.close()


# -- receive options -------------------------------------------------------------------
def received(payload: bytes, frame: bytes) -> bool:
    """A 0x90 Receive Packet carrying `payload`."""
    return frame[0] == 0x90 and frame[12:] == payload


@pytest.mark.parametrize("mode", [1, 2])
def test_digimesh_receive_options_carry_the_delivery_method(
        tmp_path: Path, opened: list[Any], mode: int) -> None:
    with Medium(2, protocol="digimesh", api_mode=mode, directory=tmp_path) as medium:
        a, b = raw(medium, 1, opened), raw(medium, 2, opened)
        to2 = medium.radios[2].address64
        for fid, dest, options, expected in ((1, to2, 0, 0xC1), (2, BROADCAST, 0, 0xC2),
                                             (3, to2, 0x40, 0x41),
                                             (4, BROADCAST, 0x40, 0x42)):
            payload = f"m{fid}".encode()
            assert status_of(a.transmit(fid, dest, payload, options=options))[1] == 0
            got = b.expect(functools.partial(received, payload))
            assert got[11] == expected, hex(got[11])
        # TO sets the default method (0x40: point-to-multipoint).
        assert a.at(5, b"TO", b"\x40") == (0, b"")
        a.transmit(6, to2, b"by TO")
        assert b.expect(functools.partial(received, b"by TO"))[11] == 0x41


def test_digimesh_receive_options_through_digi_xbee(tmp_path: Path,
                                                    opened: list[Any]) -> None:
    with Medium(2, protocol="digimesh", api_mode=1, directory=tmp_path) as medium:
        a, b = device(medium, 1, opened), device(medium, 2, opened)
        options: list[int] = []

        def on_packet(packet: Any) -> None:
            if packet.get_frame_type().code == 0x90:
                options.append(int(packet.receive_options))

        b.add_packet_received_callback(on_packet)
        a.send_data_broadcast(b"mesh")
        deadline = time.monotonic() + WAIT
        while not options and time.monotonic() < deadline:
            time.sleep(0.01)
        assert options == [0xC2]


# -- what the emulator does not support --------------------------------------------------
@pytest.mark.parametrize(("firmware", "mode"), CASES, ids=IDS)
def test_unknown_command_and_frame_type(tmp_path: Path, opened: list[Any], firmware: str,
                                        mode: int) -> None:
    with Medium(1, protocol=firmware, api_mode=mode, directory=tmp_path) as medium:
        a = raw(medium, 1, opened)
        assert a.at(1, b"ZZ") == (2, b"")  # invalid command
        assert a.at(2, b"ZZ", b"\x01") == (2, b"")
        a.send(b"\x2e\x01\x00")  # a frame type no emulated firmware takes: no answer
        assert a.at(3, b"NI") == (0, b"robot1")  # ... and the radio goes on
        assert not a.frames
        assert medium.radios[1].counters["unsupported_frame"] == 1


# -- what the daemon does with a failure status or a refused setting --------------------
@pytest.mark.parametrize("code", [0x01, 0x21, 0x24, 0x25, 0x74, 0x99])
async def test_daemon_reports_a_failed_transmit_status_and_goes_on(
        tmp_path: Path, code: int) -> None:
    # swarmd only broadcasts, whose status is always 0x00 on real radios; a radio that
    # still reports a failure (whatever the code, one digi-xbee does not know included)
    # gives one `send_error` naming it, and the transport stays up.
    from test_xbee_transport import Sink

    from swarmd.transport.base import SendError, SendFailure
    from swarmd.transport.xbee import XBeeTransport

    with Medium(2, protocol="zigbee", directory=tmp_path) as medium:
        radio = medium.radios[1]
        honest = radio.status_frame
        radio.status_frame = (  # type: ignore[method-assign]
            lambda request, status, **_: bytes((0x8B, request.frame_id, 0xFF, 0xFD, 0, code,
                                                0)))
        ours = XBeeTransport(port=medium.path(1), protocol="zigbee")
        sink = Sink()
        await ours.start(sink.frame, sink.event)
        try:
            ours.send(b"heartbeat")
            await sink.until(lambda: "send_error" in sink.names())
            error = sink.last(SendError)
            assert error.status == (code if code != 0x99 else 0xFF)
            assert error.reason is SendFailure.REFUSED and error.detail != ""
            assert ours.counters["send_error:refused"] == 1  # one counter, whatever the code
            assert ours.up
            radio.status_frame = honest  # type: ignore[method-assign]
            ours.send(b"next")
            await sink.until(lambda: ours.counters["delivered"] == 1)
        finally:
            await ours.close()


async def test_daemon_refuses_to_start_when_the_radio_refuses_a_setting(
        tmp_path: Path) -> None:
    from swarmd.transport.xbee import RadioRefused, XBeeTransport

    with Medium(1, protocol="802.15.4", directory=tmp_path) as medium:
        medium.radios[1]._valid = (  # type: ignore[method-assign]
            lambda cmd, value: cmd != "MY")
        ours = XBeeTransport(port=medium.path(1))
        with pytest.raises(RadioRefused) as info:
            await ours.start(lambda _: None, lambda *_: None)
        text = str(info.value)
        assert "\n" not in text
        assert f"XBee on {medium.path(1)} refused MY=FFFE (AT status 0x03" in text
        await ours.close()
