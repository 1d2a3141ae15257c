"""One simulated robot: a quadrotor's physics, its controller, the function it flies and
its health, stepped by whoever owns it (a robot process in real time, tests faster).

Modes: PARKED (on the ground at `home`, motors off: a standby waits there) -> TAKEOFF
(climb above home) -> FLYING (the function) -> LANDING (back to home on `release`) ->
PARKED. CRASHED is final: the craft hit the ground while flying (for instance after a
motor failed) and its motors are cut.

Health is what the robot tells its daemon (paper Fig. 4, DESIGN rule 7): FAULTY when a
motor failed, the craft crashed, or the battery is below 5%; DEGRADED below 20%; else
OK. The battery holds `battery_s` seconds of hover and drains in proportion to thrust.

Physics runs at 500 Hz, control at 100 Hz, trajectory samples at 20 Hz.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from sim.physics.controller import Command, SE3Controller
from sim.physics.model import GRAVITY, PHYSICS_DT, Preset, Vec3, quad_xml, x2
from swarmd.base.functions import (
    Flight,
    FunctionSpec,
    flight_for,
    parse_function,
)
from swarmd.core.roles import Health

Array = NDArray[np.float64]

CONTROL_EVERY = 5
"""Physics steps per control update (500 Hz / 100 Hz)."""
CONTROL_DT = PHYSICS_DT * CONTROL_EVERY
SAMPLE_DT = 0.05
"""Trajectory sampling period, s (20 Hz is plenty for plots and a 20 fps video)."""
TAKEOFF_HEIGHT = 0.5
"""Climb this far straight up before heading for the function, m: a craft that tilts
toward a far target right off the ground would scrape it."""
LAND_SPEED = 0.5
"""Descent rate when landing, m/s."""
ARM_HEIGHT = 0.3
"""Ground contact counts as a crash only after the craft was this high, m."""
FALLING = "falling"
"""Trajectory mode of a craft in the air with a motor out (whatever its daemon said)."""


class Mode(Enum):
    PARKED = "parked"
    TAKEOFF = "takeoff"
    FLYING = "flying"
    LANDING = "landing"
    CRASHED = "crashed"


@dataclass(frozen=True, slots=True)
class Sample:
    """One trajectory sample: robot time, position, orientation (w, x, y, z), state."""

    t: float
    pos: Vec3
    quat: tuple[float, float, float, float]
    mode: str
    function: str | None

    def to_json(self) -> dict[str, Any]:
        return {
            "t": round(self.t, 4),
            "p": [round(v, 4) for v in self.pos],
            "q": [round(v, 5) for v in self.quat],
            "mode": self.mode,
            "function": self.function,
        }


class QuadRobot:
    """One craft. Time `t` is the robot's clock, s; `assign` takes the run's t0 on it."""

    def __init__(
        self,
        robot_id: int,
        home: Vec3 = (0.0, 0.0, 0.0),
        preset: Preset | None = None,
        *,
        battery_s: float = 1200.0,
        t: float = 0.0,
        record: bool = True,
    ) -> None:
        self.robot_id = robot_id
        self.home = (float(home[0]), float(home[1]), float(home[2]))
        self.preset = preset or x2()
        self.model = mujoco.MjModel.from_xml_string(quad_xml(self.preset, self.home))
        self.data = mujoco.MjData(self.model)
        self.controller = SE3Controller(self.preset)
        self.body = self.model.body("quad").id
        self.t_start = t
        self.mode = Mode.PARKED
        self.function: str | None = None
        self.flight: Flight | None = None
        self.t0 = 0.0
        self.battery_s = battery_s
        self.battery = 1.0
        """Charge left, fraction of full."""
        self.failed_motors: set[int] = set()
        self.crashed_at: float | None = None
        self.armed = False
        self._land_from: tuple[float, float] | None = None
        self._land_xy: tuple[float, float] | None = None
        self.record = record
        self.samples: list[Sample] = []
        self._next_sample = t
        self._steps = 0
        self._sample()

    # -- state ---------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Robot clock, s."""
        return self.t_start + self._steps * PHYSICS_DT

    @property
    def position(self) -> Vec3:
        p = self.data.qpos
        return (float(p[0]), float(p[1]), float(p[2]))

    @property
    def velocity(self) -> Vec3:
        v = self.data.qvel
        return (float(v[0]), float(v[1]), float(v[2]))

    @property
    def attitude(self) -> tuple[float, float, float, float]:
        """Orientation quaternion (w, x, y, z), world frame (x east, y north, z up)."""
        q = self.data.qpos
        return (float(q[3]), float(q[4]), float(q[5]), float(q[6]))

    def health(self) -> Health:
        """What the robot reports to its daemon (DESIGN rule 7)."""
        if self.failed_motors or self.mode is Mode.CRASHED or self.battery < 0.05:
            return Health.FAULTY
        if self.battery < 0.2:
            return Health.DEGRADED
        return Health.OK

    # -- commands from the daemon --------------------------------------------------------
    def assign(
        self, function: str, spec: FunctionSpec | Mapping[str, Any], t0: float = 0.0
    ) -> bool:
        """Fly `function` (its spec; t0 is the run's start on this robot's clock). False
        if the craft cannot fly (crashed or a motor out): its health already says so."""
        if isinstance(spec, Mapping):
            spec = parse_function(function, spec)
        if self.mode is Mode.CRASHED or self.failed_motors:
            return False
        if function == self.function and self.mode in (Mode.TAKEOFF, Mode.FLYING):
            # The same function again (a new epoch after a rejoin): keep flying it; a
            # patrol must not restart its approach from the present waypoint.
            return True
        self.t0 = t0
        return self.fly(function, flight_for(spec, self.t - t0))

    def fly(self, function: str, flight: Flight) -> bool:
        """Fly `flight` (its setpoints on the clock `self.t - self.t0`); take off first
        from the ground. A simulated autopilot flies its position setpoints this way."""
        if self.mode is Mode.CRASHED or self.failed_motors:
            return False
        self.function = function
        self.flight = flight
        self.controller.reset()
        if self.mode in (Mode.PARKED, Mode.LANDING) and self.position[2] < (
            self.home[2] + TAKEOFF_HEIGHT
        ):
            self.mode = Mode.TAKEOFF
            self.armed = False
        else:
            self.mode = Mode.FLYING
        return True

    def release(self, function: str | None = None, *, here: bool = False) -> None:
        """Stop the function (all of them if None) and land at home (or where the craft
        is, `here`: an autopilot's LAND mode)."""
        if function is not None and function != self.function:
            return
        self.function = None
        self.flight = None
        if self.mode in (Mode.TAKEOFF, Mode.FLYING):
            self.mode = Mode.LANDING
            self._land_from = None
            self._land_xy = (self.position[0], self.position[1]) if here else None

    def fail_motor(self, index: int = 0) -> None:
        """The rotor stops producing thrust (the `motor:R@T` fault): the craft falls."""
        self.failed_motors.add(index % len(self.preset.rotors))
        self.model.actuator_gainprm[index % len(self.preset.rotors), 0] = 0.0

    def resume(self, pos: Vec3, quat: tuple[float, float, float, float], mode: str) -> None:
        """Put the craft where its previous process left it (a `restart`: the daemon
        process died and came back; the craft did not vanish). A craft that was in the
        air comes back LANDING from there: the new daemon holds no function yet (rule 2,
        its old one was taken over), and a real autopilot holds position meanwhile. A
        crashed or falling craft stays broken (its health says FAULTY at once)."""
        d = self.data
        d.qpos[0:3] = pos
        d.qpos[3:7] = quat
        d.qvel[:] = 0.0
        self.function = None
        self.flight = None
        if mode == Mode.CRASHED.value:
            self.mode = Mode.CRASHED
            self.crashed_at = self.t
        elif mode == FALLING:  # a restart does not mend the rotor: it keeps falling
            self.mode = Mode.LANDING
            self.fail_motor(0)
        elif mode == Mode.PARKED.value or pos[2] < self.home[2] + self.preset.rest_height + 0.05:
            self.mode = Mode.PARKED
        else:
            self.mode = Mode.LANDING
            self._land_from = None
            self.armed = True
            # Motors already at hover thrust (their lag state too): no drop on resume.
            d.ctrl[:] = self.preset.hover_thrust
            d.act[:] = self.preset.hover_thrust
        mujoco.mj_forward(self.model, d)
        self.samples = []
        self._next_sample = self.t
        self._sample()

    # -- stepping ------------------------------------------------------------------------
    def step_until(self, t: float) -> None:
        """Advance physics to robot time `t` (500 Hz physics, 100 Hz control)."""
        n = math.floor((t - self.t) / PHYSICS_DT + 1e-9)
        while n > 0:
            if self._steps % CONTROL_EVERY == 0:
                self._control()
            k = min(n, CONTROL_EVERY - self._steps % CONTROL_EVERY)
            mujoco.mj_step(self.model, self.data, nstep=k)
            self._steps += k
            n -= k
            if self.record and self.t >= self._next_sample - 1e-9:
                self._sample()

    def sample_now(self) -> None:
        """Record the present state now (the last sample before a flush at the end)."""
        if not self.samples or self.samples[-1].t < self.t:
            self._sample()

    def _sample(self) -> None:
        q = self.data.qpos
        mode = self.mode.value
        if self.failed_motors and self.mode not in (Mode.PARKED, Mode.CRASHED):
            mode = FALLING  # not "landing" after the daemon's release: it cannot land
        self.samples.append(
            Sample(
                self.t,
                (float(q[0]), float(q[1]), float(q[2])),
                (float(q[3]), float(q[4]), float(q[5]), float(q[6])),
                mode,
                self.function,
            )
        )
        self._next_sample += SAMPLE_DT

    def _on_ground(self) -> bool:
        return bool(self.data.ncon > 0)

    def _control(self) -> None:
        d = self.data
        pos = self.position
        z_home = self.home[2]
        self._drain_battery()
        self._check_crash(pos)
        if self.mode in (Mode.PARKED, Mode.CRASHED):
            d.ctrl[:] = 0.0
            return
        target: Vec3
        vel: Vec3 = (0.0, 0.0, 0.0)
        if self.mode is Mode.TAKEOFF:
            target = (self.home[0], self.home[1], z_home + TAKEOFF_HEIGHT + 0.1)
            if pos[2] >= z_home + TAKEOFF_HEIGHT:
                self.mode = Mode.FLYING
        if self.mode is Mode.FLYING:
            assert self.flight is not None
            sp = self.flight.setpoint(self.t - self.t0, pos)
            target, vel = sp.position, sp.velocity
        elif self.mode is Mode.LANDING:
            target, vel = self._landing_setpoint(pos)
            if target[2] <= z_home and self._on_ground():
                self.mode = Mode.PARKED
                self.armed = False
                d.ctrl[:] = 0.0
                return
        rot = d.xmat[self.body].reshape(3, 3)
        cmd = Command(np.array(target), np.array(vel), np.zeros(3))
        d.ctrl[:] = self.controller.update(
            d.qpos[0:3].copy(), d.qvel[0:3].copy(), rot, d.qvel[3:6].copy(), cmd, CONTROL_DT
        )

    def _drain_battery(self) -> None:
        # Battery: drain in proportion to thrust, 1.0 = hover (per control period).
        thrust = float(np.sum(self.data.actuator_force))
        self.battery = max(
            0.0,
            self.battery
            - thrust / (self.preset.mass * GRAVITY) * CONTROL_DT / self.battery_s,
        )

    def _check_crash(self, pos: Vec3) -> None:
        """Arm once above ARM_HEIGHT; an armed or falling craft on the ground crashed."""
        # A craft with a motor out is falling whatever it was told (the daemon releases
        # it after LEAVE, rule 7): touching the ground then is a crash, never a landing.
        falling = bool(self.failed_motors) and self.mode is not Mode.PARKED
        if self.mode in (Mode.TAKEOFF, Mode.FLYING) or falling:
            if pos[2] > self.home[2] + ARM_HEIGHT:
                self.armed = True
            if (self.armed or falling) and self._on_ground():
                self.mode = Mode.CRASHED
                self.crashed_at = self.t

    def _landing_setpoint(self, pos: Vec3) -> tuple[Vec3, Vec3]:
        hx, hy, hz = self.home
        if self._land_xy is not None:
            hx, hy = self._land_xy
        if self._land_from is None:
            self._land_from = (self.t, pos[2])
        if math.hypot(pos[0] - hx, pos[1] - hy) > 0.2 and self._land_from[1] > hz + 0.4:
            # Go home at the current height first, then descend.
            self._land_from = (self.t, pos[2])
            return (hx, hy, pos[2]), (0.0, 0.0, 0.0)
        t_from, z_from = self._land_from
        z = max(hz - 0.1, z_from - LAND_SPEED * (self.t - t_from))
        return (hx, hy, z), (0.0, 0.0, -LAND_SPEED if z > hz - 0.1 else 0.0)

    # -- recording -----------------------------------------------------------------------
    def write_trajectory(self, path: Path, *, wall0: float | None = None) -> None:
        """JSON Lines: a header `{"robot", "preset", "home", "wall0"}` (wall0: Unix time
        of robot time 0, if the clock was a wall clock), then one sample a line."""
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("w") as f:
            header = {
                "robot": self.robot_id,
                "preset": self.preset.name,
                "home": list(self.home),
                "wall0": wall0,
            }
            f.write(json.dumps(header) + "\n")
            for s in self.samples:
                f.write(json.dumps(s.to_json()) + "\n")


