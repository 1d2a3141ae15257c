"""`swarmd sim` as options -> run -> result (DESIGN section 3).

`SimOptions` holds everything the command takes and refuses a bad value when it is built;
`run_sim` checks what needs the file system (the swarm file, the faults against it, what
a craft can fly, every output path, the installed extra) before anything runs, then runs
the virtual-time simulator (`sim.virtual`) or the real-time swarm (`sim.realtime`),
writes the event log and the report, and returns a `SimResult`. Whatever is refused
raises `SimError`, one line per problem, and nothing was started: the command prints the
lines and exits 2.

The lean install: `pip install swarmd` carries no MuJoCo, matplotlib or imageio (they are
the `sim` extra). A run that needs them, a physics flight or the pictures of `--report`,
is refused up front with the line to install them (`EXTRA_HINT`), never a traceback
after the robots started.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim.shared.channel import LOSS_MODELS
from sim.shared.eventlog import stops_at_end, write_events
from sim.shared.faults import Fault, FaultKind, FaultSpecError, check_faults, parse_fault
from sim.shared.summary import Summary, counted_drops, summarize
from swarmd.core.events import Leave, Started, event_of

TRANSPORTS = ("udp", "xbee", "serial")
"""Channels of the real-time mode (sim.realtime.orchestrator)."""
LINKS = ("direct", "mavlink", "ros2")
"""How a flying robot's daemon reaches its craft: `direct` (the daemon's link drives the
MuJoCo quadrotor) or `mavlink` (the daemon's MAVLink link talks over loopback UDP to a
simulated autopilot that flies the quadrotor; docs/mavlink.md) or `ros2` (the daemon's
ROS 2 link and a small rclpy robot stack flying the quadrotor, or bare with --no-physics;
docs/ros2.md)."""
AUTOPILOTS = ("px4", "ardupilot")
"""Flavours of the simulated autopilot of `--link mavlink` (swarmd.link.mavlink_modes)."""

EXTRA_HINT = "pip install 'swarmd[sim]'"
"""The one line that tells a lean install what to add."""
PHYSICS_MODULES = ("mujoco", "numpy")
"""What flying MuJoCo quadrotors imports (sim.physics.link, in every robot process)."""
PLOT_MODULES = ("matplotlib",)
"""What `--report`'s timeline.png (and trajectories.png) needs, in every mode."""
VIDEO_MODULES = ("mujoco", "imageio", "imageio_ffmpeg", "PIL")
"""What `--report`'s video and key frames need, with physics (sim.physics.render)."""

REPORT_FILES = ("events.jsonl", "summary.json", "timeline.png", "trajectories.png",
                "swarm.mp4", "swarm.gif", "key-*.png")
"""What `--report DIR` writes at its top level (plus `realtime/`, the robots' files)."""


class SimError(Exception):
    """A run refused before it started (or a swarm that could not start): one line per
    problem in `lines`, for the command to print before it exits 2."""

    def __init__(self, *lines: str) -> None:
        super().__init__("\n".join(lines))
        self.lines = lines


