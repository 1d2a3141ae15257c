"""One robot of the real-time `swarmd sim`: a real `swarmd start` daemon in its own process.

The orchestrator (`orchestrator.py`) writes a robot file per robot (so each process runs
exactly what `swarmd start --config` runs: `swarmd.daemon.daemon.run_daemon`) and starts this
module's `child_main` in a forkserver child. What the simulator adds around the daemon:

- a receive filter (`sim/realtime/netfilter.py`): seeded loss and partitions, per receiver;
- a robot link chosen by name (`LINK_FACTORIES`): the bare `none` link, the MuJoCo
  quadrotor (`sim.physics.link.QuadLink`) when physics is on, or the daemon's MAVLink
  link talking to a simulated autopilot over that quadrotor (`mavlink-px4`,
  `mavlink-ardupilot`: sim.physics.autopilot.SimMavlinkLink); a new robot plugs in here;
- the `liar` fault: forged WARN frames about its neighbours, sent through the daemon's
  own runtime so they are signed and sequenced like its real frames (`Liar`);
- the `forge` fault: raw frames an insider holding this robot's key forges
  (`sim.shared.forge.forged_frames`), signed with the daemon's own key material and
  sent straight on its transport, past its node (`Forger`);
- two pipes to the orchestrator: events out (one JSON object a message, t relative to
  the run's t0), control in (`go`, `leave`, `unhealthy`, `liar`, `motor`, `forge`). EOF on the
  control pipe means the orchestrator is gone: the daemon stops.
- a lateness probe (`LatenessProbe`): how late this process's event loop wakes up, sent
  to the orchestrator every second, so that a summary can say "the robots were late"
  when the machine could not keep up, instead of passing the false suspicions that
  follow off as protocol failures.

Process hygiene (Ctrl-C leaves no process behind): the child puts itself
in its own process group (so the terminal's SIGINT reaches only the orchestrator, which
decides) and asks the kernel to SIGKILL it if its parent (the forkserver, which exits
with the orchestrator) dies.

`python -m sim.realtime.robot_proc --config robot.yaml [--events FILE] [--t0 UNIX]` runs the same
thing without an orchestrator (used by the network-namespace test).
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import ctypes
import os
import signal
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from sim.realtime.control import (
    Act,
    Command,
    ControlError,
    Drops,
    Failed,
    Forge,
    Go,
    Late,
    Logged,
    Ready,
    Report,
    Stats,
    decode_command,
    encode,
)
from sim.realtime.netfilter import FilterStats, PartitionWindow, ReceiveFilter
from sim.shared.faults import FaultKind
from sim.shared.forge import CAPTURE, REPEATING, forged_frames
from sim.shared.liar import liar_warnings
from sim.shared.summary import counted_drops
from swarmd.base import eventloop
from swarmd.base.logs import setup_logging
from swarmd.config import load_robot
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Health
from swarmd.daemon.daemon import Daemon, run_daemon
from swarmd.link.base import RobotLink
from swarmd.link.none import NoneLink
from swarmd.services.runtime import Runtime
from swarmd.transport.udp import UdpTransport

_PR_SET_PDEATHSIG = 1
PROBE_PERIOD = 0.1
"""s between two wake-ups of the lateness probe (a heartbeat period of the udp preset)."""
PROBE_REPORT = 1.0
"""s between two lateness messages to the orchestrator (SIGKILL ends a run: report often)."""
LATE_MS = 1.0
"""ms: wake-ups later than this are listed one by one; the others only counted."""


@dataclass(frozen=True, slots=True)
class RobotSpec:
    """Everything a robot process needs; pickled to the forkserver child."""

    robot_id: int
    config_path: str
    """The robot file written by the orchestrator (`swarmd start --config` equivalent)."""
    log_path: str
    """The daemon's stdout/stderr (JSON log lines) go here, not to the orchestrator's tty."""
    loss: float = 0.0
    seed: int = 0
    partitions: tuple[PartitionWindow, ...] = ()
    """Partitions and one-way link faults (`netfilter.link_windows`)."""
    loss_model: str = "bernoulli"
    burst_len: float = 4.0
    link: str = "none"
    t0: float | None = None
    """Start at once with this run origin (a restart); None: wait for the `go` message."""
    craft: str | None = None
    """Quadrotor preset of the `quad` link (sim.physics.model.PRESETS); None: its default."""
    refuse_arm: bool = False
    """`mavlink-*` links: the simulated autopilot denies every arm command."""


# -- robot links ----------------------------------------------------------------------------


def _none_link(spec: RobotSpec, cfg: Any) -> RobotLink:
    return NoneLink()


def _quad_link(spec: RobotSpec, cfg: Any) -> RobotLink:
    from sim.physics.link import QuadLink

    # spec.t0 set: this process restarts a robot of a running swarm; its craft resumes
    # where the killed process left it instead of reappearing parked at home.
    link: RobotLink = QuadLink.for_robot(cfg, restart_of=spec.t0, craft=spec.craft)
    return link


def _mavlink_link(flavour: str) -> Callable[[RobotSpec, Any], RobotLink]:
    def build(spec: RobotSpec, cfg: Any) -> RobotLink:
        from sim.physics.autopilot import SimMavlinkLink

        # The daemon's MAVLink link and a simulated autopilot (its own UDP port, as PX4
        # SITL gives each vehicle, the kernel's pick when it binds) flying the craft: the
        # daemon learns of a `motor` or `unhealthy` fault only through MAVLink health
        # (docs/mavlink.md).
        link: RobotLink = SimMavlinkLink.for_robot(
            cfg, flavour, 0, restart_of=spec.t0,  # type: ignore[arg-type]
            craft=spec.craft, refuse_arm=spec.refuse_arm)
        return link

    return build


def _ros2_link(physics: bool) -> Callable[[RobotSpec, Any], RobotLink]:
    def build(spec: RobotSpec, cfg: Any) -> RobotLink:
        from sim.realtime.ros2_robot import SimRos2Link

        # The daemon's ros2 link and a small rclpy robot stack beside it, flying the
        # MuJoCo craft (or nothing: --no-physics) from the link's topics only.
        return SimRos2Link(cfg, _quad_link(spec, cfg) if physics else None)

    return build


LINK_FACTORIES: dict[str, Callable[[RobotSpec, Any], RobotLink]] = {
    "none": _none_link,
    "quad": _quad_link,
    "mavlink-px4": _mavlink_link("px4"),
    "mavlink-ardupilot": _mavlink_link("ardupilot"),
    "ros2-quad": _ros2_link(True),
    "ros2-bare": _ros2_link(False),
}
"""Robot links by name: the orchestrator picks one; add a robot model here."""


class _Periodic:
    """A task on the robot's loop, started once and cancelled at the end (`_run`)."""

    _task: asyncio.Task[None] | None = None

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run())

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()

    async def _run(self) -> None:
        raise NotImplementedError