@dataclass(frozen=True, slots=True)
class Trajectory:
    """A recorded trajectory: times (run seconds), positions (N x 3), quats (N x 4)."""

    robot: int
    t: Array
    pos: Array
    quat: Array
    modes: tuple[str, ...]
    functions: tuple[str | None, ...]
    home: Vec3 = (0.0, 0.0, 0.0)

    def at(self, t: float) -> tuple[Array, Array]:
        """Position and orientation at run time `t` (held at the ends, linear between)."""
        i = int(np.searchsorted(self.t, t))
        if i <= 0:
            return self.pos[0], self.quat[0]
        if i >= len(self.t):
            return self.pos[-1], self.quat[-1]
        u = (t - self.t[i - 1]) / max(self.t[i] - self.t[i - 1], 1e-9)
        q = self.quat[i - 1] * (1 - u) + self.quat[i] * u
        return self.pos[i - 1] * (1 - u) + self.pos[i] * u, q / np.linalg.norm(q)


def trajectory_of(robot: QuadRobot, t_shift: float = 0.0) -> Trajectory:
    """The robot's samples as a Trajectory; run time = robot time + t_shift."""
    return _trajectory(robot.robot_id, robot.home, [s.to_json() for s in robot.samples], t_shift)


def _trajectory(
    rid: int, home: Vec3, rows: list[dict[str, Any]], t_shift: float
) -> Trajectory:
    n = len(rows)
    t = np.array([r["t"] for r in rows], dtype=np.float64) + t_shift
    pos = np.array([r["p"] for r in rows], dtype=np.float64).reshape(n, 3)
    quat = np.array([r["q"] for r in rows], dtype=np.float64).reshape(n, 4)
    return Trajectory(
        rid,
        t,
        pos,
        quat,
        tuple(str(r.get("mode", "")) for r in rows),
        tuple(r.get("function") for r in rows),
        home,
    )


