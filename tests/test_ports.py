"""The multicast port lease of a real-time swarm (sim/realtime/ports.py): two swarms on
one machine (two users' `swarmd sim`, tests under pytest -n) never share a channel."""

from __future__ import annotations

import errno
import socket
import time
from pathlib import Path

import pytest

from sim.realtime.orchestrator import Orchestrator
from sim.realtime.ports import PortLease, _group_port_free
from swarmd.transport.addresses import DEFAULT_GROUP
from swarmd.transport.udp import UdpTransport

ROOT = Path(__file__).resolve().parent.parent


def _robot_socket(port: int, group: str = DEFAULT_GROUP) -> socket.socket:
    """A socket exactly as a robot's daemon opens it (SO_REUSEADDR, SO_REUSEPORT, the
    group joined)."""
    return UdpTransport(group=group, port=port)._socket()


def _bind_error(address: tuple[str, int], reuse: bool) -> int | None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        if reuse:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        try:
            s.bind(address)
        except OSError as exc:
            return exc.errno
    return None


def test_held_leases_never_share_a_port() -> None:
    leases = [PortLease() for _ in range(300)]
    try:
        assert len({lease.port for lease in leases}) == len(leases)
    finally:
        for lease in leases:
            lease.release()


def test_a_held_port_is_refused_to_any_other_bind_of_loopback_with_or_without_reuse() -> None:
    with PortLease() as lease:
        for reuse in (False, True):
            assert _bind_error(("127.0.0.1", lease.port), reuse) == errno.EADDRINUSE
            assert _bind_error(("0.0.0.0", lease.port), reuse) == errno.EADDRINUSE
    assert _bind_error(("127.0.0.1", lease.port), False) is None  # released


def test_the_robots_bind_next_to_the_lease_and_hear_each_other_not_it() -> None:
    with PortLease() as lease:
        a, b = _robot_socket(lease.port), _robot_socket(lease.port)
        try:
            a.sendto(b"hb", (DEFAULT_GROUP, lease.port))
            b.settimeout(5)
            assert b.recv(64) == b"hb"
            assert lease._sock is not None
            lease._sock.setblocking(False)
            time.sleep(0.05)
            with pytest.raises(BlockingIOError):  # bound to 127.0.0.1: no multicast
                lease._sock.recv(64)
        finally:
            a.close()
            b.close()


def test_a_port_in_use_on_the_group_is_not_free() -> None:
    # What the old probe (bind 127.0.0.1:0, close) could not see: robots bound to the
    # group address of a port. Such a port is never leased.
    with PortLease() as lease:
        port = lease.port
    robot = _robot_socket(port)
    try:
        assert _bind_error(("127.0.0.1", port), False) is None  # the old probe: "free"
        assert not _group_port_free(DEFAULT_GROUP, port)
        assert _group_port_free("239.255.77.8", port)  # another group's port is its own
    finally:
        robot.close()
    assert _group_port_free(DEFAULT_GROUP, port)


def test_two_prepared_runs_hold_different_ports_until_cleanup(tmp_path: Path) -> None:
    runs = [Orchestrator(ROOT / "configs" / "paper.yaml", duration=1.0, faults=(), loss=0.0,
                         seed=0, physics=False, live=False, report_dir=tmp_path / str(i))
            for i in (1, 2)]
    try:
        for run in runs:
            run.prepare()
        assert runs[0].port != runs[1].port
        for run in runs:
            assert _bind_error(("127.0.0.1", run.port), False) == errno.EADDRINUSE
    finally:
        for run in runs:
            run.cleanup()
    assert all(run.port_lease is None for run in runs)
    assert _bind_error(("127.0.0.1", runs[0].port), False) is None


def test_a_run_given_a_port_leases_none(tmp_path: Path) -> None:
    with PortLease() as lease:
        run = Orchestrator(ROOT / "configs" / "paper.yaml", duration=1.0, faults=(), loss=0.0,
                           seed=0, physics=False, live=False, report_dir=tmp_path,
                           port=lease.port)
        try:
            run.prepare()
            assert run.port == lease.port and run.port_lease is None
        finally:
            run.cleanup()