# -- the liar -------------------------------------------------------------------------------


class Liar(_Periodic):
    """Forges WARN frames about this robot's neighbours once `start()` is called
    (whom: `sim.shared.liar.liar_warnings`).

    They go out through the daemon's own runtime (`Runtime.inject`), so they carry the
    robot's sender id, its rising sequence numbers and its signature: receivers accept
    them as real. The point of the `liar` fault is that one witness, however loud, never
    makes a quorum of *distinct* witnesses (paper section III-B, DESIGN rule 3).
    """

    def __init__(self, plan: SwarmPlan, interval: float) -> None:
        self.plan = plan
        self.interval = interval
        self.runtime: Runtime | None = None
        self.forged = 0

    async def _run(self) -> None:
        while True:
            rt = self.runtime
            if rt is not None:
                for warn in liar_warnings(self.plan, rt.snapshot()):
                    rt.inject(warn)
                    self.forged += 1
            await asyncio.sleep(self.interval)


# -- the forger -----------------------------------------------------------------------------


class Forger(_Periodic):
    """`forge:R@T:ATTACK`: once `launch(attack)` is called, the frames
    `sim.shared.forge.forged_frames` names, as the virtual simulator sends them: one
    burst, or (`REPEATING` attacks) a new round every warn interval.

    Unlike the liar's WARNs they do not go through the node (which would sign and
    sequence them honestly): they are encoded with what an insider holding robot R's
    key has (the daemon's Ed25519 signer in per-robot mode, the swarm key in shared
    mode, nothing when unsigned) and written raw on the daemon's transport, so every
    other robot's decoding and verifying is what is attacked (DESIGN "Who may say
    what"). The insider's radio is another radio: R's own daemon hears the frames as
    any robot does, and may report another sender with its id. For `replay` it plays
    back what that radio recorded before the attack: the frames R's daemon received
    (`hear`), the last `CAPTURE` of them."""

    def __init__(self, plan: SwarmPlan, interval: float) -> None:
        self.plan = plan
        self.interval = interval
        self.daemon: Daemon | None = None
        self.sent = 0
        self.attack = ""
        self._tape: collections.deque[bytes] = collections.deque(maxlen=CAPTURE)

    def hear(self, data: bytes) -> None:
        """A frame on the channel, recorded until an attack starts."""
        if self._task is None:
            self._tape.append(bytes(data))

    def launch(self, attack: str) -> None:
        """Start `attack` (one of `sim.shared.faults.ATTACKS`); a second one is ignored."""
        if self._task is None:
            self.attack = attack
            self.start()

    async def _run(self) -> None:
        attack = self.attack
        round_ = 0
        while True:
            daemon = self.daemon
            rt = daemon.runtime if daemon is not None else None
            if daemon is not None and rt is not None:
                frames = forged_frames(attack, self.plan, rt.snapshot(),
                                       keys=daemon.cfg.keys(), signer=daemon.signer,
                                       round_=round_, recorded=tuple(self._tape))
                for data in frames:
                    if rt.send_raw(data):  # False: a full socket, the frame is lost
                        self.sent += 1
                round_ += 1
                if attack not in REPEATING:
                    return
            await asyncio.sleep(self.interval)


