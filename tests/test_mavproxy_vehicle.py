"""MAVProxy, ArduPilot's own command-line ground station, flies a mission on the ArduPilot
flavour of `swarmd sim vehicle`, headless: it connects and downloads the parameters,
loads a QGC WPL plan (`wp load`), reads it back (`wp save`), and flies it (GUIDED, arm,
MISSION_START) until the autopilot disarmed after the landing, following MAVProxy's
progress lines.

MAVProxy is not in the dev extra: MAVProxy 1.8.75 requires opencv-python and vtk (some
hundred MB) although a headless session uses neither, so the suite's always-run second
client is tests/test_gcs_vehicle.py. Installed without them (`pip install --no-deps
MAVProxy`; its runtime needs pymavlink, pyserial and numpy, which the venv has), this test
runs; otherwise it skips. Only the ArduPilot flavour: MAVProxy's plan files treat line 0
as home, ArduPilot's convention. Every wait is bounded.
"""

from __future__ import annotations

import importlib.util
import math
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

if importlib.util.find_spec("MAVProxy") is None:
    pytest.skip("MAVProxy is not installed (pip install --no-deps MAVProxy)",
                allow_module_level=True)

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parent.parent
EARTH_RADIUS = 6_371_000.0
HOME = (-35.363261, 149.165230, 584.0)  # ArduPilot SITL's, the vehicle's default


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def plan_rows() -> list[tuple[float, ...]]:
    """QGC WPL 110 rows: home, take-off to 2 m, speed 2 m/s, three waypoints 4 m apart,
    land (index, current, frame, command, p1-p4, lat, lon, alt, autocontinue)."""

    def at(east: float, north: float) -> tuple[float, float]:
        lat = HOME[0] + math.degrees(north / EARTH_RADIUS)
        return lat, HOME[1] + math.degrees(
            east / (EARTH_RADIUS * math.cos(math.radians(HOME[0]))))

    body = [(3, 22, 0, 0, 0, 0, *at(0, 0), 2.0), (2, 178, 1, 2, -1, 0, 0.0, 0.0, 0.0),
            (3, 16, 0, 0, 0, 0, *at(0, 4), 2.0), (3, 16, 0, 0, 0, 0, *at(4, 4), 2.0),
            (3, 16, 0, 0, 0, 0, *at(4, 0), 2.0), (3, 21, 0, 0, 0, 0, *at(4, 0), 0.0)]
    rows: list[tuple[float, ...]] = [(0, 1, 0, 16, 0, 0, 0, 0, *HOME, 1)]
    rows += [(i, 0, *row, 1) for i, row in enumerate(body, start=1)]
    return rows


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


def test_mavproxy_flies_a_mission_on_the_ardupilot_vehicle(tmp_path: Path) -> None:
    port = free_port()
    vehicle = subprocess.Popen(
        [sys.executable, "-m", "swarmd.cli", "sim", "vehicle", "--autopilot", "ardupilot",
         "--port", str(port), "--gcs-port", "0", "--no-physics"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rows = plan_rows()
    (tmp_path / "plan.txt").write_text(
        "QGC WPL 110\n" + "".join("\t".join(str(v) for v in r) + "\n" for r in rows))
    mp = Console([sys.executable, "-m", "MAVProxy.mavproxy",
                  f"--master=udpout:127.0.0.1:{port}", "--source-system=255",
                  "--default-modules=wp,mode,arm,param,cmdlong,misc,link",
                  f"--state-basedir={tmp_path}"], tmp_path)
    times: list[tuple[str, float]] = []
    try:
        t0 = time.monotonic()
        mp.expect(r"Received (\d+) parameters", 20.0)
        times.append(("connect", time.monotonic() - t0))
        t0 = time.monotonic()
        mp.send("wp load plan.txt")
        ack = mp.expect(r"Got MISSION_ACK: TYPE_MISSION: (ACCEPTED|OPERATION_CANCELLED)", 15.0)
        if ack.group(1) != "ACCEPTED":
            # MAVProxy drops its plan when it sees the vehicle anew (a slow start on a
            # loaded machine); the autopilot cancelled the upload as the firmware does:
            # load it again, as a user would.
            mp.send("wp load plan.txt")
            mp.expect(r"Got MISSION_ACK: TYPE_MISSION: ACCEPTED", 15.0)
        times.append(("upload", time.monotonic() - t0))
        t0 = time.monotonic()
        mp.send("wp save back.txt")
        mp.expect(rf"Saved {len(rows)} waypoints to back.txt", 10.0)
        times.append(("download", time.monotonic() - t0))
        back = [tuple(float(v) for v in line.split("\t"))
                for line in (tmp_path / "back.txt").read_text().splitlines()[1:]]
        for got, sent in zip(back, rows, strict=True):  # current flags aside
            # Latitude and longitude travel as integers of 1e-7 degree (MISSION_ITEM_INT).
            assert got[2:] == pytest.approx(sent[2:], abs=1.5e-7), (got, sent)
        t0 = time.monotonic()
        mp.send("mode guided")
        mp.expect(r"Mode GUIDED", 5.0)
        mp.send("arm throttle")
        mp.expect(r"COMPONENT_ARM_DISARM: ACCEPTED", 5.0)
        mp.send("long MISSION_START 0 0")
        mp.expect(r"MISSION_START: ACCEPTED", 5.0)
        for seq in range(2, len(rows)):
            mp.expect(rf"waypoint {seq}\b", 20.0)  # MAVProxy's MISSION_CURRENT line
        mp.expect(r"DISARMED", 20.0)
        times.append(("mission", time.monotonic() - t0))
    finally:
        print("\nMAVProxy on the ardupilot vehicle: " + ", ".join(
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
