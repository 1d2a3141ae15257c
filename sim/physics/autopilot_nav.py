"""How the simulated autopilot flies on its own (`sim.physics.autopilot` has the whole
picture): the craft's setpoint, which in the auto modes moves along a straight leg at the
firmware's speed parameters, legs with an acceptance radius and a hold time, and the
legs of each firmware's Return.

- Speeds: PX4 flies its auto modes at MPC_XY_CRUISE (capped by MPC_XY_VEL_MAX) and
  MPC_Z_V_AUTO_UP / _DN (capped by MPC_Z_VEL_MAX_UP / _DN); ArduCopter at WPNAV_SPEED,
  WPNAV_SPEED_UP and WPNAV_SPEED_DN (cm/s). The craft's own cruise (2.25 m/s across,
  1.5 m/s up and down, sim/physics/point.py) caps them all, so a value above it changes
  nothing and one below it slows the craft down.
- Return, PX4 (`navigator/rtl_direct.cpp`, the return altitude of its cone): climb to the
  return altitude, fly home, descend to RTL_DESCEND_ALT, wait RTL_LAND_DELAY, land.
- Return, ArduCopter (`ArduCopter/mode_rtl.cpp`): climb to RTL_ALT (lowered near home by
  RTL_CONE_SLOPE), fly home, wait RTL_LOIT_TIME, then land, or stop at RTL_ALT_FINAL.

Pure: no messages, no state of the autopilot (`autopilot_core` runs the legs).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from sim.physics.point import SPEED_XY, SPEED_Z
from swarmd.base.functions import Setpoint, Vec3
from swarmd.link.mavlink_modes import Flavour

Param = Callable[[str], float]
"""A parameter's value by name."""

APM_MIN_CLIMB = 2.5
"""m: ArduCopter's RTL climbs at least this much when the cone lowers RTL_ALT
(RTL_ABS_MIN_CLIMB, 250 cm, `mode_rtl.cpp`)."""
APM_RTL_ALT_MIN = 2.0
"""m: the lowest RTL_ALT ArduCopter uses (RTL_ALT_MIN, 200 cm, `mode_rtl.cpp`)."""
APM_ALT_RADIUS = 0.3
"""m: when the simulated ArduCopter counts a height as reached (its position controller
has no parameter for it)."""


@dataclass(frozen=True)
class Speeds:
    """m/s: across, up, down."""

    xy: float
    up: float
    down: float

    @classmethod
    def auto(cls, flavour: Flavour, p: Param, xy: float | None = None) -> Speeds:
        """The auto modes' speeds of `flavour`; `xy` replaces the cruise speed (a
        DO_CHANGE_SPEED)."""
        if flavour == "px4":
            cruise = p("MPC_XY_CRUISE") if xy is None else xy
            return cls(min(cruise, p("MPC_XY_VEL_MAX")),
                       min(p("MPC_Z_V_AUTO_UP"), p("MPC_Z_VEL_MAX_UP")),
                       min(p("MPC_Z_V_AUTO_DN"), p("MPC_Z_VEL_MAX_DN")))
        return cls(p("WPNAV_SPEED") / 100 if xy is None else xy, p("WPNAV_SPEED_UP") / 100,
                   p("WPNAV_SPEED_DN") / 100)


@dataclass(frozen=True)
class Leg:
    """One straight leg: fly to `goal` (world frame; None: land where the craft is),
    count it reached within `radius` (across, up/down), then stay `hold` s (inf: until
    told otherwise). `seq` is the mission item it flies (None: not a mission's)."""

    goal: Vec3 | None
    speeds: Speeds
    radius: tuple[float, float] = (0.5, 0.3)
    hold: float = 0.0
    seq: int | None = None

    def reached(self, here: Vec3) -> bool:
        assert self.goal is not None
        gx, gy, gz = self.goal
        return (math.hypot(here[0] - gx, here[1] - gy) <= self.radius[0]
                and abs(here[2] - gz) <= self.radius[1])


