"""An independent client flies `swarmd sim vehicle`: MAVSDK (the C++ MAVSDK core the
`mavsdk` wheel ships) connects, reads parameters and the version, arms, takes off,
goes to a global position, holds, flies offboard and lands, on both flavours; and
uploads a mission, reads it back and flies it to touch-down with its progress.

MAVSDK decides by itself what to send (which mode before which command, which
parameter, which encoding) from the HEARTBEAT's autopilot field, so each step passing
means the vehicle answered as that firmware would. One real vehicle process per
flavour, a point mass (`--no-physics`) so the flight takes seconds of wall time; every
wait is bounded. Each step's time is printed (`pytest -s`).
"""

from __future__ import annotations

import asyncio
import math
import signal
import subprocess
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from vehicles import start_vehicle

mavsdk = pytest.importorskip("mavsdk", reason="the mavsdk wheel (the dev extra) is needed")

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, System  # noqa: E402
from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: E402
from mavsdk.asyncio.plugins.info import InfoAsync  # noqa: E402
from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync  # noqa: E402
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw  # noqa: E402
from mavsdk.asyncio.plugins.param import ParamAsync  # noqa: E402
from mavsdk.asyncio.plugins.telemetry import (  # noqa: E402
    FlightMode,
    LandedState,
    TelemetryAsync,
)

pytestmark = pytest.mark.slow
EARTH_RADIUS = 6_371_000.0