@dataclass(frozen=True, slots=True)
class SimOptions:
    """Everything `swarmd sim` takes. Building one checks the values that need nothing
    but themselves, and refuses an option the chosen mode would ignore: the user would
    believe the run used it."""

    swarm: Path
    virtual: bool = False
    duration: float = 15.0
    seed: int = 0
    loss: float = 0.0
    loss_model: str = "bernoulli"
    """`bernoulli` or `burst` (Gilbert-Elliott per directed link, sim/shared/channel.py)."""
    burst_len: float = 4.0
    """Mean frames of a loss burst (`burst`)."""
    faults: tuple[str, ...] = ()
    """Fault specs as typed (`crash:2@5`; sim.shared.faults)."""
    events: Path | None = None
    """Also write the merged event log here (JSON Lines)."""
    report: Path | None = None
    """Directory for the summary, the log and the pictures; cleared of an earlier run's."""
    physics: bool = True
    """Real time: fly MuJoCo quadrotors (False: bare daemons, link `none`)."""
    craft: str | None = None
    """Quadrotor preset (physics only); None: $SWARMD_QUAD_PRESET, else x2."""
    transport: str = "udp"
    live: bool = False
    """Real time: draw the live table on a terminal stdout."""
    link: str = "direct"
    """Physics only: `direct` or `mavlink` (LINKS)."""
    autopilot: str | None = None
    """`--link mavlink`: the simulated autopilot's flavour (AUTOPILOTS); None: px4."""
    refuse_arm: tuple[int, ...] = ()
    """`--link mavlink`: robots whose autopilot denies every arm command."""
    parsed_faults: tuple[Fault, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        problems = self._channel_problems() + self._link_problems()
        parsed = []
        for spec in self.faults:
            try:
                parsed.append(parse_fault(spec))
            except FaultSpecError as exc:
                problems.append(f"--fault: {exc}")
        if problems:
            raise SimError(*problems)
        object.__setattr__(self, "parsed_faults", tuple(parsed))

    def _channel_problems(self) -> list[str]:
        """What is wrong with the run's length, loss and transport options."""
        problems = []
        if not self.duration > 0:
            problems.append(f"--duration: {self.duration:g} is not above 0")
        if not 0.0 <= self.loss <= 1.0:
            problems.append(f"--loss: {self.loss:g} is not between 0 and 1")
        if self.loss_model not in LOSS_MODELS:
            problems.append(f"--loss-model: {self.loss_model!r} is not one of "
                            f"{', '.join(LOSS_MODELS)}")
        if not self.burst_len >= 1.0:
            problems.append(f"--burst-len: {self.burst_len:g} is below 1 frame")
        if self.transport not in TRANSPORTS:
            problems.append(f"--transport: {self.transport!r} is not one of "
                            f"{', '.join(TRANSPORTS)}")
        elif self.virtual and self.transport != "udp":
            problems.append("--transport: --virtual has no channel (it runs every core in "
                            "this process); drop --virtual to use emulated radios")
        return problems

    def _link_problems(self) -> list[str]:
        """What is wrong with the physics, craft, link and autopilot options."""
        problems = []
        if self.craft is not None and not self.flies:
            problems.append("--craft: only with physics (not with --virtual or --no-physics)")
        if self.virtual and not self.physics:
            problems.append("--no-physics: --virtual never flies; give one of the two")
        if self.link not in LINKS:
            problems.append(f"--link: {self.link!r} is not one of {', '.join(LINKS)}")
        elif self.link == "mavlink" and not self.flies:
            problems.append("--link: mavlink needs physics (the simulated autopilot flies a "
                            "MuJoCo quadrotor): not with --virtual or --no-physics")
        if self.link == "ros2" and self.virtual:
            problems.append("--link: ros2 runs real processes: not with --virtual")
        domain = os.environ.get("ROS_DOMAIN_ID", "").strip()
        if self.link == "ros2" and domain and not (domain.isdigit() and int(domain) <= 232):
            problems.append(f"ROS_DOMAIN_ID={domain!r}: a ROS 2 domain id is 0..232 "
                            "(unset it and the run leases a free one)")
        if self.autopilot is not None and self.autopilot not in AUTOPILOTS:
            problems.append(f"--autopilot: {self.autopilot!r} is not one of "
                            f"{', '.join(AUTOPILOTS)}")
        elif self.autopilot is not None and self.link != "mavlink":
            problems.append("--autopilot: only with --link mavlink")
        if self.refuse_arm and self.link != "mavlink":
            problems.append("--refuse-arm: only with --link mavlink")
        return problems

    @property
    def flies(self) -> bool:
        """Real time with MuJoCo quadrotors."""
        return self.physics and not self.virtual

    @property
    def mode(self) -> str:
        return "virtual" if self.virtual else "realtime"

    def chosen_craft(self) -> str:
        return self.craft or os.environ.get("SWARMD_QUAD_PRESET", "x2")

    @property
    def robot_link(self) -> str:
        """The robot processes' link (sim.realtime.robot_proc.LINK_FACTORIES)."""
        if self.link == "ros2":
            return "ros2-quad" if self.flies else "ros2-bare"
        if not self.flies:
            return "none"
        if self.link == "mavlink":
            return f"mavlink-{self.autopilot or 'px4'}"
        return "quad"


@dataclass(frozen=True, slots=True)
class SimResult:
    """What a run produced."""

    summary: Summary
    events: list[dict[str, Any]]
    """The merged event log, sorted by t."""
    t0: float | None
    """Real time: the run's wall-clock origin (event t is seconds since it); None virtual."""
    pictures: dict[str, Any] = field(default_factory=dict)
    """What the physics pictures of `--report` wrote or skipped (sim.physics.render)."""

    @property
    def interrupted(self) -> str | None:
        """The signal that ended a real-time run early (SIGINT, SIGTERM), else None."""
        info = self.summary.extra.get("interrupted")
        return str(info["signal"]) if info else None


# -- checks before anything runs ------------------------------------------------------------


def installed(module: str) -> bool:
    """Whether `module` can be imported, without importing it."""
    return importlib.util.find_spec(module) is not None


def missing_extra(options: SimOptions) -> str | None:
    """The line that says what to install, when the run needs the `sim` extra and it is
    not there; None when nothing is missing."""
    if options.flies:
        missing = [m for m in PHYSICS_MODULES if not installed(m)]
        if missing:
            return (f"swarmd sim: flying MuJoCo quadrotors needs the simulation extra "
                    f"({', '.join(missing)} not installed): {EXTRA_HINT} (or run with "
                    "--virtual / --no-physics)")
    if options.link == "ros2":
        from swarmd.link.ros2_node import ROS2_HINT, rclpy_missing

        if rclpy_missing():
            return ("swarmd sim: --link ros2 needs the ROS 2 wheels (rclpy not installed): "
                    f"{ROS2_HINT}")
    if options.report is not None:
        needed = PLOT_MODULES + (VIDEO_MODULES if options.flies else ())
        missing = [m for m in dict.fromkeys(needed) if not installed(m)]
        if missing:
            return (f"swarmd sim: the pictures of --report need the simulation extra "
                    f"({', '.join(missing)} not installed): {EXTRA_HINT} (or run without "
                    "--report)")
    return None


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe_dir(directory: Path) -> str | None:
    """Why nothing can be created in `directory`, or None: a real file is created and
    removed (permissions, a read-only file system, root on /proc: only trying tells)."""
    if not directory.is_dir():
        return f"{directory} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=directory, prefix=".swarmd-write-test"):
            pass
    except OSError as exc:
        return f"{directory} cannot be written: {exc.strerror or exc}"
    return None


def output_file_problem(path: Path, option: str) -> str | None:
    """Why the file `path` cannot be written (its parents created as needed), or None."""
    if path.is_dir():
        return f"{option}: {path} is a directory; give a file name in it"
    if path.exists():
        try:
            with path.open("a"):  # opened, not truncated: the run has not happened yet
                pass
        except OSError as exc:
            return f"{option}: {path} cannot be written: {exc.strerror or exc}"
        return None
    problem = _probe_dir(_nearest_existing(path.parent))
    return f"{option}: {path} cannot be written: {problem}" if problem else None


def output_dir_problem(path: Path, option: str) -> str | None:
    """Why the directory `path` cannot be created or written, or None."""
    if path.exists() and not path.is_dir():
        return f"{option}: {path} exists and is not a directory"
    problem = _probe_dir(_nearest_existing(path))
    return f"{option}: {path} cannot be written: {problem}" if problem else None


@dataclass(frozen=True, slots=True)
class _Checked:
    cfg: Any
    plan: Any
    params: Any


def check(options: SimOptions) -> _Checked:
    """Everything that can refuse the run, in the order a user fixes it; raises SimError.
    Creates, writes and starts nothing."""
    from swarmd.config import ConfigError, load_swarm

    paths = [output_file_problem(options.events, "--events") if options.events else None,
             output_dir_problem(options.report, "--report") if options.report else None]
    if any(paths):
        raise SimError(*[p for p in paths if p])
    extra = missing_extra(options)
    if extra:
        raise SimError(extra)
    try:
        cfg = load_swarm(options.swarm)
    except ConfigError as exc:
        raise SimError(*[str(p) for p in exc.problems]) from None
    plan = cfg.to_plan()
    params = cfg.params()
    problems = check_faults(list(options.parsed_faults), set(plan.robots),
                            physics=options.flies, duration=options.duration)
    if problems:
        raise SimError(*[f"--fault: {p}" for p in problems])
    unknown = sorted(set(options.refuse_arm) - set(plan.robots))
    if unknown:
        raise SimError(f"--refuse-arm: robot {', '.join(map(str, unknown))} is not in "
                       f"{options.swarm} (robots: {', '.join(map(str, sorted(plan.robots)))})")
    if options.flies:
        from sim.physics.model import PRESETS
        from swarmd.base.functions import flight_problems

        chosen = options.chosen_craft()
        if chosen not in PRESETS:
            raise SimError(f"--craft: unknown quadrotor preset {chosen!r} "
                           f"(known: {', '.join(PRESETS)})")
        # What a craft cannot fly (a waypoint under the ground...) is refused before any
        # robot starts, not logged by a robot that then stays parked.
        flight = flight_problems({n: cfg.function_spec(n) for n in plan.functions})
        if flight:
            raise SimError(*[f"{options.swarm}: {p} (or run with --no-physics)"
                             for p in flight])
    return _Checked(cfg, plan, params)


def clear_report(report: Path) -> None:
    """Remove what an earlier run wrote into `report`, and nothing else. A reused report
    directory must not mix runs: the robots' persisted state under `realtime/state`
    would make them restore the old run's roles (DESIGN rule 2), and old trajectory
    files and key frames would be drawn with the new ones."""
    report.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(report / "realtime", ignore_errors=True)
    for pattern in REPORT_FILES:
        for path in report.glob(pattern):
            path.unlink(missing_ok=True)


# -- the run ---------------------------------------------------------------------------------


def run_sim(options: SimOptions) -> SimResult:
    """Check, run, write the event log and the report; SimError if refused."""
    checked = check(options)
    if options.report is not None:
        try:
            clear_report(options.report)
        except OSError as exc:
            raise SimError(f"--report: {options.report} cannot be written: "
                           f"{exc.strerror or exc} ({type(exc).__name__})") from None
    faults = list(options.parsed_faults)
    if options.virtual:
        summary, events, t0 = _run_virtual(checked, faults, options)
    else:
        summary, events, t0 = _run_realtime(checked, faults, options)
    if options.events is not None:
        write_events(options.events, events)
    pictures: dict[str, Any] = {}
    if options.report is not None:
        pictures = _write_report(options, checked, summary, events, t0)
    return SimResult(summary=summary, events=events, t0=t0, pictures=pictures)


def _auth(checked: _Checked) -> str:
    """The swarm's authentication mode for the virtual simulator: the file's (`none`,
    `shared`, `per-robot`: the simulator makes throwaway identities for the last)."""
    cfg = checked.cfg
    # Signed by default: a swarm file that says nothing is simulated per robot, as the
    # real-time swarm signs every run with throwaway keys.
    return str(cfg.auth_mode) if cfg.auth_explicit else "per-robot"


def _run_virtual(checked: _Checked, faults: list[Fault], options: SimOptions,
                 ) -> tuple[Summary, list[dict[str, Any]], None]:
    from sim.virtual.simulator import run_virtual

    key = checked.cfg.key()
    start = time.perf_counter()
    result = run_virtual(checked.plan, checked.params, duration=options.duration,
                         faults=faults, loss=options.loss, seed=options.seed,
                         keys=(key,) if key else (), auth=_auth(checked),
                         loss_model=options.loss_model, burst_len=options.burst_len)
    wall = time.perf_counter() - start
    summary = summarize(result.events, faults, checked.plan, checked.params,
                        loss=options.loss, duration=options.duration, mode="virtual",
                        extra_violations=result.violations)
    summary.drops = {r: d for r, d in ((r, counted_drops(d)) for r, d in result.drops.items())
                     if d}
    summary.extra["frames_sent"] = result.frames_sent
    summary.extra["robot_seconds_per_wall_second"] = round(
        result.robot_seconds / max(wall, 1e-9))
    return summary, [*result.events, *stops_at_end(result.events, options.duration)], None


def _run_realtime(checked: _Checked, faults: Sequence[Fault], options: SimOptions,
                  ) -> tuple[Summary, list[dict[str, Any]], float]:
    from sim.realtime.orchestrator import run_realtime
    from sim.realtime.summary import summarize_realtime

    try:
        result = run_realtime(options.swarm, duration=options.duration, faults=faults,
                              loss=options.loss, seed=options.seed,
                              report_dir=options.report, physics=options.physics,
                              craft=options.chosen_craft() if options.flies else None,
                              transport=options.transport, live=options.live,
                              link=options.robot_link, refuse_arm=options.refuse_arm,
                              loss_model=options.loss_model, burst_len=options.burst_len)
    except (ValueError, RuntimeError) as exc:  # a swarm that could not start
        raise SimError(f"swarmd sim: {exc}") from None
    # A robot whose autopilot refuses to arm is faulty: its daemon hands its function
    # over (DESIGN rule 7), so its replacement is no false takeover. The fault counts
    # from the moment the health problem reached the daemon (its `leave`), as an
    # injected `unhealthy` does: how long the link retried the arm first (COMMAND_ACK
    # retries, slower on a loaded machine) is the link's time, not the protocol's.
    # Without a leave, from its daemon's start, when it held its function.
    started = {e["robot"]: float(e["t"]) for e in reversed(result.events)
               if isinstance(event_of(e), Started)}
    left = {e["robot"]: float(e["t"]) for e in reversed(result.events)
            if isinstance(ev := event_of(e), Leave) and ev.reason == "fault"}
    refused = [RefusedArm(FaultKind.UNHEALTHY,
                          round(left.get(r, started.get(r, 0.0)), 6) - 1e-6
                          if r in left else round(started.get(r, 0.0), 6) + 1e-6, (r,))
               for r in options.refuse_arm]
    summary = summarize_realtime(result, [*refused, *faults], checked.plan, checked.params,
                                 loss=options.loss)
    end = result.ended_at if result.ended_at is not None else result.duration
    stops = stops_at_end(result.events, end, dead=result.deaths)
    return summary, [*result.events, *stops], result.t0


@dataclass(frozen=True, slots=True)
class RefusedArm(Fault):
    """`--refuse-arm R` for the run's checker and summary: what the daemon sees of it is
    a robot unhealthy from t=0 (kind `unhealthy`), labelled as the option."""

    def spec(self) -> str:
        return f"refuse-arm:{self.robot}"


def _write_report(options: SimOptions, checked: _Checked, summary: Summary,
                  events: list[dict[str, Any]], t0: float | None) -> dict[str, Any]:
    from sim.physics.plots import timeline_png

    report = options.report
    assert report is not None
    write_events(report / "events.jsonl", events)
    (report / "summary.json").write_text(summary.to_json() + "\n", encoding="utf-8")
    # summary.duration: where the run really ended (earlier when interrupted).
    timeline_png(events, report / "timeline.png", end=summary.duration,
                 title=f"swarmd sim ({summary.mode})")
    if not options.flies:
        return {}
    # Trajectory plot, video and key frames from the robots' trajectory files.
    from sim.physics.render import report_pictures

    return report_pictures(report, events,
                           {n: checked.cfg.function_spec(n) for n in checked.plan.functions},
                           t0=t0, end=summary.duration)
