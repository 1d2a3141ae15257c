"""The robot side of the link for a simulated quadrotor: `QuadLink` is a `RobotLink`
(swarmd/link/base.py) whose robot is a MuJoCo craft stepped in real time in the daemon's
own process.

Paper Fig. 4: the robot's one input to swarmd is its health, its one output from swarmd
is the function to execute. Here health comes from the craft's own state (a failed
motor, a crash, the battery: `QuadRobot.health`), so a `motor:R@T` fault, which leaves
the daemon running, is noticed through health (DESIGN rule 7: the daemon sends LEAVE),
not only through silence.

Timing: one asyncio task wakes every `wake` seconds (40 ms) and steps physics up to the
loop's clock (500 Hz physics, 100 Hz control). Waking every control period instead cost
about twice the CPU for the same result (docs/physics.md: 50 robots at 50 ms wakes used
0.67 of 2 cores, never late). Health goes to the daemon when it changes and at least
every `health_period` (0.5 s), so a daemon that times robot health out never does so
for a live craft.

Trajectory: samples (20 Hz) are appended to `traj_path` as JSON Lines at every wake,
each with its Unix time `w`, because the real-time simulator ends a run (and the `crash`
fault ends a robot) with SIGKILL: nothing may wait for `close()`.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any

from sim.physics.model import Preset, Vec3, preset, x2
from sim.physics.robot import Mode, QuadRobot, last_state
from swarmd.base.functions import FunctionSpecError, parse_function
from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback

log = logging.getLogger("swarmd.sim.physics")

WAKE = 0.04
"""s between physics catch-ups (see the module docstring)."""
HEALTH_PERIOD = 0.5
"""s: longest time between two health reports."""
STATS_PERIOD = 2.0
"""s between two lateness lines in the trajectory file."""
LAND_HORIZON = 60.0
"""s of physics `close` may fast-forward to land the craft (a 20 m flight home and a
4 m descent take ~17 s)."""


def default_home(robot_id: int) -> Vec3:
    """A parking spot for a robot whose swarm entry has no `home`: a row at y = -5 m,
    1.5 m apart (apart enough for two X2s)."""
    return (1.5 * (robot_id - 1), -5.0, 0.0)


class QuadLink:
    """A MuJoCo quadrotor behind the robot-link interface (see the module docstring)."""

    def __init__(
        self,
        robot_id: int,
        home: Vec3 | None = None,
        *,
        craft: Preset | None = None,
        traj_path: Path | None = None,
        wake: float = WAKE,
        health_period: float = HEALTH_PERIOD,
        battery_s: float = 1200.0,
        wall: Callable[[], float] = time.time,
        restart_of: float | None = None,
    ) -> None:
        self.robot_id = robot_id
        self.home = home if home is not None else default_home(robot_id)
        self.robot = QuadRobot(robot_id, self.home, craft or x2(), battery_s=battery_s)
        self.traj_path = traj_path
        self.restart_of = restart_of
        """The run's t0 (Unix time) if this process restarts a robot of that run: the
        craft resumes where the last one left it, the trajectory file is appended, and
        patrols keep the run's clock; otherwise a stale file (an earlier run into the
        same directory) is replaced."""
        if restart_of is not None and traj_path is not None:
            state = last_state(traj_path, since=restart_of)
            if state is not None:
                self.robot.resume(*state)
        self.wake = wake
        self.health_period = health_period
        self._wall = wall
        self.wall0 = wall()
        """Unix time of robot time 0 (reset by `start`)."""
        self._mono0 = 0.0
        self._on_health: HealthCallback | None = None
        self._task: asyncio.Task[None] | None = None
        self._file: IO[str] | None = None
        self._forced = Health.OK
        self._reported: Health | None = None
        self._last_report = float("-inf")

        # The link's error count and its wake-up lateness figures.
        self.errors = 0
        """Bad assignments and physics exceptions: counted and logged, never raised."""
        self.lateness: collections.deque[float] = collections.deque(maxlen=20000)
        """How late each wake-up was, s (the benchmark's real-time measure)."""
        self._window: list[float] = []
        self._last_stats = 0.0

    @classmethod
    def for_robot(cls, cfg: Any, restart_of: float | None = None,
                  craft: str | None = None) -> QuadLink:
        """Build from a loaded robot file (`swarmd.config.RobotConfig`): home from the
        swarm entry, trajectory next to the robot's state (`<state_dir>/traj-<id>.jsonl`).
        The craft is the preset `craft` names; without one, `SWARMD_QUAD_PRESET`'s, else
        the X2 (a robot process started by hand, `python -m sim.realtime.robot_proc`).
        `restart_of`: the run's t0 when this process restarts the robot (see __init__)."""
        import os

        rid = int(cfg.robot_id)
        home2 = getattr(cfg.entry, "home", None)
        home = (float(home2[0]), float(home2[1]), 0.0) if home2 is not None else None
        chosen = preset(craft or os.environ.get("SWARMD_QUAD_PRESET", "x2"))
        traj = Path(cfg.state_dir) / f"traj-{rid}.jsonl"
        return cls(rid, home, craft=chosen, traj_path=traj, restart_of=restart_of)

    @property
    def running(self) -> bool:
        """Started and stepping in real time."""
        return self._task is not None

    # -- RobotLink -----------------------------------------------------------------------
    async def start(self, on_health: HealthCallback) -> None:
        """Start stepping in real time; report health at once."""
        loop = asyncio.get_running_loop()
        self._on_health = on_health
        self.wall0 = self._wall()
        self._mono0 = loop.time()
        self._last_stats = self._mono0
        if self.traj_path is not None:
            try:
                self.traj_path.parent.mkdir(parents=True, exist_ok=True)
                self._file = self.traj_path.open("a" if self.restart_of is not None else "w")
                header = {"robot": self.robot_id, "preset": self.robot.preset.name,
                          "home": list(self.home), "wall0": self.wall0}
                self._file.write(json.dumps(header) + "\n")
            except OSError as exc:
                self.errors += 1
                log.error("robot %d: cannot write trajectory %s: %s",
                          self.robot_id, self.traj_path, exc)
        self._report(force=True)
        self._task = loop.create_task(self._run(), name=f"quad{self.robot_id}")

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        """Fly `function`; params are its spec, optionally with `t0` (the run's start,
        Unix time; default `restart_of`, else this link's start)."""
        try:
            spec = parse_function(function, params)
            # The patrol clock is the run's (functions.py). The daemon's params carry no
            # t0: a first process starts at the run's t0, so its own wall0 is that to a
            # few ms; a restarted one started later and must use the run's t0.
            origin = self.restart_of if self.restart_of is not None else self.wall0
            t0_wall = float(params.get("t0", origin))
        except (FunctionSpecError, TypeError, ValueError) as exc:
            self.errors += 1
            log.error("robot %d: cannot fly %s (epoch %d): %s", self.robot_id, function,
                      epoch, exc)
            return
        self.catch_up()
        if not self.robot.assign(function, spec, t0=t0_wall - self.wall0):
            log.warning("robot %d: assigned %s but cannot fly (%s)", self.robot_id, function,
                        self.robot.mode.value)
        self._report()

    def release(self, function: str) -> None:
        """Stop `function` and land at home."""
        self.catch_up()
        self.robot.release(function)

    async def close(self) -> None:
        """Stop stepping; land the craft (fast-forward, see `_land_before_exit`); flush
        the trajectory."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        self.catch_up()
        self._land_before_exit()
        self.robot.sample_now()
        self._flush()
        if self._file is not None:
            self._file.close()
            self._file = None
        self._on_health = None

    def _land_before_exit(self) -> None:
        # The daemon is stopping (a `leave` fault, a clean stop) and the craft's physics
        # dies with this process: without this the trajectory ends in mid-air and the
        # replay shows the craft hanging there. Landing is simulated ahead of the wall
        # clock (samples keep their future Unix times `w`), ~0.1 s of CPU, well inside
        # the daemon's 10 s allowance for closing the link.
        r = self.robot
        if r.mode in (Mode.TAKEOFF, Mode.FLYING):
            r.release()
        end = r.t + LAND_HORIZON
        errors = self.errors
        while r.mode is Mode.LANDING and r.t < end and self.errors == errors:
            self._step(min(end, r.t + 1.0))

    # -- simulator faults ----------------------------------------------------------------
    def fail_motor(self, index: int = 0) -> None:
        """`motor:R@T`: a rotor stops; the craft falls while the daemon runs on."""
        self.catch_up()
        self.robot.fail_motor(index)
        log.warning("robot %d: motor %d failed", self.robot_id, index)
        self._report()

    def set_health(self, health: Health) -> None:
        """`unhealthy:R@T`: the robot reports at least `health` from now on."""
        self._forced = max(self._forced, health)
        self._report()

    def health(self) -> Health:
        """What the robot reports: its own state, or worse if forced."""
        return max(self.robot.health(), self._forced)

    # -- the real-time loop --------------------------------------------------------------
    def _now(self) -> float:
        """Robot time: seconds since `start` on the loop's (monotonic) clock."""
        return asyncio.get_running_loop().time() - self._mono0

    def catch_up(self) -> None:
        """Step the physics up to now (robot time): commands and reads act at the
        present instant (an autopilot sharing this craft calls it before each)."""
        with contextlib.suppress(RuntimeError):  # no running loop: nothing to catch up
            self._step(self._now())

    def _step(self, t: float) -> None:
        try:
            self.robot.step_until(t)
        except Exception as exc:  # a physics blow-up must not take the daemon down
            self.errors += 1
            self._forced = Health.FAULTY
            log.exception("robot %d: physics failed: %s", self.robot_id, exc)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        due = loop.time()
        while True:
            due += self.wake
            await asyncio.sleep(max(0.0, due - loop.time()))
            now = loop.time()
            self.lateness.append(now - due)
            self._window.append(now - due)
            if now - due > 1.0:  # stalled (SIGSTOP, overload): resynchronise, don't burst
                due = now
            self._step(now - self._mono0)
            self._report()
            self._flush()
            if now - self._last_stats >= STATS_PERIOD:
                self._write_stats(now)

    def _write_stats(self, now: float) -> None:
        # How late the physics wake-ups were since the last line: the benchmark reads
        # these from the trajectory file of every robot of a `swarmd sim` run.
        late, self._window = sorted(self._window), []
        self._last_stats = now
        if self._file is None or not late:
            return
        row = {
            "stats": {
                "wakes": len(late),
                "late_p50_ms": round(1000 * late[len(late) // 2], 3),
                "late_p99_ms": round(1000 * late[min(len(late) - 1, int(0.99 * len(late)))], 3),
                "late_max_ms": round(1000 * late[-1], 3),
                "cpu_s": round(time.process_time(), 3),
            },
            "w": round(self._wall(), 4),
        }
        try:
            self._file.write(json.dumps(row, separators=(",", ":")) + "\n")
            self._file.flush()
        except OSError as exc:
            self.errors += 1
            log.error("robot %d: trajectory write failed: %s", self.robot_id, exc)

    def _report(self, *, force: bool = False) -> None:
        if self._on_health is None:
            return
        h = self.health()
        try:
            now = asyncio.get_running_loop().time()
        except RuntimeError:
            now = 0.0
        if force or h != self._reported or now - self._last_report >= self.health_period:
            self._reported = h
            self._last_report = now
            self._on_health(h)

    def _flush(self) -> None:
        samples = self.robot.samples
        if not samples:
            return
        self.robot.samples = []
        if self._file is None:
            return
        try:
            for s in samples:
                row = s.to_json()
                row["w"] = round(self.wall0 + s.t, 4)
                self._file.write(json.dumps(row, separators=(",", ":")) + "\n")
            self._file.flush()
        except OSError as exc:
            self.errors += 1
            log.error("robot %d: trajectory write failed: %s", self.robot_id, exc)


def read_stats(path: Path) -> list[dict[str, Any]]:
    """The lateness lines (`{"stats": {...}, "w": unix}`) of a trajectory file, in order;
    lines that do not parse (a SIGKILL can cut the last one) are skipped."""
    out: list[dict[str, Any]] = []
    with path.open() as f:
        for line in f:
            if '"stats"' not in line:
                continue
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if isinstance(row, dict) and isinstance(row.get("stats"), dict):
                out.append({**row["stats"], "w": row.get("w")})
    return out
