"""A point-mass craft for the simulated autopilot when physics is not wanted
(`swarmd sim vehicle --no-physics`): the same modes and interface as `QuadRobot`
(sim/physics/robot.py) that `sim.physics.autopilot` uses, stepped kinematically.

It flies toward its setpoint at bounded speeds (the X2 preset's cruise: 2.25 m/s
horizontally, 1.5 m/s vertically, docs/physics.md), climbs `TAKEOFF_HEIGHT` straight up
first, lands at `LAND_SPEED`, and with a motor out it falls until it hits the ground
(CRASHED). No attitude, no motor lag, no battery model: a ground station or SDK sees a
craft that goes where it is told, at a few microseconds of CPU a step.
"""

from __future__ import annotations

import asyncio
import math

from sim.physics.model import GRAVITY, Vec3
from sim.physics.robot import LAND_SPEED, TAKEOFF_HEIGHT, Mode
from swarmd.base.functions import Flight
from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback

STEP = 0.02
"""s per kinematic step (50 Hz)."""
SPEED_XY, SPEED_Z = 2.25, 1.5
"""m/s: cruise speeds (the X2 preset's, sim/physics/controller.py Gains)."""
GAIN = 2.0
"""1/s: speed per metre of position error before the speed limits."""


def _clamp(v: float, limit: float) -> float:
    return max(-limit, min(limit, v))


class PointRobot:
    """A craft as a point: see the module docstring."""

    def __init__(self, robot_id: int, home: Vec3 = (0.0, 0.0, 0.0)) -> None:
        self.robot_id = robot_id
        self.home = (float(home[0]), float(home[1]), float(home[2]))
        self.t = 0.0
        self.mode = Mode.PARKED
        self.function: str | None = None
        self.flight: Flight | None = None
        self.t0 = 0.0
        self.battery = 1.0
        self.failed_motors: set[int] = set()
        self._pos = list(self.home)
        self._vel = [0.0, 0.0, 0.0]
        self._land_xy: tuple[float, float] | None = None

    @property
    def position(self) -> Vec3:
        return (self._pos[0], self._pos[1], self._pos[2])

    @property
    def velocity(self) -> Vec3:
        return (self._vel[0], self._vel[1], self._vel[2])

    @property
    def attitude(self) -> tuple[float, float, float, float]:
        return (1.0, 0.0, 0.0, 0.0)  # level, facing east (no attitude is simulated)

    def health(self) -> Health:
        return Health.FAULTY if self.failed_motors or self.mode is Mode.CRASHED else Health.OK

    def fly(self, function: str, flight: Flight) -> bool:
        """As `QuadRobot.fly`: follow `flight`, taking off first from the ground."""
        if self.mode is Mode.CRASHED or self.failed_motors:
            return False
        self.function = function
        self.flight = flight
        low = self._pos[2] < self.home[2] + TAKEOFF_HEIGHT
        self.mode = Mode.TAKEOFF if self.mode in (Mode.PARKED, Mode.LANDING) and low else (
            Mode.FLYING)
        return True

    def release(self, function: str | None = None, *, here: bool = False) -> None:
        """As `QuadRobot.release`: land at home, or where the craft is (`here`)."""
        if function is not None and function != self.function:
            return
        self.function = None
        self.flight = None
        if self.mode in (Mode.TAKEOFF, Mode.FLYING):
            self.mode = Mode.LANDING
            self._land_xy = (self._pos[0], self._pos[1]) if here else None

    def fail_motor(self, index: int = 0) -> None:
        self.failed_motors.add(index % 4)

    def step_until(self, t: float) -> None:
        while self.t + STEP <= t + 1e-9:
            self._step()
            self.t += STEP

    def _step(self) -> None:
        p = self._pos
        v = self._vel
        ground = self.home[2]
        if self.mode in (Mode.PARKED, Mode.CRASHED):
            v[:] = [0.0, 0.0, 0.0]
            return
        if self.failed_motors:  # a rotor out: it falls, whatever it was told
            v[0] = v[1] = 0.0
            v[2] -= GRAVITY * STEP
        elif self.mode is Mode.TAKEOFF:
            self._towards((self.home[0], self.home[1], ground + TAKEOFF_HEIGHT + 0.1))
            if p[2] >= ground + TAKEOFF_HEIGHT:
                self.mode = Mode.FLYING
        elif self.mode is Mode.FLYING and self.flight is not None:
            sp = self.flight.setpoint(self.t - self.t0, self.position)
            self._towards(sp.position, sp.velocity)
        elif self.mode is Mode.LANDING:
            hx, hy = self._land_xy or (self.home[0], self.home[1])
            if math.hypot(p[0] - hx, p[1] - hy) > 0.2 and p[2] > ground + 0.4:
                self._towards((hx, hy, p[2]))
            else:
                self._towards((hx, hy, p[2]))
                v[2] = -LAND_SPEED
        for i in range(3):
            p[i] += v[i] * STEP
        if p[2] <= ground:
            p[2] = ground
            # Touching the ground falling is a crash; landing (or a setpoint on the
            # ground) parks the craft, which the autopilot sees as landed.
            self.mode = Mode.CRASHED if self.failed_motors else Mode.PARKED
            v[:] = [0.0, 0.0, 0.0]

    def _towards(self, target: Vec3, ff: Vec3 = (0.0, 0.0, 0.0)) -> None:
        p, v = self._pos, self._vel
        vx, vy = ff[0] + GAIN * (target[0] - p[0]), ff[1] + GAIN * (target[1] - p[1])
        scale = min(1.0, SPEED_XY / max(math.hypot(vx, vy), 1e-9))
        v[0], v[1] = vx * scale, vy * scale
        v[2] = _clamp(ff[2] + GAIN * (target[2] - p[2]), SPEED_Z)


class PointLink:
    """`PointRobot` stepped on the event loop's clock: what `MavlinkAutopilot` needs of
    a `QuadLink` (sim/physics/link.py), without MuJoCo, trajectory or health reports."""

    def __init__(self, robot_id: int, home: Vec3 | None = None) -> None:
        self.robot_id = robot_id
        self.home: Vec3 = home if home is not None else (0.0, 0.0, 0.0)
        self.robot = PointRobot(robot_id, self.home)
        self._mono0: float | None = None

    @property
    def running(self) -> bool:
        return self._mono0 is not None

    async def start(self, on_health: HealthCallback) -> None:
        self._mono0 = asyncio.get_running_loop().time()

    def catch_up(self) -> None:
        """Step the point craft up to now (robot time), as `QuadLink.catch_up`."""
        if self._mono0 is not None:
            self.robot.step_until(asyncio.get_running_loop().time() - self._mono0)

    def fail_motor(self, index: int = 0) -> None:
        self.catch_up()
        self.robot.fail_motor(index)

    async def close(self) -> None:
        self._mono0 = None