# -- drops ----------------------------------------------------------------------------------

DROPS_PERIOD = 1.0
"""s between two drop reports of a robot process (only when the counts changed)."""


class DropReporter(_Periodic):
    """Every `DROPS_PERIOD`, the daemon's counted drops (`sim.shared.summary.counted_drops`
    of the core's, plus the runtime's queue overflow) as a `Drops` report when they
    changed, and once more when the daemon stops: the run's summary shows
    what every robot refused, by reason, as of its last report (a SIGKILLed robot's
    last second is lost)."""

    def __init__(self, emit: Callable[[Report], None]) -> None:
        self.emit = emit
        self.daemon: Daemon | None = None
        self._last: dict[str, int] = {}

    def stop(self) -> None:
        super().stop()
        self.report()

    def report(self) -> None:
        rt = self.daemon.runtime if self.daemon is not None else None
        if rt is None:
            return
        drops = counted_drops(rt.drop_counts())
        if drops != self._last:
            self._last = drops
            self.emit(Drops(drops))

    async def _run(self) -> None:
        while True:
            await asyncio.sleep(DROPS_PERIOD)
            self.report()


# -- lateness -------------------------------------------------------------------------------


class LatenessProbe(_Periodic):
    """How late this process's event loop runs: every `PROBE_PERIOD` it asks to wake up
    and measures by how much it overslept; every `PROBE_REPORT` it emits a `Late` report
    counting the wake-ups and listing only those `LATE_MS` or more late (t = their run
    time), so an idle swarm sends a few bytes a second.

    The daemon's heartbeats ride on the same loop, so this is how late they go out: a
    lateness near `t_max` makes the neighbours suspect a healthy robot (paper Fig. 7)."""

    def __init__(self, emit: Callable[[Report], None],
                 clock: Callable[[], float]) -> None:
        self.emit = emit
        self.clock = clock

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        samples: list[tuple[float, float]] = []
        wakes = 0
        reported = loop.time()
        while True:
            due = loop.time() + PROBE_PERIOD
            await asyncio.sleep(PROBE_PERIOD)
            now = loop.time()
            wakes += 1
            late_ms = round(1000 * max(0.0, now - due), 1)
            if late_ms >= LATE_MS:
                samples.append((round(self.clock(), 3), late_ms))
            if now - reported >= PROBE_REPORT:
                self.emit(Late(wakes, samples))
                samples = []
                wakes = 0
                reported = now


