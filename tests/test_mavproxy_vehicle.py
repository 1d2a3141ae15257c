"""MAVProxy, ArduPilot's own command-line ground station, flies a mission on both
flavours of `swarmd sim vehicle`, headless: it connects and downloads the parameters,
loads a QGC WPL plan (`wp load`), reads it back (`wp save`), starts it and follows
MAVProxy's progress lines until the autopilot disarmed after the landing.

MAVProxy uploads a plan file's lines as they are, line 0 as item 0, and treats no
autopilot differently there (`mavproxy_wp.py`, pymavlink's `mavwp.py`). So the ArduPilot
plan starts with home (ArduPilot's item 0, its convention) and the PX4 plan with the
take-off, PX4's first item, as a PX4 user of MAVProxy writes it. Starting it:
ArduPilot GUIDED, `arm throttle`, MISSION_START (ArduCopter starts a mission armed
only); PX4 MISSION_START alone, which PX4's Commander takes as Mission mode and arming
(MAVProxy's `mode mission` cannot reach PX4: pymavlink passes PX4's mode tuple where
DO_SET_MODE wants a number).

MAVProxy 1.8.75 declares opencv-python and vtk (some hundred MB) although a headless
session imports neither: `make setup` installs it without them (`pip install --no-deps
MAVProxy`; its runtime needs pymavlink, pyserial and numpy, which the dev extra brings),
so this test runs in CI; a venv without MAVProxy skips it, saying how to install it.
Every wait is bounded and the test judges by what MAVProxy says and in which order,
never by how fast.
"""

from __future__ import annotations

import importlib.util
import math
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from vehicles import start_vehicle

from sim.physics.mavlink_defs import GEO_ORIGIN
from swarmd.link.mavlink_modes import Flavour

if importlib.util.find_spec("MAVProxy") is None:
    pytest.skip("MAVProxy is not installed (pip install --no-deps MAVProxy)",
                allow_module_level=True)

pytestmark = pytest.mark.slow
EARTH_RADIUS = 6_371_000.0


def plan_rows(flavour: Flavour) -> list[tuple[float, ...]]:
    """QGC WPL 110 rows (index, current, frame, command, p1-p4, lat, lon, alt,
    autocontinue): take-off to 2 m, speed 2 m/s, three waypoints 4 m apart, land, from
    the vehicle's default home (each firmware's SITL home); ArduPilot's plan starts with
    home as line 0."""
    home = GEO_ORIGIN[flavour]

    def at(east: float, north: float) -> tuple[float, float]:
        lat = home[0] + math.degrees(north / EARTH_RADIUS)
        return lat, home[1] + math.degrees(
            east / (EARTH_RADIUS * math.cos(math.radians(home[0]))))

    body = [(3, 22, 0, 0, 0, 0, *at(0, 0), 2.0), (2, 178, 1, 2, -1, 0, 0.0, 0.0, 0.0),
            (3, 16, 0, 0, 0, 0, *at(0, 4), 2.0), (3, 16, 0, 0, 0, 0, *at(4, 4), 2.0),
            (3, 16, 0, 0, 0, 0, *at(4, 0), 2.0), (3, 21, 0, 0, 0, 0, *at(4, 0), 0.0)]
    if flavour == "ardupilot":
        body.insert(0, (0, 16, 0, 0, 0, 0, *home))
    return [(i, int(i == 0), *row, 1) for i, row in enumerate(body)]


class Console:
    """MAVProxy on a pipe: commands in, lines out (read by a thread)."""

    def __init__(self, args: list[str], cwd: Path) -> None:
        self.proc = subprocess.Popen(args, cwd=cwd, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip())

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def expect(self, pattern: str, timeout: float) -> re.Match[str]:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                continue
            self.seen.append(line)
            found = re.search(pattern, line)
            if found:
                return found
        raise AssertionError(f"MAVProxy never said {pattern!r}; last: {self.seen[-15:]}")

    def expect_all(self, patterns: list[str], timeout: float) -> None:
        """Each of `patterns` said, in any order."""
        end = time.monotonic() + timeout
        while patterns:
            line = self.expect("|".join(f"(?:{p})" for p in patterns),
                               max(end - time.monotonic(), 0.0)).string
            patterns = [p for p in patterns if not re.search(p, line)]


