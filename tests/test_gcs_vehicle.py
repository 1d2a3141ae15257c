"""A ground station flies a mission on `swarmd sim vehicle`, as QGroundControl does it,
over pymavlink (MAVProxy, the Python ground station on PyPI, requires OpenCV and VTK:
too heavy for the dev extra; tests/test_mavproxy_vehicle.py runs it where it is
installed without them; docs/mavlink.md).

What QGroundControl sends on connect (its own HEARTBEAT at 1 Hz, the protocol version
request, AUTOPILOT_VERSION, the whole parameter list, the mission download), then a plan
upload read back and compared, and "Start Mission" as QGroundControl's firmware plugins
do it (PX4: arm, then Mission mode; ArduPilot: GUIDED, arm, MISSION_START), followed to
touch-down by MISSION_CURRENT and MISSION_ITEM_REACHED. One vehicle process per flavour,
a point mass (`--no-physics`); every wait is bounded. Times are printed (`pytest -s`).
"""

from __future__ import annotations

import math
import signal
import subprocess
import time
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink import mavutil
from vehicles import start_vehicle

pytestmark = pytest.mark.slow
EARTH_RADIUS = 6_371_000.0


class Station:
    """A QGroundControl-like client: system 255, component 190 (MAV_COMP_ID_MISSIONPLANNER),
    a GCS HEARTBEAT every second while it waits."""

    def __init__(self, port: int) -> None:
        self.link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=190, dialect="ardupilotmega")
        self.mav = self.link.mav
        self._beat = 0.0
        self.times: list[tuple[str, float]] = []
        self.log: list[Any] = []

    def beat(self) -> None:
        if time.monotonic() - self._beat >= 1.0:
            self._beat = time.monotonic()
            self.mav.heartbeat_send(6, 8, 0, 0, 4)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID

    def wait(self, kinds: list[str], timeout: float = 5.0,
             check: Callable[[Any], bool] = lambda m: True) -> Any:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.beat()
            m = self.link.recv_match(blocking=True, timeout=0.1)
            if m is None:
                continue
            self.log.append(m)
            if m.get_type() in kinds and check(m):
                return m
        raise AssertionError(f"no {kinds} within {timeout} s")

    def command(self, command: int, *params: float, timeout: float = 3.0) -> int:
        p = (*params, *([0.0] * (7 - len(params))))
        self.mav.command_long_send(1, 1, command, 0, *p)
        ack = self.wait(["COMMAND_ACK"], timeout, lambda m: m.command == command)
        return int(ack.result)

    def step(self, name: str, t0: float) -> None:
        self.times.append((name, time.monotonic() - t0))


def connect(st: Station, flavour: str) -> int:
    """What QGroundControl does on connect; the number of parameters."""
    st.beat()
    st.wait(["HEARTBEAT"], 10.0, lambda m: m.get_srcSystem() == 1)
    # MAV_CMD_REQUEST_PROTOCOL_VERSION: PX4 answers it; ArduPilot UNSUPPORTED.
    assert st.command(519, 1) == (0 if flavour == "px4" else 3)
    assert st.command(512, 148) == 0
    st.wait(["AUTOPILOT_VERSION"])
    st.mav.param_request_list_send(1, 1)
    first = st.wait(["PARAM_VALUE"])
    names = {first.param_id}
    while len(names) < first.param_count:
        names.add(st.wait(["PARAM_VALUE"]).param_id)
    st.mav.mission_request_list_send(1, 1, 0)
    st.wait(["MISSION_COUNT"])
    st.mav.mission_ack_send(1, 1, 0, 0)
    return len(names)


def plan(home: tuple[float, float, float], flavour: str) -> list[tuple[Any, ...]]:
    """Take-off to 2 m, speed 2 m/s, three waypoints 4 m apart, land; ArduPilot's
    plan starts with home (item 0), as QGroundControl writes it."""
    lat0, lon0, alt0 = home

    def at(east: float, north: float) -> tuple[int, int]:
        lat = lat0 + math.degrees(north / EARTH_RADIUS)
        lon = lon0 + math.degrees(east / (EARTH_RADIUS * math.cos(math.radians(lat0))))
        return round(lat * 1e7), round(lon * 1e7)

    rel = 3  # MAV_FRAME_GLOBAL_RELATIVE_ALT, QGroundControl's default
    body = [(rel, 22, 0, 0, 0, math.nan, *at(0, 0), 2.0), (2, 178, 1, 2, -1, 0, 0, 0, 0.0),
            (rel, 16, 0, 0, 0, math.nan, *at(0, 4), 2.0),
            (rel, 16, 0, 0, 0, math.nan, *at(4, 4), 2.0),
            (rel, 16, 0, 0, 0, math.nan, *at(4, 0), 2.0),
            (rel, 21, 0, 0, 0, math.nan, *at(4, 0), 0.0)]
    head = [(0, 16, 0, 0, 0, 0, round(lat0 * 1e7), round(lon0 * 1e7), alt0)]
    return (head if flavour == "ardupilot" else []) + body


