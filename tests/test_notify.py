"""swarmd.notify against real NOTIFY_SOCKET listeners (AF_UNIX datagram sockets)."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarmd.notify import Notifier


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A socket bound where systemd would put NOTIFY_SOCKET."""
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5)
    yield sock, path
    sock.close()


def _recv(sock: socket.socket) -> dict[str, str]:
    data = sock.recv(4096).decode()
    assert data.endswith("\n")
    return dict(line.split("=", 1) for line in data.splitlines())


def test_notifier_sends_each_message_to_a_path_socket(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    n = Notifier.from_env({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready("STANDBY")
    assert _recv(sock) == {"READY": "1", "STATUS": "STANDBY"}
    assert n.status("ACTIVE f2 epoch 1")
    assert _recv(sock) == {"STATUS": "ACTIVE f2 epoch 1"}
    assert n.watchdog()
    assert _recv(sock) == {"WATCHDOG": "1"}
    assert n.stopping()
    assert _recv(sock) == {"STOPPING": "1"}
    assert n.sent == 4 and n.failures == 0
    n.close()


def test_notifier_reaches_an_abstract_socket() -> None:
    name = f"swarmd-test-{os.getpid()}-{id(object())}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(5)
    try:
        n = Notifier.from_env({"NOTIFY_SOCKET": "@" + name})
        assert n.ready()
        assert _recv(sock) == {"READY": "1"}
    finally:
        sock.close()


def test_status_cannot_smuggle_a_second_assignment(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    Notifier(path).status("bad\nREADY=1")
    assert _recv(sock) == {"STATUS": "bad READY=1"}


def test_without_notify_socket_everything_is_a_noop() -> None:
    n = Notifier.from_env({"WATCHDOG_USEC": "5000000"})
    assert not n.enabled
    assert n.watchdog_period() is None
    assert not n.ready() and not n.watchdog() and not n.stopping()
    assert n.sent == 0 and n.failures == 0


def test_send_failure_is_counted_not_raised(tmp_path: Path) -> None:
    n = Notifier.from_env({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    assert n.ready() is False
    assert n.watchdog() is False
    assert n.failures == 2 and n.sent == 0


def test_watchdog_period_is_half_of_watchdog_usec() -> None:
    env = {"NOTIFY_SOCKET": "/run/x", "WATCHDOG_USEC": "5000000"}
    assert Notifier.from_env(env).watchdog_period() == 2.5
    env["WATCHDOG_PID"] = str(os.getpid())
    assert Notifier.from_env(env).watchdog_period() == 2.5
    # Meant for another process (sd_watchdog_enabled(3)): not ours to ping.
    env["WATCHDOG_PID"] = str(os.getpid() + 1)
    assert Notifier.from_env(env).watchdog_period() is None
    env.pop("WATCHDOG_PID")
    env["WATCHDOG_USEC"] = "soon"
    assert Notifier.from_env(env).watchdog_period() is None
    env["WATCHDOG_USEC"] = "0"
    assert Notifier.from_env(env).watchdog_period() is None
