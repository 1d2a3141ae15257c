"""The XBee emulator: API framing, AT commands, and the real digi-xbee library on it."""

from __future__ import annotations

import os
import select
import time
from pathlib import Path

import pytest

from sim.xbee_emu import Medium, api
from sim.xbee_emu.radio import EmulatedRadio, RemoteCommand, Reply, Transmit

NASTY = bytes([0x7E, 0x7D, 0x11, 0x13]) * 20  # every byte API mode 2 must escape


def test_api_frame_round_trip_both_modes_with_special_bytes() -> None:
    for mode in (1, 2):
        data = bytes((0x10, 0x7E)) + NASTY
        raw = api.encode(data, mode)
        if mode == 2:
            assert all(b not in raw[1:] for b in (0x7E, 0x11, 0x13))
        parser = api.FrameParser(mode)
        # Split at every offset: the parser is incremental.
        for cut in range(len(raw) + 1):
            parser = api.FrameParser(mode)
            assert parser.feed(b"\x55" + raw[:cut]) + parser.feed(raw[cut:]) == [data]


def test_api_parser_drops_bad_checksum_and_resyncs() -> None:
    good = api.encode(b"\x08\x01AP", 1)
    bad = bytearray(good)
    bad[-1] ^= 1
    parser = api.FrameParser(1)
    assert parser.feed(bytes(bad) + good) == [b"\x08\x01AP"]
    assert parser.drops["checksum"] == 1


def test_radio_at_queue_apply_write_and_power_cycle() -> None:
    radio = EmulatedRadio(3, "802.15.4")
    assert radio.handle(b"\x08\x01ID") == [Reply(b"\x88\x01ID\x00\x06\x07")]
    assert radio.handle(b"\x09\x02ID\x12\x34") == [Reply(b"\x88\x02ID\x00")]
    assert radio.params["ID"] == b"\x06\x07"  # queued, not applied
    radio.handle(b"\x08\x03AC")
    assert radio.params["ID"] == b"\x12\x34"
    radio.handle(b"\x08\x04CH\x0f")
    radio.handle(b"\x08\x05WR")
    radio.handle(b"\x08\x06CH\x10")
    radio.power_cycle()
    assert radio.params["CH"] == b"\x0f"  # written survives, unwritten is lost
    assert radio.handle(b"\x08\x07ZZ") == [Reply(b"\x88\x07ZZ\x02")]  # invalid command
    assert radio.handle(b"\x08\x08SH\x01") == [Reply(b"\x88\x08SH\x01")]  # read-only
    assert radio.handle(b"\x08\x00NI") == []  # frame id 0: no answer


def test_radio_transmit_request_and_receive_frames() -> None:
    a, b = EmulatedRadio(1, "802.15.4"), EmulatedRadio(2, "802.15.4")
    out = a.handle(b"\x00\x05" + (0xFFFF).to_bytes(8, "big") + b"\x00hello")
    assert out == [Transmit(5, 0x00, 0xFFFF, b"hello")]
    assert b.receive_frame(a, b"hi", True)[0] == 0x81  # MY=0: 16-bit source
    a.handle(b"\x08\x01MY\xff\xfe")
    frame = b.receive_frame(a, b"hi", True)
    assert frame[0] == 0x80 and frame[1:9] == a.address64.to_bytes(8, "big")


def test_radio_tx16_remote_at_and_frames_a_firmware_does_not_take() -> None:
    a, b = EmulatedRadio(1, "802.15.4"), EmulatedRadio(2, "802.15.4")
    (tx16,) = a.handle(b"\x01\x09\xff\xff\x00hello")  # TX16 to 0xFFFF
    assert isinstance(tx16, Transmit) and tx16.broadcast and tx16.data == b"hello"
    assert a.status_frame(tx16, 0) == b"\x89\x09\x00"
    b.handle(b"\x08\x01MY\x00\x42")
    (unicast,) = a.handle(b"\x01\x0a\x00\x42\x00hi")
    assert isinstance(unicast, Transmit) and not unicast.broadcast
    assert b.addressed_by(unicast.dest64, unicast.dest16)
    assert not a.addressed_by(unicast.dest64, unicast.dest16)
    (remote,) = a.handle(b"\x17\x0b" + b.address64.to_bytes(8, "big") + b"\xff\xfe\x02NI")
    assert isinstance(remote, RemoteCommand) and b.addressed_by(remote.dest64, remote.dest16)
    status, value = b.remote_command(remote)
    assert (status, value) == (0, b"robot2")
    answer = b.remote_response(remote, status, value)
    assert answer[:2] == b"\x97\x0b" and answer[2:10] == b.address64.to_bytes(8, "big")
    assert answer[10:12] == b"\x00\x42" and answer[12:] == b"NI\x00robot2"
    zigbee = EmulatedRadio(3, "zigbee")
    assert zigbee.handle(b"\x01\x01\xff\xff\x00x") == []  # legacy 802.15.4 frames
    assert zigbee.handle(b"\x00\x01" + bytes(8) + b"\x00x") == []
    assert a.handle(b"\x11\x01" + bytes(20)) == []  # explicit addressing: not here
    assert a.handle(b"\x2e\x01") == []
    assert zigbee.counters["unsupported_frame"] == 2 and a.counters["unsupported_frame"] == 2


