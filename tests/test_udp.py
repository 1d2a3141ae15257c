"""UDP multicast transport on loopback."""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
from typing import Any

import pytest
from harness import send_to_group
from pydantic import ValidationError

from swarmd.config.robot import UdpTransportConfig
from swarmd.transport import socket_filter
from swarmd.transport.base import ChannelEvent, SendError, SendFailure, TransportError
from swarmd.transport.udp import MAX_PAYLOAD, UdpTransport, UdpUp


class Sink:
    def __init__(self) -> None:
        self.frames: list[bytes] = []
        self.events: list[ChannelEvent] = []
        self.got = asyncio.Event()

    def frame(self, data: bytes) -> None:
        self.frames.append(data)
        self.got.set()

    def event(self, event: ChannelEvent) -> None:
        self.events.append(event)


async def test_udp_two_transports_exchange_frames_on_loopback(udp_port: int) -> None:
    port = udp_port
    a, b = UdpTransport(port=port), UdpTransport(port=port)
    sa, sb = Sink(), Sink()
    await a.start(sa.frame, sa.event)
    await b.start(sb.frame, sb.event)
    try:
        a.send(b"\x11hello")
        await asyncio.wait_for(sb.got.wait(), 2.0)
        assert sb.frames == [b"\x11hello"]
        b.send(b"\x11from b")
        await asyncio.wait_for(sa.got.wait(), 2.0)
        await asyncio.sleep(0.05)  # give our own echo, were it delivered, time to show up
        # Loopback on, but our own datagrams are dropped in the kernel (socket_filter.py).
        assert sa.frames == [b"\x11from b"]
        assert a.counters["sent"] == 1 and a.counters["received"] == 1
        assert UdpUp(a.group, port, "127.0.0.1") in sa.events
    finally:
        await a.close()
        await b.close()



async def test_udp_own_frames_are_filtered_but_the_same_bytes_from_another_socket_arrive(
        udp_port: int) -> None:
    # Only our sending socket's address and port are filtered: a second daemon with our
    # id (or a forger) repeating our very bytes is still heard, for the core's `own`
    # drop and the runtime's `duplicate_id` to judge.
    t = UdpTransport(port=udp_port)
    sink = Sink()
    await t.start(sink.frame, sink.event)
    try:
        assert t.echoes_filtered
        for _ in range(3):
            t.send(b"\x11mine")
        send_to_group(t.group, udp_port, b"\x11mine")
        await asyncio.wait_for(sink.got.wait(), 2.0)
        await asyncio.sleep(0.05)
        assert sink.frames == [b"\x11mine"] and t.counters["sent"] == 3
    finally:
        await t.close()


async def test_udp_without_a_socket_filter_hears_its_echoes_and_says_so(
        udp_port: int, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    # Where the kernel refuses SO_ATTACH_FILTER the echoes come back as they always
    # did (the core drops them as `own`), and the log says why.
    monkeypatch.setattr(socket_filter, "attach", lambda sock, code: False)
    t = UdpTransport(port=udp_port)
    sink = Sink()
    with caplog.at_level(logging.INFO, logger="swarmd.transport.udp"):
        await t.start(sink.frame, sink.event)
    try:
        assert not t.echoes_filtered
        t.send(b"\x11echo")
        await asyncio.wait_for(sink.got.wait(), 2.0)
        assert sink.frames == [b"\x11echo"]
        assert any("SO_ATTACH_FILTER" in r.getMessage() for r in caplog.records)
    finally:
        await t.close()


async def test_udp_socket_options_default_to_loopback_ttl_1(udp_port: int) -> None:
    t = UdpTransport(port=udp_port)
    sink = Sink()
    await t.start(sink.frame, sink.event)
    try:
        sock, out = t._sock, t._out
        assert sock is not None and out is not None
        # Both sockets: whichever sends, nothing leaves this host (DESIGN section 4).
        for s in (sock, out):
            assert s.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL) == 1
            assert s.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP) == 1
            iface = s.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, 4)
            assert socket.inet_ntoa(iface) == "127.0.0.1"
        assert sock.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT) == 1
        assert sock.getsockname() == (t.group, udp_port)
        assert out.getsockname()[0] == "127.0.0.1" and out.getsockname()[1] != udp_port
    finally:
        await t.close()
    assert t._sock is None and t._out is None


