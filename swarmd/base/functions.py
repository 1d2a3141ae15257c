"""Functions a craft flies, from the swarm file's `functions:` mapping, as setpoints.

Kinds (DESIGN section 3):
- `slot`: `{kind: slot, position: [x, y, z]}` - hold a position in a formation.
- `patrol`: `{kind: patrol, waypoints: [[x, y, z], ...], speed: v}` - fly a closed loop
  of waypoints at `speed` m/s.

Patrol progress is set by a clock the whole swarm shares: seconds since the run's t0.
The *nominal* holder of a patrol is at arc length `speed * t` (mod the loop length), so
every robot can compute, without asking anyone, which waypoint the holder was heading to
at time t. A substitute assigned at t flies straight to that waypoint (the failed robot's
next waypoint), then continues the loop in order from it: it waits there if it arrived
ahead of the schedule, or runs at `catchup` x speed until it is back on it. The first
holder does the same from its take-off, so the holder is on the schedule except right
after it starts, and a takeover resumes the patrol where it was, not from the start.

Everything here is pure (no physics) so it is tested on its own.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

Vec3 = tuple[float, float, float]


MIN_ALTITUDE = 0.2
"""Lowest height a function may ask for, m. A parked X2 rests with its centre 4 cm up
and a move overshoots by a few cm; ground contact after take-off is a crash
(`sim.physics.robot`), so a slot or waypoint lower than this (or under the ground) would
fly the craft into the ground: refused before the run, not found out in a robot."""
MAX_SPEED = 50.0
"""Patrol speed bound, m/s (exclusive): far above what the presets fly (~2-4 m/s)."""


class FunctionSpecError(ValueError):
    """A function entry the craft cannot fly: `loc` is the swarm-file field
    (`functions.p1.waypoints[2]`), `reason` what is wrong with it."""

    def __init__(self, name: str, key: str, reason: str) -> None:
        self.loc = f"functions.{name}" + (f".{key}" if key else "")
        self.reason = reason
        super().__init__(f"function {name}: {key + ' ' if key else ''}{reason}")


@dataclass(frozen=True, slots=True)
class Setpoint:
    """Where the craft should be now, and how fast that point moves (world frame)."""

    position: Vec3
    velocity: Vec3 = (0.0, 0.0, 0.0)
    yaw: float = 0.0


@dataclass(frozen=True, slots=True)
class SlotSpec:
    """Hold `position`."""

    position: Vec3


@dataclass(frozen=True, slots=True)
class PatrolSpec:
    """A closed loop of `waypoints` flown at `speed` m/s."""

    waypoints: tuple[Vec3, ...]
    speed: float
    arcs: tuple[float, ...] = field(init=False, repr=False, compare=False)
    """Arc length at each waypoint from waypoint 0; arcs[n] is the loop length."""

    def __post_init__(self) -> None:
        arcs = [0.0]
        n = len(self.waypoints)
        for i in range(n):
            arcs.append(arcs[-1] + _dist(self.waypoints[i], self.waypoints[(i + 1) % n]))
        object.__setattr__(self, "arcs", tuple(arcs))

    @property
    def length(self) -> float:
        """Loop length, m."""
        return self.arcs[-1]

    def point(self, s: float) -> tuple[Vec3, Vec3]:
        """Position at arc length `s` (any real, wraps) and the unit direction there."""
        n = len(self.waypoints)
        s = s % self.length
        i = min(bisect.bisect_right(self.arcs, s) - 1, n - 1)
        a, b = self.waypoints[i], self.waypoints[(i + 1) % n]
        seg = self.arcs[i + 1] - self.arcs[i]
        u = (s - self.arcs[i]) / seg
        d = tuple((b[k] - a[k]) / seg for k in range(3))
        return _lerp(a, b, u), (d[0], d[1], d[2])

    def next_after(self, s: float) -> tuple[int, float]:
        """The first waypoint strictly ahead of unwrapped arc length `s`: (index, its
        unwrapped arc length)."""
        n = len(self.waypoints)
        loops = math.floor(s / self.length)
        within = s - loops * self.length
        i = bisect.bisect_right(self.arcs, within)  # arcs[i] > within
        if i > n:  # float edge: exactly at the loop end
            loops, i = loops + 1, 1
        return i % n, loops * self.length + self.arcs[i]


FunctionSpec = SlotSpec | PatrolSpec


def _dist(a: Vec3, b: Vec3) -> float:
    return math.sqrt(sum((a[k] - b[k]) ** 2 for k in range(3)))


def _lerp(a: Vec3, b: Vec3, u: float) -> Vec3:
    return (a[0] + (b[0] - a[0]) * u, a[1] + (b[1] - a[1]) * u, a[2] + (b[2] - a[2]) * u)


def _vec3(name: str, key: str, value: Any) -> Vec3:
    if (
        not isinstance(value, list | tuple)
        or len(value) != 3
        or not all(isinstance(v, int | float) and math.isfinite(v) for v in value)
    ):
        raise FunctionSpecError(name, key, f"must be [x, y, z] finite numbers, got {value!r}")
    if value[2] < MIN_ALTITUDE:
        where = "under the ground" if value[2] < 0 else "too close to the ground"
        raise FunctionSpecError(
            name, key, f"z = {value[2]} m is {where}: a craft flies at z >= {MIN_ALTITUDE} m"
        )
    return (float(value[0]), float(value[1]), float(value[2]))


def parse_function(name: str, spec: Mapping[str, Any]) -> FunctionSpec:
    """One entry of the swarm file's `functions:` mapping. Extra keys (the runtime adds
    `t0`) are ignored. Raises FunctionSpecError naming the field."""
    kind = spec.get("kind", "slot" if "position" in spec else None)
    if kind == "slot":
        return SlotSpec(_vec3(name, "position", spec.get("position")))
    if kind == "patrol":
        raw = spec.get("waypoints")
        if not isinstance(raw, list | tuple) or len(raw) < 2:
            raise FunctionSpecError(name, "waypoints", "must list at least 2 points")
        wps = tuple(_vec3(name, f"waypoints[{i}]", w) for i, w in enumerate(raw))
        for i in range(len(wps)):
            j = (i + 1) % len(wps)
            if _dist(wps[i], wps[j]) < 1e-6:
                # A zero-length leg has no direction: the setpoint would divide by zero.
                raise FunctionSpecError(
                    name, f"waypoints[{j}]", f"coincide with waypoints[{i}] (a closed loop: "
                    "the last one is followed by the first)")
        speed = spec.get("speed", 1.0)
        if (not isinstance(speed, int | float) or isinstance(speed, bool)
                or not 0 < speed < MAX_SPEED):
            raise FunctionSpecError(name, "speed", f"must be in (0, {MAX_SPEED:g}) m/s: {speed!r}")
        return PatrolSpec(wps, float(speed))
    raise FunctionSpecError(name, "kind", f"must be 'slot' or 'patrol', got {kind!r}")


def parse_functions(functions: Mapping[str, Mapping[str, Any]]) -> dict[str, FunctionSpec]:
    """The whole `functions:` mapping."""
    return {name: parse_function(name, spec) for name, spec in functions.items()}


def flight_problems(functions: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """What a craft could not fly in a swarm file's `functions:` mapping, one
    `"functions.<name>.<field>: <reason>"` per bad function (empty: all flyable). For
    `swarmd sim` with physics to refuse a swarm up front, before any robot process
    starts, instead of a robot logging that it cannot fly its function."""
    problems = []
    for name, spec in functions.items():
        try:
            parse_function(name, spec)
        except FunctionSpecError as exc:
            problems.append(f"{exc.loc}: {exc.reason}")
    return problems


def next_waypoint(spec: PatrolSpec, t: float) -> int:
    """Index of the waypoint the patrol's holder is heading to at run time `t`."""
    return spec.next_after(spec.speed * t)[0]