# -- process set-up -------------------------------------------------------------------------


def _die_with_parent() -> None:
    """Own process group; SIGKILL from the kernel when the parent goes (Linux). Either
    refused, the robot still runs (the orchestrator kills it by pid, and the control
    pipe's end stops it): said once on stderr, so a leftover process is explained."""
    try:
        os.setpgid(0, 0)
    except OSError as exc:
        print(f"robot process: no process group of its own ({exc})", file=sys.stderr)
    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError) as exc:
        print(f"robot process: no death signal from its parent ({exc})", file=sys.stderr)
    if os.getppid() != parent:  # the parent died before prctl took effect
        os._exit(1)


def _redirect_output(path: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)


class _Robot:
    """The asyncio side of one robot process."""

    def __init__(
        self,
        spec: RobotSpec,
        emit: Callable[[Report], None],
        control: Connection | None,
    ) -> None:
        self.spec = spec
        self.emit = emit
        self.control = control
        self.cfg = load_robot(Path(spec.config_path))
        plan = self.cfg.swarm.to_plan()
        params = self.cfg.swarm.params()
        self.link = LINK_FACTORIES[spec.link](spec, self.cfg)
        self.liar = Liar(plan, params.warn_interval)
        self.forger = Forger(plan, params.warn_interval)
        self.t0 = spec.t0
        self.filter = ReceiveFilter(
            spec.robot_id,
            loss=spec.loss,
            seed=spec.seed,
            partitions=spec.partitions,
            clock=self._run_time,
            loss_model=spec.loss_model,
            burst_len=spec.burst_len,
        )
        self.stop_event: asyncio.Event | None = None
        self.go: asyncio.Event | None = None
        self.probe = LatenessProbe(emit, self._run_time)
        self.drops = DropReporter(emit)

    def _run_time(self) -> float:
        return time.time() - (self.t0 or 0.0)

    def _on_control(self) -> None:
        assert self.control is not None
        try:
            while self.control.poll():
                self._command(decode_command(self.control.recv_bytes()))
        except (EOFError, OSError):
            # The orchestrator is gone: stop (no orphan daemons).
            asyncio.get_running_loop().remove_reader(self.control.fileno())
            if self.go is not None:
                self.go.set()
            if self.stop_event is not None:
                self.stop_event.set()
        except ControlError as exc:
            print(f"robot {self.spec.robot_id}: bad control message: {exc}", file=sys.stderr)

    def _command(self, cmd: Command) -> None:
        match cmd:
            case Go(t0):
                self.t0 = t0
                if self.go is not None:
                    self.go.set()
            case Act(FaultKind.LEAVE):
                # DESIGN section 3 `leave`: the node's stop(handover=True) path, then exit.
                if self.stop_event is not None:
                    self.stop_event.set()
            case Act(FaultKind.UNHEALTHY):
                # DESIGN rule 7: the robot reports a fault; the daemon sends LEAVE.
                set_health = getattr(self.link, "set_health", None)
                if set_health is not None:
                    set_health(Health.FAULTY)
            case Act(FaultKind.LIAR):
                self.liar.start()
            case Forge(attack):
                self.forger.launch(attack)
            case Act(FaultKind.MOTOR):
                fail = getattr(self.link, "fail_motor", None)
                if fail is not None:
                    fail()
            case _:
                print(f"robot {self.spec.robot_id}: unknown control {cmd!r}", file=sys.stderr)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        self.stop_event = asyncio.Event()
        self.go = asyncio.Event()
        if self.control is not None:
            loop.add_reader(self.control.fileno(), self._on_control)
        if self.t0 is None:
            self.emit(Ready(os.getpid()))
            await self.go.wait()
            if self.stop_event.is_set():
                return 0
        assert self.t0 is not None
        # All robots start together at t0 (a wall-clock time the orchestrator picked).
        await asyncio.sleep(max(0.0, self.t0 - time.time()))
        self.probe.start()
        self.drops.start()
        try:
            return await run_daemon(
                self.cfg,
                # The insider's radio hears every frame on the channel, its own and those
                # of slots it does not hear (`Forger.hear`): no socket filter.
                transport=UdpTransport.from_config(self.cfg.transport, kernel_filter=False)
                if self.cfg.transport.kind == "udp" else None,
                link=self.link,
                receive_filter=self._hear,
                event_sink=self._sink,
                stop_event=self.stop_event,
                on_ready=self._ready,
                time_origin=self.t0,
                handle_signals=self.control is None,
                config_path=Path(self.spec.config_path),
            )
        finally:
            self.liar.stop()
            self.forger.stop()
            self.probe.stop()
            self.drops.stop()

    def _sink(self, record: Mapping[str, Any]) -> None:
        self.emit(Logged(dict(record)))

    def _ready(self, daemon: Daemon) -> None:
        self.liar.runtime = daemon.runtime
        self.forger.daemon = daemon
        self.drops.daemon = daemon

    def _hear(self, data: bytes, now: float) -> bool:
        if not self.filter(data, now):
            return False
        self.forger.hear(data)  # the insider's radio records what this robot hears
        return True