def load_and_read_back(mp: Console, rows: list[tuple[float, ...]], tmp_path: Path,
                       times: list[tuple[str, float]]) -> None:
    """`wp load` the plan, `wp save` it back: equal to 1e-7 degree, the integer
    encoding of MISSION_ITEM_INT (the current flags aside)."""
    t0 = time.monotonic()
    mp.send("wp load plan.txt")
    mp.expect(r"Got MISSION_ACK: TYPE_MISSION: ACCEPTED", 15.0)
    times.append(("upload", time.monotonic() - t0))
    t0 = time.monotonic()
    mp.send("wp save back.txt")
    mp.expect(rf"Saved {len(rows)} waypoints to back.txt", 10.0)
    times.append(("download", time.monotonic() - t0))
    back = [tuple(float(v) for v in line.split("\t"))
            for line in (tmp_path / "back.txt").read_text().splitlines()[1:]]
    for got, sent in zip(back, rows, strict=True):
        assert got[2:] == pytest.approx(sent[2:], abs=1.5e-7), (got, sent)


def start_and_follow(mp: Console, flavour: str, count: int) -> None:
    """Start the mission as each firmware takes it from MAVProxy, then follow every
    item after the take-off becoming current (MAVProxy's `waypoint N` lines, from
    MISSION_CURRENT) in order, to the disarm after the landing."""
    first = 1 if flavour == "ardupilot" else 0  # ArduPilot's item 0 is home
    if flavour == "ardupilot":
        mp.send("mode guided")
        mp.expect(r"Mode GUIDED", 5.0)
        mp.send("arm throttle")
        mp.expect(r"COMPONENT_ARM_DISARM: ACCEPTED", 5.0)
    mp.send("long MISSION_START 0 0")
    mp.expect(r"MISSION_START: ACCEPTED", 5.0)
    started = len(mp.seen)
    for seq in range(first + 1, count):
        mp.expect(rf"waypoint {seq}\b", 20.0)
    mp.expect(r"DISARMED", 20.0)
    if flavour == "px4":  # MISSION_START armed it: MAVProxy said so on the way
        assert any(re.search(r"(?<!DIS)ARMED\b", line) for line in mp.seen[started:])


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_mavproxy_flies_a_mission(flavour: Flavour, tmp_path: Path) -> None:
    started = start_vehicle(flavour, "--gcs-port", "0", "--no-physics")
    vehicle = started.proc
    rows = plan_rows(flavour)
    (tmp_path / "plan.txt").write_text(
        "QGC WPL 110\n" + "".join("\t".join(str(v) for v in r) + "\n" for r in rows))
    mp = Console([sys.executable, "-m", "MAVProxy.mavproxy",
                  f"--master=udpout:127.0.0.1:{started.port}", "--source-system=255",
                  "--default-modules=wp,mode,arm,param,cmdlong,misc,link",
                  f"--state-basedir={tmp_path}"], tmp_path)
    times: list[tuple[str, float]] = []
    try:
        t0 = time.monotonic()
        # Connected once MAVProxy has the parameters and has taken the vehicle as its
        # target ("online system"), in either order: MAVProxy keeps a plan per target
        # system, and one loaded before that is not the one it uploads (it answers the
        # autopilot's requests "Request for bad waypoint 0 (max 0)").
        mp.expect_all([r"Received \d+ parameters", r"online system \d+"], 30.0)
        times.append(("connect", time.monotonic() - t0))
        load_and_read_back(mp, rows, tmp_path, times)
        t0 = time.monotonic()
        start_and_follow(mp, flavour, len(rows))
        times.append(("mission", time.monotonic() - t0))
    finally:
        print(f"\nMAVProxy on the {flavour} vehicle: " + ", ".join(
            f"{name} {dt:.2f} s" for name, dt in times))
        mp.proc.kill()
        mp.proc.wait(10)
        vehicle.send_signal(signal.SIGTERM)
        try:
            vehicle.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            vehicle.kill()
            vehicle.communicate()
            raise
    assert vehicle.returncode == 0