class Flight(Protocol):
    """A function being flown: the setpoint at run time `t`, given where the craft is."""

    def setpoint(self, t: float, position: Vec3) -> Setpoint: ...

    @property
    def target(self) -> Vec3:
        """Where the craft is heading now (a slot, or the next patrol waypoint)."""
        ...


class SlotFlight:
    """Hold the slot's position."""

    def __init__(self, spec: SlotSpec) -> None:
        self.spec = spec

    def setpoint(self, t: float, position: Vec3) -> Setpoint:
        return Setpoint(self.spec.position)

    @property
    def target(self) -> Vec3:
        return self.spec.position


class PatrolFlight:
    """Fly to the waypoint the holder was heading to at `t_assign`, then the loop."""

    ARRIVE = 0.3
    """Distance at which the first waypoint counts as reached, m."""

    def __init__(self, spec: PatrolSpec, t_assign: float, catchup: float = 1.5) -> None:
        self.spec = spec
        self.first, self.s_first = spec.next_after(spec.speed * t_assign)
        self.catchup = catchup
        self.t_arrived: float | None = None
        self._late = False
        self._s = self.s_first

    def progress(self, t: float) -> float:
        """Unwrapped arc length this craft should be at (after arrival)."""
        assert self.t_arrived is not None
        nominal = self.spec.speed * t
        if not self._late:  # early: wait at the waypoint for the schedule
            return max(self.s_first, nominal)
        run = self.s_first + self.catchup * self.spec.speed * (t - self.t_arrived)
        return min(nominal, run)

    def setpoint(self, t: float, position: Vec3) -> Setpoint:
        wp = self.spec.waypoints[self.first]
        if self.t_arrived is None:
            if _dist(position, wp) > self.ARRIVE:
                return Setpoint(wp)  # straight there (the controller saturates the error)
            self.t_arrived = t
            self._late = self.spec.speed * t > self.s_first
        s = self.progress(t)
        self._s = s
        pos, d = self.spec.point(s)
        nominal = self.spec.speed * t
        rate = 0.0
        if s >= nominal - 1e-9 and nominal >= self.s_first:
            rate = self.spec.speed
        elif self._late and s < nominal:
            rate = self.catchup * self.spec.speed
        return Setpoint(pos, (d[0] * rate, d[1] * rate, d[2] * rate))

    def heading_to(self) -> int:
        """Index of the waypoint this craft is heading to (as of the last setpoint)."""
        if self.t_arrived is None:
            return self.first
        return self.spec.next_after(self._s)[0]

    @property
    def target(self) -> Vec3:
        return self.spec.waypoints[self.heading_to()]


def flight_for(spec: FunctionSpec, t_assign: float) -> SlotFlight | PatrolFlight:
    """The flight of a function assigned at run time `t_assign`."""
    if isinstance(spec, SlotSpec):
        return SlotFlight(spec)
    return PatrolFlight(spec, t_assign)