def child_main(spec: RobotSpec, events: Connection, control: Connection) -> None:
    """Forkserver entry: run one robot until killed, told to leave, or orphaned."""
    _die_with_parent()
    _redirect_output(spec.log_path)
    # The daemon's warnings and errors as JSON lines (swarmd.base.logs), with their fields
    # (`error`, `error_type`): the orchestrator quotes them when a robot fails.
    setup_logging("WARNING")
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    lost = collections.Counter[str]()

    def emit(report: Report) -> None:
        # One message per report: a pipe write below PIPE_BUF is atomic, so a SIGKILL
        # never leaves half a record for the orchestrator. The orchestrator gone: nobody
        # is left to tell, and the control pipe's end stops this robot; the loss is
        # counted and said once in the robot's log.
        try:
            events.send_bytes(encode(report))
        except OSError as exc:
            lost["reports"] += 1
            if lost["reports"] == 1:
                print(f"robot {spec.robot_id}: report pipe closed ({exc}); reports are "
                      "lost from now on", file=sys.stderr)

    code = 1
    try:
        robot = _Robot(spec, emit, control)
        code = eventloop.run(robot.run())
        _report_stats(robot.filter.stats, robot.liar.forged + robot.forger.sent, emit)
    except Exception as exc:  # a robot that cannot start says why, in its log and pipe
        emit(Failed(f"{type(exc).__name__}: {exc}"))
        raise
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(code)


def _report_stats(
    stats: FilterStats, forged: int, emit: Callable[[Report], None]
) -> None:
    emit(Stats(stats.passed, stats.lost, stats.partitioned, forged))


def main(argv: list[str] | None = None) -> int:
    """Stand-alone robot process (no orchestrator): `python -m sim.realtime.robot_proc`."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", required=True, help="robot file")
    ap.add_argument("--events", help="append the event log (JSON lines) here")
    ap.add_argument("--t0", type=float, default=None, help="run origin (Unix time)")
    ap.add_argument("--loss", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg_path = Path(args.config)
    out = open(args.events, "a", buffering=1) if args.events else None  # noqa: SIM115

    def emit(report: Report) -> None:
        if out is not None and isinstance(report, Logged):
            out.write(encode(report).decode() + "\n")

    robot_id = int(load_robot(cfg_path).robot)
    t0 = args.t0 if args.t0 is not None else time.time()
    spec = RobotSpec(robot_id, str(cfg_path), "", loss=args.loss, seed=args.seed, t0=t0)
    robot = _Robot(spec, emit, None)
    try:
        return eventloop.run(robot.run())
    finally:
        if out is not None:
            out.close()


if __name__ == "__main__":
    sys.exit(main())
