"""swarmd.base.notify against real NOTIFY_SOCKET listeners (AF_UNIX datagram sockets)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from swarms import unsigned_paper

from swarmd.base.notify import Notifier


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


# -- the daemon under a real NOTIFY_SOCKET ---------------------------------------------
REPO = Path(__file__).resolve().parent.parent
WATCHDOG_USEC = 400_000  # systemd would ping-check every 0.4 s; the daemon pings at 0.2 s


def _free_port(kind: socket.SocketKind) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _robot_dir(tmp_path: Path, metrics_port: int, udp_port: int) -> Path:
    """Robot 2 of the paper's swarm, alone on a private loopback multicast port."""
    unsigned_paper(tmp_path, "swarm.yaml")
    robot = tmp_path / "robot.yaml"
    robot.write_text(
        "robot: 2\n"
        "swarm: swarm.yaml\n"
        f"transport: {{kind: udp, port: {udp_port}, "
        "interface: 127.0.0.1, ttl: 1}\n"
        "state_dir: state\n"
        f"metrics: {{host: 127.0.0.1, port: {metrics_port}}}\n"
    )
    return robot


def test_swarmd_start_speaks_sd_notify(
    listener: tuple[socket.socket, str], tmp_path: Path, udp_port: int
) -> None:
    pytest.importorskip("swarmd.daemon.daemon", reason="daemon runtime not in this tree")
    httpx = pytest.importorskip("httpx")
    if not (REPO / "configs" / "paper.yaml").exists():
        pytest.skip("configs/paper.yaml not in the tree")
    sock, path = listener
    sock.settimeout(0.5)
    metrics_port = _free_port(socket.SOCK_STREAM)
    robot = _robot_dir(tmp_path, metrics_port, udp_port)
    env = {**os.environ, "NOTIFY_SOCKET": path, "WATCHDOG_USEC": str(WATCHDOG_USEC)}
    env.pop("WATCHDOG_PID", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarmd.cli", "start", "--config", str(robot)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, cwd=tmp_path,
    )
    got: list[tuple[float, dict[str, str]]] = []

    def collect(until: Callable[[], bool], limit: float) -> None:
        end = time.monotonic() + limit
        while not until() and time.monotonic() < end and proc.poll() is None:
            try:
                got.append((time.monotonic(), _recv(sock)))
            except TimeoutError:
                continue

    def names(key: str) -> list[float]:
        return [t for t, m in got if key in m]

    try:
        # READY, then enough watchdog pings to measure their period (bounded: 20 s).
        collect(lambda: bool(names("READY")) and len(names("WATCHDOG")) >= 8, 20)
        assert names("READY"), f"no READY=1; daemon said: {_output(proc)}"
        statuses = [m["STATUS"] for _, m in got if "STATUS" in m]
        assert "active f2 epoch 0" in statuses  # role and function (paper.yaml: 2 holds f2)
        pings = names("WATCHDOG")
        assert len(pings) >= 8, got
        # Half of WatchdogSec. The loop re-arms at absolute times, so a ping delayed by
        # a loaded machine does not shift the later ones: the mean gap stays the period.
        mean_gap = (pings[-1] - pings[0]) / (len(pings) - 1)
        assert mean_gap == pytest.approx(WATCHDOG_USEC / 2e6, rel=0.25)

        # End to end: the daemon's own endpoint, scraped over HTTP.
        scrape = httpx.get(f"http://127.0.0.1:{metrics_port}/metrics", timeout=5).text
        assert 'swarmd_role{swarmd_role="ACTIVE"} 1.0' in scrape
        assert 'swarmd_function_info{function="f2"} 1.0' in scrape
        assert "swarmd_frames_sent_total" in scrape

        proc.send_signal(signal.SIGTERM)
        collect(lambda: bool(names("STOPPING")), 10)
        assert names("STOPPING"), f"no STOPPING=1; daemon said: {_output(proc)}"
        assert proc.wait(timeout=10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        if proc.stdout is not None:
            proc.stdout.close()


def _output(proc: subprocess.Popen[bytes]) -> str:
    if proc.poll() is None:
        return "(still running)"
    assert proc.stdout is not None
    return proc.stdout.read().decode(errors="replace")[-2000:]