async def until(check: Callable[[], Awaitable[bool]], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not await check():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        await asyncio.sleep(0.1)


class Steps:
    """Times each step of the flight; the table is printed at the end."""

    def __init__(self, flavour: str) -> None:
        self.flavour = flavour
        self.times: list[tuple[str, float]] = []

    async def run(self, name: str, step: Awaitable[Any], timeout: float = 15.0) -> Any:
        t0 = time.monotonic()
        result = await asyncio.wait_for(step, timeout)
        self.times.append((name, time.monotonic() - t0))
        return result

    def table(self) -> str:
        rows = "\n".join(f"  {name:<10} {dt:6.2f} s" for name, dt in self.times)
        return f"MAVSDK on the {self.flavour} vehicle:\n{rows}\n  {'total':<10} " \
               f"{sum(dt for _, dt in self.times):6.2f} s"


async def fly(system: System, flavour: str, steps: Steps) -> None:
    tel, action = TelemetryAsync(system), ActionAsync(system)

    async def ready() -> bool:
        h = await tel.health()
        return bool(h.is_armable and h.is_global_position_ok and h.is_home_position_ok)

    await steps.run("health", until(ready, 10.0, "armable, global position and home"))

    async def identify() -> Any:
        version = await InfoAsync(system).get_version()
        param = ParamAsync(system)
        if flavour == "px4":
            assert await param.get_param_float("MIS_TAKEOFF_ALT") == pytest.approx(2.5)
            await param.set_param_float("COM_DISARM_LAND", 1.0)
            assert await param.get_param_float("COM_DISARM_LAND") == pytest.approx(1.0)
        else:
            assert await param.get_param_int("DISARM_DELAY") == 10
            await param.set_param_int("DISARM_DELAY", 5)
            assert await param.get_param_int("DISARM_DELAY") == 5
        return version

    version = await steps.run("params", identify())
    assert (version.flight_sw_major, version.flight_sw_minor) == (
        (1, 15) if flavour == "px4" else (4, 5))

    home = await tel.home()
    assert abs(home.latitude_deg) > 1.0  # a real place, not 0, 0

    async def climbed(height: float) -> bool:
        return bool((await tel.position()).relative_altitude_m >= height)

    await steps.run("arm", action.arm())
    # PX4: NAV_TAKEOFF with NaN altitude -> MIS_TAKEOFF_ALT (2.5 m); ArduPilot: GUIDED,
    # then NAV_TAKEOFF to MAVSDK's own 2 m.
    await steps.run("takeoff", _both(action.takeoff(),
                                     until(lambda: climbed(1.8), 15.0, "the climb")))

    north = home.latitude_deg + math.degrees(4.0 / EARTH_RADIUS)

    async def arrived() -> bool:
        p = await tel.position()
        return bool(abs(p.latitude_deg - north) * math.radians(1) * EARTH_RADIUS < 0.3
                    and abs(p.relative_altitude_m - 2.0) < 0.3)

    await steps.run("goto", _both(action.goto_location(north, home.longitude_deg,
                                                       home.absolute_altitude_m + 2.0, 0.0),
                                  until(arrived, 15.0, "the goto position")))

    async def holding() -> bool:
        return bool(await tel.flight_mode() == FlightMode.HOLD)

    await steps.run("hold", _both(action.hold(), until(holding, 5.0, "HOLD")))

    offboard = OffboardAsync(system)

    async def at_offboard_point() -> bool:
        p = (await tel.position_velocity_ned()).position
        return bool(abs(p.north_m - 4.0) < 0.3 and abs(p.east_m - 3.0) < 0.3)

    async def offboard_flight() -> None:
        await offboard.set_position_ned(PositionNedYaw(4.0, 3.0, -2.0, 0.0))
        await offboard.start()
        await until(at_offboard_point, 10.0, "the offboard setpoint")
        await offboard.stop()

    await steps.run("offboard", offboard_flight())

    async def down_and_disarmed() -> bool:
        return bool(await tel.landed_state() == LandedState.ON_GROUND
                    and not await tel.armed())

    await steps.run("land", _both(action.land(), until(down_and_disarmed, 15.0,
                                                       "touch-down and auto-disarm")))


async def _both(command: Awaitable[Any], wait: Awaitable[None]) -> None:
    await command
    await wait


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
async def test_mavsdk_flies_the_simulated_vehicle(flavour: str) -> None:
    await with_vehicle(flavour, fly)


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
async def test_mavsdk_flies_a_mission(flavour: str) -> None:
    await with_vehicle(flavour, fly_mission)


async def with_vehicle(flavour: str,
                       flight: Callable[[System, str, Steps], Awaitable[None]]) -> None:
    """Start a vehicle process, connect MAVSDK, run `flight`, stop the vehicle."""
    # Off the loop: the wait for the vehicle's connect line blocks.
    vehicle = await asyncio.to_thread(start_vehicle, flavour, "--sysid", "1", "--gcs-port",
                                      "0", "--no-physics")
    proc = vehicle.proc
    steps = Steps(flavour)
    try:
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(config) as sdk:
            await sdk.add_any_connection(f"udpout://127.0.0.1:{vehicle.port}")
            system = await steps.run("connect", sdk.first_autopilot(timeout_s=15.0), 20.0)
            assert system is not None, "no autopilot heard"
            await flight(system, flavour, steps)
    finally:
        print("\n" + steps.table())
        proc.send_signal(signal.SIGTERM)
        try:
            out, err = proc.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise
    assert proc.returncode == 0, err[-2000:]
    out = vehicle.head + out
    assert f"udpout://127.0.0.1:{vehicle.port}" in out and "vehicle: stopped" in out


def mission_items(home: Any, flavour: str) -> list[Any]:
    """Take-off to 2 m, speed 2 m/s, three waypoints 4 m apart (0.5 m acceptance), land
    (ArduPilot's mission starts with home, item 0)."""

    def at(east: float, north: float) -> tuple[int, int]:
        lat = home.latitude_deg + math.degrees(north / EARTH_RADIUS)
        lon = home.longitude_deg + math.degrees(
            east / (EARTH_RADIUS * math.cos(math.radians(home.latitude_deg))))
        return round(lat * 1e7), round(lon * 1e7)

    body: list[tuple[int, int, float, float, float | None, float, float]] = [
            (6, 22, 0.0, 0.0, 0, 0, 2.0), (2, 178, 1.0, 2.0, None, 0, 0.0),
            (6, 16, 0.0, 0.5, 0, 4, 2.0), (6, 16, 0.0, 0.5, 4, 4, 2.0),
            (6, 16, 0.0, 0.5, 4, 0, 2.0), (6, 21, 0.0, 0.0, 4, 0, 0.0)]
    items = []
    if flavour == "ardupilot":
        x, y = at(0, 0)
        items.append(MissionItem(0, 0, 16, 1, 1, 0.0, 0.0, 0.0, 0.0, x, y,
                                 home.absolute_altitude_m, 0))
    for frame, command, p1, p2, east, north, z in body:
        x, y = at(east, north) if east is not None else (0, 0)
        current = int(not items)  # MAVSDK wants the first one marked current
        items.append(MissionItem(len(items), frame, command, current, 1, p1, p2, 0.0, 0.0,
                                 x, y, z, 0))
    return items


async def fly_mission(system: System, flavour: str, steps: Steps) -> None:
    tel, action, mission = TelemetryAsync(system), ActionAsync(system), MissionRawAsync(system)

    async def ready() -> bool:
        h = await tel.health()
        return bool(h.is_armable and h.is_global_position_ok and h.is_home_position_ok)

    await steps.run("health", until(ready, 10.0, "armable, global position and home"))
    # The parameters MAVSDK's action plugin reads and sets (PX4: RTL_RETURN_ALT; ArduPilot:
    # RTL_ALT, in cm).
    rtl = await action.get_return_to_launch_altitude()
    assert rtl == pytest.approx(60.0 if flavour == "px4" else 15.0)
    if flavour == "px4":  # MAVSDK 4.1 sets ArduPilot 4.7's RTL_ALT_M, not 4.5's RTL_ALT
        await action.set_return_to_launch_altitude(30.0)
        assert await action.get_return_to_launch_altitude() == pytest.approx(30.0)
    home = await tel.home()
    items = mission_items(home, flavour)
    await steps.run("upload", mission.upload_mission(items))
    back = await steps.run("download", mission.download_mission())

    def row(it: Any) -> tuple[Any, ...]:
        return (it.seq, it.frame, it.command, it.autocontinue, it.param1, it.param2,
                it.x, it.y, it.z)

    assert [row(it) for it in back] == [row(it) for it in items]
    first = 1 if flavour == "ardupilot" else 0
    seen: set[int] = set()

    async def finished() -> bool:
        seen.add((await mission.mission_progress()).current)
        return bool(await mission.is_mission_finished() and not await tel.armed())

    await steps.run("arm", action.arm())
    await steps.run("mission", _both(mission.start_mission(),
                                     until(finished, 40.0, "the mission's end")), 45.0)
    assert set(range(first + 2, len(items) - 1)) <= seen  # the waypoints, each current