class PathTarget:
    """The craft's setpoint (a `Flight` for `QuadRobot.fly` / `PointRobot.fly`) in the
    world frame: a fixed point (offboard setpoints, hold), or a point moving along a leg
    at the leg's speeds when they are below the craft's own (the auto modes)."""

    def __init__(self, position: Vec3, clock: Callable[[], float]) -> None:
        self.position = position
        self.velocity: Vec3 = (0.0, 0.0, 0.0)
        self._clock = clock
        self._path: tuple[Vec3, Vec3, float, float] | None = None
        """start, goal, start time, duration."""

    def hold(self, position: Vec3, velocity: Vec3 = (0.0, 0.0, 0.0)) -> None:
        self.position, self.velocity, self._path = position, velocity, None

    def go(self, start: Vec3, goal: Vec3, speeds: Speeds) -> None:
        """Along the straight line from `start` to `goal` at `speeds`."""
        self.hold(goal)
        if speeds.xy >= SPEED_XY and min(speeds.up, speeds.down) >= SPEED_Z:
            return  # the craft's own limits: straight at the goal, as before a leg
        across = math.dist(start[:2], goal[:2])
        dz = goal[2] - start[2]
        vz = speeds.up if dz > 0 else speeds.down
        duration = max(across / max(speeds.xy, 0.05), abs(dz) / max(vz, 0.05))
        if duration > 0:
            self._path = (start, goal, self._clock(), duration)

    def setpoint(self, t: float, position: Vec3) -> Setpoint:
        if self._path is None:
            return Setpoint(self.position, self.velocity)
        start, goal, t0, duration = self._path
        u = (self._clock() - t0) / duration
        if u >= 1.0:
            return Setpoint(goal, (0.0, 0.0, 0.0))
        point = tuple(s + u * (g - s) for s, g in zip(start, goal, strict=True))
        velocity = tuple((g - s) / duration for s, g in zip(start, goal, strict=True))
        return Setpoint((point[0], point[1], point[2]), (velocity[0], velocity[1], velocity[2]))

    @property
    def target(self) -> Vec3:
        return self.position


def _px4_return_height(across: float, height: float, p: Param) -> float:
    """m above home PX4 returns at from `across` m away and `height` m up."""
    accept = p("NAV_ACC_RAD")
    ret = p("RTL_RETURN_ALT")
    if p("RTL_CONE_ANG") <= 0:  # no cone: RTL_RETURN_ALT from anywhere
        return max(ret, height)
    if across <= accept:
        ret = 2.0 * across
    else:
        if across <= p("RTL_MIN_DIST"):
            cone = math.radians(min(max(p("RTL_CONE_ANG"), 1.0), 89.0))
            ret = min(ret, across / math.tan(cone))
        ret = max(ret, 2.0 * accept)
    return max(ret, height)


def _apm_return_height(across: float, height: float, p: Param) -> float:
    """m above home ArduCopter returns at: RTL_ALT (at least 2 m) or RTL_CLIMB_MIN
    above where it is, lowered near home to RTL_CONE_SLOPE x the distance but at
    least 2.5 m up, never down (`mode_rtl.cpp` compute_return_target)."""
    ret = max(0.0, height + max(p("RTL_CLIMB_MIN"), 0.0) / 100,
              max(p("RTL_ALT") / 100, APM_RTL_ALT_MIN))
    slope = p("RTL_CONE_SLOPE")
    if slope >= 0.5:  # RTL_MIN_CONE_SLOPE: no shallower cone
        ret = max(height, min(ret, max(across * slope, height + APM_MIN_CLIMB)))
    return ret


def rtl_legs(flavour: Flavour, here: Vec3, home: Vec3, p: Param) -> list[Leg]:
    """The legs of a Return from `here` (world frame) to `home`, ending on the ground
    (a last leg with goal None) unless the firmware hovers there."""
    x, y, z = here
    hx, hy, hz = home
    across, height = math.hypot(x - hx, y - hy), z - hz
    speeds = Speeds.auto(flavour, p)
    if flavour == "px4":
        ret = hz + _px4_return_height(across, height, p)
        descend, wait = min(ret, hz + p("RTL_DESCEND_ALT")), p("RTL_LAND_DELAY")
        radius = (p("NAV_ACC_RAD"), p("NAV_MC_ALT_RAD"))
    else:
        ret = hz + _apm_return_height(across, height, p)
        final = p("RTL_ALT_FINAL") / 100
        descend = hz + final if 0 < final < ret - hz else ret
        wait = p("RTL_LOIT_TIME") / 1000
        radius = (p("WPNAV_RADIUS") / 100, APM_ALT_RADIUS)
    home_radius = (0.5, radius[1])  # home itself is flown to, not passed by
    legs = [Leg((x, y, ret), speeds, radius), Leg((hx, hy, ret), speeds, home_radius)]
    if flavour == "ardupilot" and descend != ret:
        return [*legs, Leg((hx, hy, descend), speeds, home_radius, hold=math.inf)]
    hover = math.inf if wait < 0 else max(wait, 0.0)
    legs.append(Leg((hx, hy, descend), speeds, home_radius, hold=hover))
    return [*legs, Leg(None, speeds)]