async def test_udp_send_errors_are_counted_not_raised(udp_port: int) -> None:
    t = UdpTransport(port=udp_port)
    sink = Sink()
    t.send(b"before start")  # not open yet
    await t.start(sink.frame, sink.event)
    try:
        t.send(b"x" * (MAX_PAYLOAD + 1))
        assert t.counters["send_errors"] == 2
        # Only after start; counted by a bounded class, the size beside it.
        assert [e for e in sink.events if isinstance(e, SendError)] == [
            SendError("udp", SendFailure.OVERSIZE, "oversize", size=MAX_PAYLOAD + 1,
                      limit=MAX_PAYLOAD)]
        assert t.send_reasons == {"send_error:not_open": 1, "send_error:oversize": 1}
    finally:
        await t.close()
    t.send(b"after close")
    assert t.counters["send_errors"] == 3


class _Refusing:
    """A socket whose every send fails with the next of `errors` (what a host without
    a route, with a full buffer or a firewall rule answers)."""

    def __init__(self, errors: list[OSError]) -> None:
        self.errors = errors

    def sendto(self, data: bytes, address: tuple[str, int]) -> int:
        raise self.errors.pop(0)


async def test_udp_os_errors_are_counted_by_a_few_classes(udp_port: int) -> None:
    # Keyed by the error's words, every new errno or address would be a new counter;
    # keyed by its class they stay a fixed set, the words go to the log.
    t = UdpTransport(port=udp_port)
    sink = Sink()
    await t.start(sink.frame, sink.event)
    errors = [OSError(errno.ENETUNREACH, "Network is unreachable"),
              OSError(errno.EHOSTUNREACH, "No route to host"),
              OSError(errno.ENOBUFS, "No buffer space available"),
              PermissionError(errno.EPERM, "Operation not permitted")]
    out = t._out
    t._out = _Refusing(list(errors))  # type: ignore[assignment]
    try:
        for _ in errors:
            t.send(b"frame")
    finally:
        t._out = out
        await t.close()
    assert t.send_reasons == {"send_error:unreachable": 2, "send_error:no_buffer": 1,
                              "send_error:permission": 1}
    assert [(e.reason, e.detail) for e in sink.events if isinstance(e, SendError)] == [
        (SendFailure.UNREACHABLE, str(errors[0])), (SendFailure.UNREACHABLE, str(errors[1])),
        (SendFailure.NO_BUFFER, str(errors[2])), (SendFailure.PERMISSION, str(errors[3]))]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"group": "10.0.0.1"}, "udp group 10.0.0.1 is not a multicast group"),
        ({"group": "nonsense"}, "not an IPv4 address"),
        ({"interface": "eth0"}, "not its name"),
        ({"port": 0}, "out of range"),
        ({"ttl": 300}, "out of range"),
    ],
)
def test_udp_rejects_bad_config_with_clear_message(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(TransportError, match=message):
        UdpTransport(**kwargs)


@pytest.mark.parametrize(("field", "value"),
                         [("group", "10.0.0.1"), ("group", "nonsense"), ("interface", "eth0")])
def test_robot_file_and_transport_refuse_the_same_addresses(field: str, value: str) -> None:
    # One check (swarmd/transport/addresses.py): a robot file that validates never
    # fails later in the constructor, and both say the same thing.
    kwargs: dict[str, Any] = {field: value}
    with pytest.raises(TransportError) as transport:
        UdpTransport(**kwargs)
    with pytest.raises(ValidationError) as config:
        UdpTransportConfig(kind="udp", **kwargs)
    said = str(transport.value).split(" ", 2)[2]  # after "udp group" / "udp interface"
    assert said in str(config.value)