def last_state(
    path: Path, since: float
) -> tuple[Vec3, tuple[float, float, float, float], str] | None:
    """(position, orientation, mode) of the last sample in a trajectory file written at
    or after Unix time `since` (this run's t0: a file left by an earlier run into the
    same directory is not this craft's state), or None."""
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return None
    for line in reversed(lines):  # the last whole sample: a SIGKILL can cut the last line
        if '"p"' not in line:
            continue
        try:
            row = json.loads(line)
            w = float(row["w"])
            p = row["p"]
            q = row["q"]
            mode = str(row["mode"])
            pos = (float(p[0]), float(p[1]), float(p[2]))
            quat = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        except (ValueError, KeyError, TypeError, IndexError):
            continue
        return (pos, quat, mode) if w >= since else None
    return None


def load_trajectory(path: Path, t0: float | None = None) -> Trajectory:
    """Read a trajectory file: header lines `{"robot", "preset", "home", "wall0"}` (one
    per process start: a restarted robot appends) and samples `{"t", "p", "q", "mode",
    "function"[, "w"]}`. With `t0` (the run's start, Unix time) times become run
    seconds, from each sample's Unix time `w` or its header's `wall0`; otherwise they
    stay on the robot's clock. Lines that do not parse are skipped (a SIGKILL can cut
    the last one)."""
    rid = 0
    home = (0.0, 0.0, 0.0)
    wall0 = None
    rows: list[dict[str, Any]] = []
    with path.open() as f:
        for line in f:
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if not isinstance(row, dict):
                continue
            if "robot" in row:
                rid = int(row["robot"])
                h = row.get("home") or (0.0, 0.0, 0.0)
                home = (float(h[0]), float(h[1]), float(h[2]))
                wall0 = row.get("wall0")
                if t0 is not None and wall0 is not None:
                    # A new process of this robot from here on: drop what the previous
                    # one simulated ahead of the clock (QuadLink.close lands the craft
                    # fast-forwarded), or the replay would flicker between the two.
                    rows = [r for r in rows if float(r["t"]) < float(wall0) - t0]
                continue
            if not {"t", "p", "q"} <= row.keys():
                continue
            if t0 is not None:
                if "w" in row:
                    row["t"] = float(row["w"]) - t0
                elif wall0 is not None:
                    row["t"] = float(row["t"]) + float(wall0) - t0
            rows.append(row)
    if not rows:
        raise ValueError(f"{path}: no trajectory samples")
    rows.sort(key=lambda r: float(r["t"]))
    return _trajectory(rid, home, rows, 0.0)
