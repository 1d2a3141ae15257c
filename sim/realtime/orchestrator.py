"""The real-time `swarmd sim`: one OS process per robot, real daemons on loopback multicast.

Theory of operation
-------------------
`run_realtime` writes one robot file per robot of the swarm (the same file `swarmd start
--config` takes: UDP multicast on 127.0.0.1, TTL 1, a port picked for this run so runs
never hear each other) and starts one process per robot from a forkserver that preloads
swarmd (50 robots are up in about a second, where a fresh interpreter each would take
several). Each process (`sim/realtime/robot_proc.py`) loads its file, says `ready`, and waits for
`go` with a run origin t0 a little in the future, so that every daemon starts at the same
wall-clock instant and event times (seconds since t0) are comparable across processes.

Faults happen to real processes at their times (DESIGN section 3):
crash = SIGKILL of the robot's process group; pause = SIGSTOP, then SIGCONT after D;
restart = a new process on the same state dir (so persisted epochs fence it, rule 2);
leave / unhealthy / liar / motor / forge = a control message to the robot process; loss and
partition = the per-process receive filter (`sim/realtime/netfilter.py`), set at spawn. Every
injected fault is logged as `fault{kind}` with robot = its target (0 for a partition).

The run ends at t0 + duration with a SIGKILL of every robot at once: a graceful stop
would hand functions over (LEAVE) in the last instant and write takeovers that are
artefacts of the ending. Ctrl-C or SIGTERM (`handle_signals`, the CLI) end the run the
same way, early: the result says `interrupted` and `ended_at`, so the caller can still
write the partial report. A cancellation or any exception also kills and reaps every
robot before it goes up; robots die by themselves if the orchestrator does (robot_proc:
PDEATHSIG and control-pipe EOF).

What can go wrong with the processes themselves is reported, never silently passed over
(`RealtimeResult.problems`, found by `sim/realtime/problems.py`); a robot that fails to
start, or is not ready within `READY_TIMEOUT`, refuses the run with the reason and the
robot's log. Each robot also reports how late its event loop runs
(`sim.realtime.robot_proc.LatenessProbe`), so a summary can say when the machine could
not keep up.

Events from every robot arrive over pipes and are merged by t into one log.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sim.xbee_emu.medium import Medium

import asyncio
import contextlib
import functools
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Callable, Coroutine, Sequence
from pathlib import Path
from typing import Any, ParamSpec

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
    decode_report,
    encode,
)
from sim.realtime.ports import PortLease
from sim.realtime.problems import (
    deaths,
    never_started,
    process_problems,
    robot_log,
    summed_drops,
    survived_errors,
    tail_of,
)
from sim.realtime.procs import (
    RobotProcess,
    forkserver_context,
    kill_group,
    main_not_reimported,
)
from sim.realtime.result import RealtimeResult
from sim.realtime.robotfiles import (
    emulated_radio,
    robot_ids,
    sign_for_run,
    start_medium,
    state_dir,
    write_robot_file,
)
from sim.realtime.schedule import FaultSchedule
from sim.realtime.view import SwarmView
from sim.shared.eventlog import write_events
from sim.shared.faults import LINK_KINDS, Fault, FaultKind, fault_record
from swarmd.transport.addresses import DEFAULT_GROUP

__all__ = ["Orchestrator", "RealtimeResult", "run_realtime", "run_realtime_async"]

START_MARGIN = 0.3
"""s between the last robot's `ready` and t0: enough to deliver `go` to 50 processes."""
READY_TIMEOUT = 20.0
"""s allowed for every robot process to load its config and open its transport, plus
`READY_PER_ROBOT` for each robot: an overloaded machine starts a big swarm slowly (80
robots on one busy core took 25 s) and must be waited for, not refused."""
READY_PER_ROBOT = 0.5

P = ParamSpec("P")


