"""A robot always knows what it holds: every daemon start tells the robot link (docs/
daemon.md, "Robot links"; DESIGN rule 2 across a restart).

Robot 2's daemon (`swarmd start`, a real process) is SIGKILLed while it holds f2; standby
4 takes f2 over; the daemon is started again on its state file, now a standby. The
robot side, which kept executing f2 while its daemon was dead, must be told to release
before anything else: at the end exactly one robot executes f2. For the socket and exec
links here (the ros2 link: tests/test_ros2_field.py), for the MAVLink pilot on virtual
time; the node's part (a restarted standby releases, a holder re-asserts) is also in
tests/test_runtime.py.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from swarms import ring_text

ROOT = Path(__file__).resolve().parent.parent
GROUP = "239.255.77.10"


def wait_until(check: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < end, f"not within {timeout:g} s: {what}"
        time.sleep(0.05)


class SocketRobot:
    """The robot side of the socket link: reconnects, says it is healthy, and executes
    what it was last told (`doing`)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.doing = ""
        self.told: list[dict[str, Any]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                    s.connect(str(self.path))
                    s.settimeout(0.2)
                    self._talk(s)
            except OSError:
                time.sleep(0.1)

    def _talk(self, s: socket.socket) -> None:
        buf = b""
        while not self._stop.is_set():
            s.sendall(b'{"health": "ok"}\n')
            try:
                data = s.recv(4096)
            except TimeoutError:
                continue
            if not data:
                return  # the daemon is gone: keep doing what we did, reconnect
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                msg = json.loads(line)
                self.told.append(msg)
                self.doing = msg.get("assign", "")

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)


class Ring:
    """The ring swarm as `swarmd start` processes; robot 2 with `link`, the others none."""

    def __init__(self, tmp: Path, link: dict[str, Any]) -> None:
        from sim.realtime.ports import PortLease

        self.dir = tmp
        self.port = PortLease(GROUP)
        swarm = tmp / "swarm.yaml"
        swarm.write_text(ring_text())
        self.files = {}
        for r in (1, 2, 3, 4):
            doc = {"robot": r, "swarm": str(swarm),
                   "transport": {"kind": "udp", "group": GROUP, "port": self.port.port,
                                 "interface": "127.0.0.1", "ttl": 0, "loopback": True},
                   "link": link if r == 2 else {"kind": "none"},
                   "event_log": str(tmp / f"events{r}.jsonl"),
                   "state_dir": str(tmp / "state" / str(r))}
            self.files[r] = tmp / f"robot{r}.yaml"
            self.files[r].write_text(yaml.safe_dump(doc))
        self.procs: dict[int, subprocess.Popen[bytes]] = {}

    def start(self, robot: int) -> None:
        log = (self.dir / f"daemon{robot}.log").open("ab")
        self.procs[robot] = subprocess.Popen(
            [sys.executable, "-m", "swarmd.cli", "start", "--config", str(self.files[robot]),
             "--log-format", "json"], stdout=log, stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONPATH": str(ROOT)})

    def events(self, robot: int) -> list[dict[str, Any]]:
        path = self.dir / f"events{robot}.jsonl"
        return [json.loads(x) for x in path.read_text().splitlines()] if path.exists() \
            else []

    def kill(self, robot: int, sig: int = signal.SIGKILL) -> None:
        proc = self.procs[robot]
        if proc.poll() is None:
            proc.send_signal(sig)
        proc.wait(10)

    def holds_f2(self, robot: int) -> bool:
        """Robot's daemon executes f2 now, from its events (a none link)."""
        held = False
        for e in self.events(robot):
            if e["event"] == "takeover" and e["function"] == "f2":
                held = True
            elif e["event"] in ("fenced", "leave", "stopped"):
                held = False
        return held

    def kill_and_restart_two(self, doing: Callable[[], str]) -> None:
        """The scenario: robot 2 executes f2, its daemon is SIGKILLed, 4 takes f2, 2's
        daemon comes back (a standby now)."""
        for r in (1, 2, 3, 4):
            self.start(r)
        wait_until(lambda: doing() == "f2", 30, "robot 2 executes f2")
        self.kill(2)
        wait_until(lambda: self.holds_f2(4), 30, "robot 4 takes f2 over")
        assert doing() == "f2"  # nobody told robot 2 otherwise while its daemon was dead
        self.start(2)
        wait_until(lambda: sum(e["event"] == "started" for e in self.events(2)) >= 2, 30,
                   "robot 2's daemon started again")

    def close(self) -> None:
        for r in list(self.procs):
            self.kill(r, signal.SIGTERM)
        self.port.release()


@pytest.mark.slow
def test_socket_link_a_restarted_standby_tells_its_robot_to_release(tmp_path: Path) -> None:
    path = tmp_path / "robot2.sock"
    ring = Ring(tmp_path, {"kind": "socket", "path": str(path), "health_timeout": 2.0})
    robot = SocketRobot(path)
    try:
        ring.kill_and_restart_two(lambda: robot.doing)
        wait_until(lambda: robot.doing == "", 20, "robot 2 told to release")
        assert robot.told[-1] == {"release": ""}
        assert [r for r in (1, 3, 4) if ring.holds_f2(r)] == [4]  # f2: robot 4 only
    finally:
        robot.stop()
        ring.close()


@pytest.mark.slow
def test_exec_link_a_restarted_standby_tells_its_robot_to_release(tmp_path: Path) -> None:
    state = tmp_path / "doing"
    state.write_text("")
    ring = Ring(tmp_path, {
        "kind": "exec",
        "on_assign": ["sh", "-c", f'printf %s "$SWARMD_FUNCTION" > {state}'],
        "on_release": ["sh", "-c", f': > {state}; echo release >> {state}.log']})
    try:
        ring.kill_and_restart_two(state.read_text)
        wait_until(lambda: state.read_text() == "", 20, "robot 2 told to release")
        assert [r for r in (1, 3, 4) if ring.holds_f2(r)] == [4]
    finally:
        ring.close()


def test_mavlink_pilot_of_a_restarted_standby_releases_what_the_vehicle_flies() -> None:
    """The vehicle still flies f2 (armed, in the mode the dead daemon set); the new
    daemon's pilot knows no function. Told to release with no name, it sets the
    configured release mode; a vehicle on the ground is left alone."""
    from test_mavlink_link import Loop

    from swarmd.link.mavlink_pilot import MAV_CMD_DO_SET_MODE

    flying = Loop("ardupilot", release="land")
    flying.ap.armed, flying.ap.mode = True, "guided"
    flying.run(1.0)
    flying.pilot.release("", flying.now)
    flying.run(2.0)
    modes = [c.param2 for c in flying.commands() if c.command == MAV_CMD_DO_SET_MODE]
    assert modes and modes[-1] == 9  # LAND

    grounded = Loop("ardupilot", release="land")
    grounded.run(1.0)
    grounded.pilot.release("", grounded.now)
    grounded.run(2.0)
    assert grounded.commands() == []