def _pty_request(path: str, frame: bytes, mode: int = 1) -> bytes:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, api.encode(frame, mode))
        parser = api.FrameParser(mode)
        deadline = time.monotonic() + 2
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], 0.1)
            if ready:
                got = parser.feed(os.read(fd, 256))
                if got:
                    return got[0]
        raise AssertionError("no reply")
    finally:
        os.close(fd)


def test_pty_radio_answers_at_and_unplug_replug(tmp_path: Path) -> None:
    with Medium(2, directory=tmp_path) as medium:
        assert _pty_request(medium.path(1), b"\x08\x01NI") == b"\x88\x01NI\x00robot1"
        medium.unplug(1)
        assert not os.path.exists(medium.path(1))
        medium.replug(1)
        assert _pty_request(medium.path(1), b"\x09\x02VR") == b"\x88\x02VR\x00\x20\x14"


@pytest.mark.parametrize("protocol", ["zigbee", "802.15.4", "digimesh"])
@pytest.mark.parametrize("api_mode", [1, 2])
def test_digi_xbee_opens_emulated_radios_and_broadcasts(
    tmp_path: Path, protocol: str, api_mode: int
) -> None:
    from digi.xbee.devices import XBeeDevice
    from digi.xbee.models.protocol import XBeeProtocol

    expected = {"zigbee": XBeeProtocol.ZIGBEE, "802.15.4": XBeeProtocol.RAW_802_15_4,
                "digimesh": XBeeProtocol.DIGI_MESH}[protocol]
    with Medium(2, protocol=protocol, api_mode=api_mode, directory=tmp_path) as medium:
        a, b = XBeeDevice(medium.path(1), 9600), XBeeDevice(medium.path(2), 9600)
        received: list[bytes] = []
        try:
            a.open()
            b.open()
            assert a.get_protocol() == expected and b.get_protocol() == expected
            if protocol == "802.15.4":
                a.set_parameter("MY", b"\xff\xfe")
            b.add_data_received_callback(lambda m: received.append(bytes(m.data)))
            payload = NASTY[: {"zigbee": 92, "802.15.4": 100, "digimesh": 73}[protocol]]
            a.send_data_broadcast(payload)  # raises unless the status says delivered
            deadline = time.monotonic() + 3
            while not received and time.monotonic() < deadline:
                time.sleep(0.01)
            assert received == [payload]
        finally:
            a.close()
            b.close()


def test_oversize_payload_gets_status_0x74(tmp_path: Path) -> None:
    from digi.xbee.devices import XBeeDevice
    from digi.xbee.exception import TransmitException

    with Medium(2, protocol="digimesh", directory=tmp_path) as medium:
        dev = XBeeDevice(medium.path(1), 9600)
        try:
            dev.open()
            with pytest.raises(TransmitException) as info:
                dev.send_data_broadcast(b"x" * 74)
            assert info.value.status.code == 0x74
        finally:
            dev.close()


def test_radios_on_other_pan_or_loss_do_not_hear(tmp_path: Path) -> None:
    with Medium(3, directory=tmp_path, seed=1) as medium:
        medium.radios[3].params["ID"] = b"\x12\x34"
        medium.set_loss(2, 1.0)
        a = medium.radios[1]
        with medium._lock:  # as the medium's own thread does
            medium._transmit(a, Transmit(0, 0x00, 0xFFFF, b"x"))
        assert medium.delivered == 0 and medium.lost == 1


def test_the_medium_removes_the_directory_it_made_and_keeps_one_it_found(
        tmp_path: Path) -> None:
    made = tmp_path / "radios"
    with Medium(2, directory=made) as medium:
        assert Path(medium.path(1)).is_symlink()
    assert not made.exists()
    with Medium(2, directory=tmp_path):
        pass
    assert tmp_path.is_dir()