class Orchestrator:
    """One real-time run. Use `run_realtime` / `run_realtime_async`.

    Built in three steps: the constructor only checks and keeps its arguments (no file,
    process or socket), `prepare` does the run's I/O, `run` supervises the processes
    while its `FaultSchedule` says when each fault acts; `cleanup` undoes what `prepare`
    made."""

    def __init__(self, swarm_path: Path, *, duration: float, faults: Sequence[Fault],
                 loss: float, seed: int, physics: bool, live: bool, report_dir: Path | None,
                 group: str = DEFAULT_GROUP, port: int | None = None, transport: str = "udp",
                 craft: str | None = None, link: str | None = None,
                 refuse_arm: Sequence[int] = (), loss_model: str = "bernoulli",
                 burst_len: float = 4.0) -> None:
        self.swarm_path = swarm_path
        self.loss_model = loss_model
        self.burst_len = burst_len
        self.craft = craft
        self.transport = transport
        self.duration = duration
        self.schedule = FaultSchedule(faults, duration)
        self.faults = self.schedule.faults
        self.loss = loss
        self.seed = seed
        # The robots' link (robot_proc.LINK_FACTORIES): `quad` drives the MuJoCo craft
        # directly, `mavlink-px4` / `mavlink-ardupilot` through a simulated autopilot.
        self.link = link or ("quad" if physics else "none")
        if self.link not in ("none", "ros2-bare") and not physics:
            raise ValueError(f"robot link {self.link!r} flies a craft: it needs physics")
        self.refuse_arm = frozenset(refuse_arm)
        self.live = live
        self.report_dir = report_dir
        self.group = group
        self._port = port
        if transport not in ("udp", "xbee", "serial"):
            raise ValueError(f"unknown transport {transport!r}: udp, xbee or serial")
        self.physics = physics

        # What the run keeps of its processes and what they report (no process yet).
        self.procs: dict[int, RobotProcess] = {}
        self.retired: list[RobotProcess] = []
        self.events: list[dict[str, Any]] = []
        self.stats: dict[int, dict[str, int]] = {}
        self.problems: list[str] = []
        self.late: list[tuple[int, float, float]] = []
        self.wakes = 0
        self.t0 = 0.0
        self._ready = asyncio.Event()
        self._stop = asyncio.Event()
        self.interrupted: str | None = None

        # Set by `prepare` (the start step: files, keys, radios), never by the
        # constructor: until then, empty.
        self.port = 0
        self.port_lease: PortLease | None = None
        self.robots: tuple[int, ...] = ()
        self.ready_timeout = READY_TIMEOUT
        self.view = SwarmView(())
        self.radio_of: dict[int, int] = {}
        self.identity_files: Any = None
        self._run_dir: Path | None = None
        self._ctx: Any = None
        self.ros_domain: Any = None
        self.medium: Medium | None = None

    @property
    def run_dir(self) -> Path:
        """The run's directory (robot files, logs, keys, radios); made by `prepare`."""
        if self._run_dir is None:
            raise RuntimeError("Orchestrator.prepare() first: the run has no directory yet")
        return self._run_dir

    def prepare(self) -> None:
        """The start step, all the run's I/O before any robot: read the swarm, pick the
        port, make the run directory, sign this run's throwaway keys, lease a ROS 2
        domain and start the emulated radios. Idempotent (`run` calls it too); what it
        made is undone by `cleanup`, also after a failure half-way."""
        if self._run_dir is not None:
            return
        self._pick_port()
        self.robots = robot_ids(self.swarm_path)
        self.ready_timeout = READY_TIMEOUT + READY_PER_ROBOT * len(self.robots)
        self.view = SwarmView(self.robots)
        self.radio_of = {r: i + 1 for i, r in enumerate(self.robots)}
        # Absolute: the robot files written below name their state_dir, and a relative
        # path in a robot file is read relative to that file (docs/config.md), so
        # `--report out/demo` put the trajectories under out/demo/realtime/robots/out/...
        self._run_dir = (
            self.report_dir.resolve() / "realtime" if self.report_dir
            else Path(tempfile.mkdtemp(prefix="swarmd-"))
        )
        self._run_dir.mkdir(parents=True, exist_ok=True)
        (self._run_dir / "logs").mkdir(exist_ok=True)
        # Throwaway keys for this run; the robots run from a copy of the swarm file
        # that names them (robotfiles.sign_for_run).
        self.swarm_path, self.identity_files = sign_for_run(self._run_dir, self.swarm_path)
        self._ctx = forkserver_context(self.physics)
        # `--link ros2`: $ROS_DOMAIN_ID, else the run's own domain (ros2_robot).
        if self.link.startswith("ros2"):
            from sim.realtime.ros2_robot import DomainLease

            self.ros_domain = DomainLease.for_run()
            print(self.ros_domain.announce(), file=sys.stderr, flush=True)
        if self.transport in ("xbee", "serial"):
            self.medium = start_medium(len(self.robots), self._run_dir, self.seed,
                                       self.transport)

    def _pick_port(self) -> None:
        """The given multicast port, or a leased one."""
        if self._port:
            self.port = self._port
        else:
            # The run's own multicast port, held until `cleanup` so that no other run on
            # this machine is handed it while these robots use it (sim/realtime/ports.py).
            self.port_lease = PortLease(self.group)
            self.port = self.port_lease.port

    # -- processes --------------------------------------------------------------------------
    def _spawn(self, robot: int, t0: float | None) -> RobotProcess:
        from sim.realtime.robot_proc import RobotSpec, child_main

        cfg = write_robot_file(self.run_dir, self.swarm_path, robot, group=self.group,
                               port=self.port, transport=emulated_radio(
                                   self.transport, self.medium, self.radio_of[robot]),
                               identity_file=self.identity_files.get(robot),
                               link=self.ros_domain.link_doc(robot) if self.ros_domain
                               else None)
        spec = RobotSpec(
            robot_id=robot, config_path=str(cfg),
            log_path=str(robot_log(self.run_dir, robot)),
            loss=self.loss, seed=self.seed, partitions=self.schedule.partitions,
            loss_model=self.loss_model, burst_len=self.burst_len, link=self.link, t0=t0,
            craft=self.craft, refuse_arm=robot in self.refuse_arm,
        )
        ev_r, ev_w = self._ctx.Pipe(duplex=False)
        ctl_r, ctl_w = self._ctx.Pipe(duplex=False)
        process = self._ctx.Process(target=child_main, args=(spec, ev_w, ctl_r),
                                    name=f"swarmd-robot{robot}", daemon=False)
        with main_not_reimported():
            process.start()
        ev_w.close()
        ctl_r.close()
        proc = RobotProcess(robot, process, ev_r, ctl_w, ready=t0 is not None,
                     spawned_at=self.run_time() if t0 is not None else 0.0)
        asyncio.get_running_loop().add_reader(ev_r.fileno(), self._on_events, proc)
        self._write_pids(proc)
        return proc

    def _write_pids(self, latest: RobotProcess) -> None:
        pids = {str(p.robot_id): p.process.pid for p in self.procs.values()}
        pids[str(latest.robot_id)] = latest.process.pid
        doc = {"orchestrator": os.getpid(), "robots": pids,
               "retired": [p.process.pid for p in self.retired]}
        tmp = self.run_dir / "pids.json.tmp"
        tmp.write_text(json.dumps(doc))
        os.replace(tmp, self.run_dir / "pids.json")

    def _on_events(self, proc: RobotProcess) -> None:
        try:
            while proc.events.poll():
                self._record(proc, decode_report(proc.events.recv_bytes()))
        except (EOFError, OSError):
            self._close_events(proc)
        except ControlError as exc:  # a robot wrote something that is no report: say so
            self.problems.append(f"robot {proc.robot_id}: bad event message: {exc}")

    def _close_events(self, proc: RobotProcess) -> None:
        if not proc.eof:
            proc.eof = True
            with contextlib.suppress(ValueError, OSError):
                asyncio.get_running_loop().remove_reader(proc.events.fileno())
            if not proc.ready:
                self._ready_check()
            if proc.alive and self.t0:
                # Its pipe closed and nobody killed it: the process ended on its own.
                proc.alive = False
                proc.died_at = self.run_time()
                self.view.set_process(proc.robot_id, "left" if proc.left else "exited")

    def _record(self, proc: RobotProcess, report: Report) -> None:
        match report:
            case Ready():
                proc.ready = True
                self._ready_check()
            case Failed(error):
                proc.error = error
                self._ready_check()
            case Drops(counts):
                proc.drops = dict(counts)
            case Stats(passed, lost, partitioned, forged):
                self.stats[proc.robot_id] = {"passed": passed, "lost": lost,
                                             "partitioned": partitioned, "forged": forged}
            case Late(wakes, samples):
                self.wakes += wakes
                self.late.extend((proc.robot_id, t, ms) for t, ms in samples)
            case Logged(record):
                self.events.append(record)
                self.view.feed(record)

    def _ready_check(self) -> None:
        if all(p.ready or p.eof or p.error for p in self.procs.values()):
            self._ready.set()

    def _send(self, proc: RobotProcess, msg: Command) -> None:
        try:
            proc.control.send_bytes(encode(msg))
        except OSError as exc:  # the robot is gone; the fault still goes in the log
            self.problems.append(f"robot {proc.robot_id}: control {msg}: {exc}")

    def _kill_proc(self, proc: RobotProcess) -> None:
        if proc.alive and proc.process.pid is not None:
            kill_group(proc.process.pid, signal.SIGKILL)
        proc.alive = False

    def kill_all(self) -> None:
        """SIGKILL every robot process and reap it; safe to call more than once."""
        for proc in self._all():
            self._kill_proc(proc)
        for proc in self._all():
            proc.process.join(timeout=5.0)
            with contextlib.suppress(OSError):
                proc.control.close()

    # -- faults -----------------------------------------------------------------------------
    def run_time(self) -> float:
        return time.time() - self.t0

    def _fault_event(self, fault: Fault) -> None:
        rec = fault_record(fault, self.run_time())  # the same record as --virtual's
        self.events.append(rec)
        self.view.feed(rec)

    def _apply(self, fault: Fault) -> None:
        if fault.kind in LINK_KINDS:
            for part in fault.split():
                self._fault_event(part)  # the receive filters already hold the window
            return
        parts = fault.split()
        if len(parts) > 1:  # several robots at one instant: one fault each
            for part in parts:
                self._apply(part)
            return
        self._fault_event(fault)
        self._act(fault, self.procs.get(fault.robot))

    def _act(self, fault: Fault, proc: RobotProcess | None) -> None:
        """What a fault on one robot does to its process (`proc`; None: it has none)."""
        kind = fault.kind
        if kind is FaultKind.COLLIDE:  # the crafts lose their motors; without physics, a crash
            kind = FaultKind.MOTOR if self.link == "quad" else FaultKind.CRASH
        match kind:
            case FaultKind.CRASH:
                if proc is not None:
                    self._kill_proc(proc)
            case FaultKind.PAUSE:
                if proc is not None and proc.alive and proc.process.pid is not None:
                    kill_group(proc.process.pid, signal.SIGSTOP)
                    asyncio.get_running_loop().call_later(fault.duration or 0.0,
                                                          self._resume, proc)
            case FaultKind.RESTART:
                if proc is not None:
                    self._kill_proc(proc)  # a restart of a live robot is a crash first
                    self.retired.append(proc)
                if fault.wiped:  # its state directory emptied: as at a first start
                    shutil.rmtree(state_dir(self.run_dir, fault.robot), ignore_errors=True)
                self.procs[fault.robot] = self._spawn(fault.robot, self.t0)
            case FaultKind.LEAVE | FaultKind.UNHEALTHY | FaultKind.LIAR | FaultKind.MOTOR:
                if proc is not None and proc.alive:
                    proc.left = proc.left or kind is FaultKind.LEAVE
                    self._send(proc, Act(kind))
            case FaultKind.FORGE:  # the robot process holds R's key: it forges (Forger)
                if proc is not None and proc.alive:
                    self._send(proc, Forge(fault.attack))
            case _:
                self.problems.append(f"fault kind {fault.kind} is not supported in real time")

    def _resume(self, proc: RobotProcess) -> None:
        if proc.alive and proc.process.pid is not None:
            kill_group(proc.process.pid, signal.SIGCONT)
            self.view.set_process(proc.robot_id, "running")

    # -- the run ----------------------------------------------------------------------------
    def interrupt(self, reason: str) -> None:
        """End the run now (a signal handler): robots are killed, the result is partial."""
        if self.interrupted is None:
            self.interrupted = reason
        self._stop.set()

    async def _until(self, event: asyncio.Event, timeout: float) -> bool:
        """Wait for `event` or `interrupt()` for at most `timeout` s: True if `event` was
        set."""
        waits = [asyncio.ensure_future(event.wait()), asyncio.ensure_future(self._stop.wait())]
        try:
            await asyncio.wait(waits, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waits:
                w.cancel()
        return event.is_set()

    async def run(self, *, handle_signals: bool = False) -> RealtimeResult:
        self.prepare()
        startup = ended_at = 0.0
        installed = self._install_signals() if handle_signals else []
        try:
            startup = await self._start_robots()
            if self.interrupted is None:
                ended_at = await self._fly()
        finally:
            for sig in installed:
                asyncio.get_running_loop().remove_signal_handler(sig)
            self.schedule.cancel()
            self.kill_all()
            await self._drain()
        return self._result(startup, ended_at)

    def _install_signals(self) -> list[signal.Signals]:
        """SIGINT and SIGTERM end the run early (`interrupt`); the handlers installed."""
        loop = asyncio.get_running_loop()
        installed = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, self.interrupt, sig.name)
            installed.append(sig)
        return installed

    async def _start_robots(self) -> float:
        """Spawn every robot and wait until each is ready; the seconds that took. Raises
        `RuntimeError` naming the robots that were not ready in time or failed to start
        (unless the run was interrupted meanwhile)."""
        started = time.monotonic()
        for robot in self.robots:
            self.procs[robot] = self._spawn(robot, None)
        self._ready_check()
        ready = await self._until(self._ready, self.ready_timeout)
        if not ready and self.interrupted is None:
            slow = [r for r, p in self.procs.items() if not p.ready]
            raise RuntimeError(
                f"robots {slow} not ready after {self.ready_timeout:g} s: "
                + "; ".join(f"robot {r}: {self._log_tail(self.procs[r])}" for r in slow))
        startup = time.monotonic() - started
        failed = [p for p in self.procs.values() if not p.ready]
        if failed and self.interrupted is None:
            raise RuntimeError(
                "robot processes failed to start: "
                + "; ".join(f"robot {p.robot_id}: {p.error or self._log_tail(p)}"
                            for p in failed)
            )
        return startup

    async def _fly(self) -> float:
        """From t0 to the end of the run (or an interruption), faults applied on
        schedule; the run time it ended at."""
        live_ctx: Any = contextlib.nullcontext()
        self.t0 = time.time() + START_MARGIN
        for proc in self.procs.values():
            self._send(proc, Go(self.t0))
        self.schedule.arm(self.t0, self._apply)
        if self.live and sys.stdout.isatty():
            from rich.live import Live

            live_ctx = Live(get_renderable=lambda: self.view.table(self.run_time()),
                            refresh_per_second=4, transient=False)
        with live_ctx:
            await self._until(self._stop, self.t0 + self.duration - time.time())
        ended_at = min(self.duration, max(0.0, self.run_time()))
        # Before the robots are killed: only then is a live process telling.
        self.problems += never_started(self.procs.values(), self.events, ended_at,
                                       self.run_dir)
        return ended_at

    def _result(self, startup: float, ended_at: float) -> RealtimeResult:
        """The result, once every robot is killed and its last reports read."""
        self.problems += process_problems(self._all(), self.run_dir)
        died = deaths(self._all())
        self.events.sort(key=lambda r: float(r.get("t", 0.0)))
        return RealtimeResult(
            events=self.events, robots=self.robots, duration=self.duration, t0=self.t0,
            startup_s=startup, run_dir=self.run_dir if self.report_dir else None,
            problems=self.problems, stats=self.stats, drops=summed_drops(self._all()),
            deaths=died,
            late=sorted(self.late, key=lambda x: x[1]), wakes=self.wakes,
            interrupted=self.interrupted, ended_at=ended_at,
            log_errors=survived_errors(self.run_dir, self.robots, died),
        )

    def _all(self) -> list[RobotProcess]:
        return [*self.retired, *self.procs.values()]

    async def _drain(self) -> None:
        """Read what the killed robots wrote before they died (bounded)."""
        deadline = time.monotonic() + 2.0
        procs = self._all()
        while time.monotonic() < deadline and not all(p.eof for p in procs):
            for p in procs:
                if not p.eof:
                    self._on_events(p)
            await asyncio.sleep(0.01)
        for p in procs:
            self._close_events(p)
            with contextlib.suppress(OSError):
                p.events.close()

    def _log_tail(self, proc: RobotProcess) -> str:
        return tail_of(self.run_dir, proc)

    def cleanup(self) -> None:
        if self.port_lease is not None:
            self.port_lease.release()
            self.port_lease = None
        if self.ros_domain is not None:
            self.ros_domain.release()
            self.ros_domain = None
        if self.medium is not None:
            self.medium.stop()
            self.medium = None
        if self.report_dir is None and self._run_dir is not None:
            shutil.rmtree(self._run_dir, ignore_errors=True)


