"""The simulated MAVLink autopilot: a ground station sees it, the daemon's link flies it.

Real time over UDP loopback (a MuJoCo craft in this process), short and bounded.
"""

from __future__ import annotations

import asyncio
import signal
import subprocess
import time
from collections.abc import Callable
from typing import Any

import pytest

pytest.importorskip("mujoco")

from pymavlink import mavutil
from vehicles import ROOT, start_vehicle, vehicle_args

from sim.physics.autopilot import SimMavlinkLink, start_autopilot
from sim.physics.autopilot_core import AutopilotCore
from sim.physics.link import QuadLink
from sim.physics.robot import QuadRobot
from swarmd.core.roles import Health

pytestmark = pytest.mark.slow


async def until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        await asyncio.sleep(0.1)


def ground_station(port: int, arm: bool) -> dict[str, Any]:
    """A ground-station role client (pymavlink's own mavutil, system 255): what it sees."""
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                      source_component=190)
    try:
        seen: dict[str, Any] = {}
        end = time.monotonic() + 20.0
        while time.monotonic() < end and not {"HEARTBEAT", "LOCAL_POSITION_NED"} <= set(seen):
            conn.mav.heartbeat_send(6, 8, 0, 0, 4)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            msg = conn.recv_match(type=["HEARTBEAT", "LOCAL_POSITION_NED"], blocking=True,
                                  timeout=0.5)
            if msg is not None:
                seen[msg.get_type()] = msg
        seen["mode"] = conn.flightmode
        seen["system"] = conn.target_system
        if arm:
            conn.mav.command_long_send(conn.target_system, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            seen["ack"] = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=10.0)
        return seen
    finally:
        conn.close()


# Each firmware's boot mode without RC: PX4 Hold (AUTO.LOITER), ArduCopter STABILIZE.
@pytest.mark.parametrize(("flavour", "mode", "refused"), [("px4", "LOITER", 1),
                                                           ("ardupilot", "STABILIZE", 4)])
async def test_a_ground_station_sees_the_vehicle_its_position_and_mode(
        flavour: str, mode: str, refused: int) -> None:
    quad = QuadLink(3, (2.0, -1.0, 0.0))
    # Port 0: the autopilot binds the port the kernel gives it, and the ground station
    # sends to that one. A port probed free before could be taken by another process
    # before the autopilot bound it.
    ap = await start_autopilot(quad, flavour, 0)  # type: ignore[arg-type]
    ap.refuse_arm = True
    try:
        assert ap.port != 0
        seen = await asyncio.to_thread(ground_station, ap.port, True)
    finally:
        await ap.close()
        await quad.close()
    hb = seen["HEARTBEAT"]
    assert seen["system"] == 3
    assert hb.autopilot == (12 if flavour == "px4" else 3) and hb.type == 2  # quadrotor
    assert seen["mode"] == mode  # pymavlink decodes the flavour's own mode encoding
    pos = seen["LOCAL_POSITION_NED"]
    assert abs(pos.x) < 0.1 and abs(pos.y) < 0.1  # parked on its home: the NED origin
    assert seen["ack"] is not None and seen["ack"].command == 400
    # The refuse-arm switch, answered as the firmware answers a failed arming check:
    # PX4 TEMPORARILY_REJECTED, ArduPilot FAILED.
    assert seen["ack"].result == refused


def test_a_failed_motor_shows_in_health_bits_and_emergency() -> None:
    core = AutopilotCore(QuadRobot(1, (0.0, 0.0, 0.0)), "ardupilot", 1)
    assert core.system_status() == 3 and core.sensors_health() & 32768
    core.robot.fail_motor(1)
    assert core.system_status() == 6  # EMERGENCY
    assert not core.sensors_health() & 32768  # motor outputs unhealthy
    msgs = core.telemetry(0.0)
    sys_status = next(m for m in msgs if m.get_type() == "SYS_STATUS")
    assert not sys_status.onboard_control_sensors_health & 32768


class Health_:
    def __init__(self) -> None:
        self.values: list[Health] = []

    def __call__(self, h: Health) -> None:
        self.values.append(h)

    @property
    def last(self) -> Health | None:
        return self.values[-1] if self.values else None


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
async def test_the_link_flies_the_slot_and_hears_the_motor_failure(flavour: str) -> None:
    home = (1.0, -2.0, 0.0)
    link = SimMavlinkLink(QuadLink(2, home), flavour)  # type: ignore[arg-type]
    health = Health_()
    await link.start(health)
    try:
        # Its autopilot's port is the kernel's pick at the bind, never probed before
        # (another process could take a probed port first), and the link talks to it.
        assert link.port != 0 and link.link.url == f"udpout:127.0.0.1:{link.port}"
        await until(lambda: health.last is Health.OK, 15.0, "health ok")
        slot = (3.0, 1.0, 1.5)
        link.assign("f2", 1, {"kind": "slot", "position": list(slot)})

        def err() -> float:
            p = link.quad.robot.position
            return float(sum((p[i] - slot[i]) ** 2 for i in range(3)) ** 0.5)

        await until(lambda: err() < 0.5, 40.0, "the craft in its slot")
        assert health.last is Health.OK
        link.fail_motor(2)
        t_fail = time.monotonic()
        await until(lambda: health.last is Health.FAULTY, 10.0, "faulty through MAVLink")
        assert time.monotonic() - t_fail < 10.0
        assert link.link.last is not None
        assert any("motors" in r or "EMERGENCY" in r for r in link.link.last.reasons)
    finally:
        await link.close()


async def test_a_refused_arm_is_reported_as_a_health_problem() -> None:
    link = SimMavlinkLink(QuadLink(4, (0.0, 0.0, 0.0)), "ardupilot", refuse_arm=True)
    health = Health_()
    await link.start(health)
    try:
        await until(lambda: health.last is Health.OK, 15.0, "health ok")
        link.assign("f1", 1, {"kind": "slot", "position": [0.0, 0.0, 1.5]})
        await until(lambda: health.last is Health.FAULTY, 15.0, "faulty after the refusal")
        assert link.link.last is not None and "arm" in link.link.last.reasons[0]
        assert link.quad.robot.position[2] < 0.2  # it never left the ground
    finally:
        await link.close()


OPTIONS = ("--sysid", "7", "--gcs-port", "0", "--no-physics")


def test_sim_vehicle_says_where_to_connect_and_ends_cleanly_on_ctrl_c() -> None:
    # On `--port 0` (tests/vehicles.py): its first lines come once it listens, and they
    # name the port the kernel gave it (bounded: a silent process fails here).
    vehicle = start_vehicle("ardupilot", *OPTIONS)
    proc, port = vehicle.proc, vehicle.port
    try:
        first = vehicle.head.splitlines()[:2]
        assert port != 0
        assert any(f"udpout://127.0.0.1:{port}" in line for line in first), first
        seen = ground_station(port, arm=False)
        assert seen["system"] == 7 and seen["HEARTBEAT"].autopilot == 3
        # A second vehicle on the same port: one line, exit 1. The first one holds the
        # port all along, so no other process can have it.
        busy = subprocess.run(vehicle_args("ardupilot", port, *OPTIONS), cwd=ROOT,
                              capture_output=True, text=True, timeout=60)
        assert busy.returncode == 1 and busy.stderr.strip().startswith(
            f"--port: cannot listen on 127.0.0.1:{port}"), busy.stderr
        assert len(busy.stderr.strip().splitlines()) == 1
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise
    assert proc.returncode == 0, err[-2000:]
    assert (vehicle.head + out).rstrip().endswith("vehicle: stopped")