def upload(st: Station, items: list[tuple[Any, ...]]) -> None:
    st.mav.mission_count_send(1, 1, len(items), 0)
    while True:
        m = st.wait(["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"])
        if m.get_type() == "MISSION_ACK":
            assert m.type == 0, f"upload refused: MAV_MISSION_RESULT {m.type}"
            return
        frame, cmd, *rest = items[m.seq]
        st.mav.mission_item_int_send(1, 1, m.seq, frame, cmd, 0, 1, *rest, 0)


def download(st: Station) -> list[tuple[Any, ...]]:
    st.mav.mission_request_list_send(1, 1, 0)
    count = st.wait(["MISSION_COUNT"]).count
    got = []
    for seq in range(count):
        st.mav.mission_request_int_send(1, 1, seq, 0)

        def this_one(m: Any, s: int = seq) -> bool:
            return bool(m.seq == s)

        m = st.wait(["MISSION_ITEM_INT"], check=this_one)
        got.append((m.frame, m.command, m.param1, m.param2, m.param3, m.param4, m.x, m.y,
                    m.z))
    st.mav.mission_ack_send(1, 1, 0, 0)
    return got


def same(a: tuple[Any, ...], b: tuple[Any, ...]) -> bool:
    return all(x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
               for x, y in zip(a, b, strict=True))


def fly(st: Station, flavour: str, count: int) -> list[int]:
    """Start the mission as QGroundControl does; the MISSION_ITEM_REACHED seqs until
    the craft landed and disarmed."""
    if flavour == "px4":
        assert st.command(400, 1) == 0
        assert st.command(176, 1, 4, 4) == 0  # AUTO.MISSION
    else:
        assert st.command(176, 1, 4) == 0  # GUIDED
        assert st.command(400, 1) == 0
        assert st.command(300, 0, 0) == 0  # MAV_CMD_MISSION_START
    reached: list[int] = []
    end = time.monotonic() + 60.0
    armed = True
    while armed or len(reached) < count:
        assert time.monotonic() < end, f"mission not flown: reached {reached}"
        m = st.wait(["MISSION_ITEM_REACHED", "HEARTBEAT"], 5.0)
        if m.get_type() == "MISSION_ITEM_REACHED" and m.seq not in reached:
            reached.append(m.seq)
        elif m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1:
            armed = bool(m.base_mode & 128)
    return reached


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_a_ground_station_flies_a_mission(flavour: str) -> None:
    vehicle = start_vehicle(flavour, "--sysid", "1", "--gcs-port", "0", "--no-physics")
    proc = vehicle.proc
    st = Station(vehicle.port)
    try:
        t0 = time.monotonic()
        n_params = connect(st, flavour)
        st.step("connect", t0)
        assert n_params > 30
        home_msg = st.wait(["HOME_POSITION"], 5.0)
        home = (home_msg.latitude / 1e7, home_msg.longitude / 1e7, home_msg.altitude / 1e3)
        items = plan(home, flavour)
        t0 = time.monotonic()
        upload(st, items)
        st.step("upload", t0)
        t0 = time.monotonic()
        back = download(st)
        st.step("download", t0)
        assert len(back) == len(items) >= 6
        assert all(same(a, b) for a, b in zip(back, items, strict=True)), back
        first = 1 if flavour == "ardupilot" else 0
        t0 = time.monotonic()
        reached = fly(st, flavour, len(items) - first)
        st.step("mission", t0)
        assert reached == list(range(first, len(items)))
        currents = [m.seq for m in st.log if m.get_type() == "MISSION_CURRENT"]
        assert set(range(first, len(items))) <= set(currents)
    finally:
        print(f"\nQGroundControl-style client on the {flavour} vehicle: " + ", ".join(
            f"{name} {dt:.2f} s" for name, dt in st.times))
        st.link.close()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise
    assert proc.returncode == 0