async def run_realtime_async(
    swarm_path: Path,
    *,
    duration: float,
    faults: Sequence[Fault] = (),
    loss: float = 0.0,
    seed: int = 0,
    events_path: Path | None = None,
    report_dir: Path | None = None,
    physics: bool = False,
    transport: str = "udp",
    live: bool = False,
    port: int | None = None,
    handle_signals: bool = False,
    craft: str | None = None,
    link: str | None = None,
    refuse_arm: Sequence[int] = (),
    loss_model: str = "bernoulli",
    burst_len: float = 4.0,
) -> RealtimeResult:
    """Run the swarm in real time (see the module docstring); awaitable form for tests.
    `handle_signals`: SIGINT and SIGTERM end the run early with a partial result
    (`interrupted`) instead of raising; only one run per process may ask for that.
    `craft`: the quadrotor preset every robot flies (physics; None: the link's default).
    `link`: the robots' link (`sim.realtime.robot_proc.LINK_FACTORIES`; None: `quad` with
    physics, else `none`); `refuse_arm`: robots whose simulated autopilot denies arming
    (the `mavlink-*` links)."""
    orch = Orchestrator(swarm_path, duration=duration, faults=faults, loss=loss, seed=seed,
                        physics=physics, live=live, report_dir=report_dir, port=port,
                        transport=transport, craft=craft, link=link, refuse_arm=refuse_arm,
                        loss_model=loss_model, burst_len=burst_len)
    try:
        orch.prepare()
        result = await orch.run(handle_signals=handle_signals)
    finally:
        orch.cleanup()
    if events_path is not None:
        write_events(events_path, result.events)
    return result


def _until_signalled(
    run: Callable[P, Coroutine[Any, Any, RealtimeResult]], name: str, doc: str,
) -> Callable[P, RealtimeResult]:
    """The blocking form of `run`, taking exactly its arguments (one parameter list for
    both forms), in a new event loop; `handle_signals` defaults to True there."""

    @functools.wraps(run)  # inspect.signature / help() show run's parameters
    def blocking(*args: P.args, **kwargs: P.kwargs) -> RealtimeResult:
        kwargs.setdefault("handle_signals", True)
        return asyncio.run(run(*args, **kwargs))

    blocking.__name__ = blocking.__qualname__ = name
    blocking.__doc__ = doc
    return blocking


run_realtime = _until_signalled(
    run_realtime_async, "run_realtime",
    "`swarmd sim` without --virtual: `run_realtime_async`'s parameters, blocking. Ctrl-C "
    "and SIGTERM end the run early: every robot is killed and reaped, and the partial "
    "result says `interrupted` (the CLI still writes its report and exits 128 + the "
    "signal's number).")
