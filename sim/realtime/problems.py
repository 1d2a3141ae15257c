"""What went wrong with a real-time run's robot processes themselves, told from what the
orchestrator kept of them (`RobotProcess`), the merged event log and each robot's log
under `<run>/logs/`; reported, never silently passed over: a live robot whose daemon
never logged `started`, a robot process that ends on its own during the run (`deaths`:
the time its pipe closed, so the checker treats it as a crash rather than calling its
replacement a false takeover), errors a robot survived. Each finding is one line for
`RealtimeResult.problems` (or `log_errors`), quoting the robot's log where that explains
it. Nothing here starts, signals or waits for a process: `Orchestrator` does, and asks
this module what to report.
"""

from __future__ import annotations

import signal
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from sim.realtime.logscan import log_errors, log_tail
from sim.realtime.procs import RobotProcess
from swarmd.core.events import Started, event_of

STARTED_GRACE = 3.0
"""s a live robot process has, from its start, to log `started` before that is a problem."""


def robot_log(run_dir: Path, robot: int) -> Path:
    """Where robot `robot`'s process writes its daemon's log."""
    return run_dir / "logs" / f"robot{robot}.log"


def tail_of(run_dir: Path, proc: RobotProcess) -> str:
    """The end of a robot process's log, for a one-line problem."""
    return log_tail(robot_log(run_dir, proc.robot_id))


def errors_of(run_dir: Path, robot: int) -> str:
    """The errors robot `robot` logged and survived; "" for none (or no log)."""
    return log_errors(robot_log(run_dir, robot), robot)


def never_started(procs: Iterable[RobotProcess], events: Sequence[dict[str, Any]],
                  end: float, run_dir: Path) -> list[str]:
    """Live robots whose daemon never logged `started` (e.g. a transport that blocks on
    open): alive, but not in the swarm. Asked before the robots are killed, at run time
    `end`."""
    out = []
    for p in procs:
        if not p.alive or end - p.spawned_at < STARTED_GRACE:
            continue
        if not any(e.get("robot") == p.robot_id and isinstance(event_of(e), Started)
                   and float(e.get("t", 0.0)) >= p.spawned_at - 0.5 for e in events):
            out.append(
                f"robot {p.robot_id}: process alive but its daemon never started (no "
                f"`started` event in {end - p.spawned_at:.1f} s): {tail_of(run_dir, p)}")
    return out


def process_problems(procs: Iterable[RobotProcess], run_dir: Path) -> list[str]:
    """One line for each robot process that ended on its own, with its exit code and
    the end of its log (its error, when it sent one)."""
    out = []
    for p in procs:
        code = p.process.exitcode
        if p.died_at is not None:
            if p.left and code == 0:
                continue  # a leave: the daemon handed over and exited
            out.append(
                f"robot {p.robot_id}: process ended on its own at t={p.died_at:.2f} s "
                f"(exit code {code}): {p.error or tail_of(run_dir, p)}")
        elif p.error is not None and p.ready:
            out.append(f"robot {p.robot_id} failed: {p.error}")
        elif code not in (0, -signal.SIGKILL, None):
            out.append(f"robot {p.robot_id} exited with {code}: {tail_of(run_dir, p)}")
    return out


def deaths(procs: Iterable[RobotProcess]) -> dict[int, float]:
    """robot -> run time its process ended on its own (a leave is no death): the checker
    treats it as a crash rather than calling its replacement a false takeover."""
    return {p.robot_id: p.died_at for p in procs if p.died_at is not None and not p.left}


def survived_errors(run_dir: Path, robots: Iterable[int], died: Iterable[int]) -> list[str]:
    """The errors each robot that did not die logged (a robot that died is a problem
    already, its log quoted there); robots without any are left out."""
    gone = set(died)
    found = [errors_of(run_dir, r) for r in robots if r not in gone]
    return [e for e in found if e]


def summed_drops(procs: Iterable[RobotProcess]) -> dict[int, dict[str, int]]:
    """robot -> counted drops summed over its processes (a restart is a new one)."""
    out: dict[int, dict[str, int]] = {}
    for proc in procs:
        mine = out.setdefault(proc.robot_id, {})
        for reason, n in proc.drops.items():
            mine[reason] = mine.get(reason, 0) + n
    return {r: dict(sorted(d.items())) for r, d in out.items() if d}


__all__ = ["STARTED_GRACE", "deaths", "errors_of", "never_started", "process_problems",
           "robot_log", "summed_drops", "survived_errors", "tail_of"]
