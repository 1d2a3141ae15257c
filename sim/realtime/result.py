"""What a real-time run produced: the merged log and what went wrong with the processes,
for the summary (sim.realtime.summary) and the report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass(slots=True)
class RealtimeResult:
    """What a real-time run produced. `events` is the merged log, sorted by t."""

    events: list[dict[str, Any]]
    robots: tuple[int, ...]
    duration: float
    t0: float
    startup_s: float
    """s from the first process start to every robot ready (forkserver start-up)."""
    run_dir: Path | None
    """Robot files, per-robot logs and pids; kept only when `report_dir` was given."""
    problems: list[str] = field(default_factory=list)
    """Robot processes that failed to start, ended on their own, or never started their
    daemon: a run with problems is not a trustworthy test of the protocol."""
    stats: dict[int, dict[str, int]] = field(default_factory=dict)
    """Receive-filter counters of robots that exited gracefully (leave)."""
    drops: dict[int, dict[str, int]] = field(default_factory=dict)
    """robot -> its daemons' counted drops by reason, as last reported (once a second)."""
    deaths: dict[int, float] = field(default_factory=dict)
    """robot -> run time (s) its process ended on its own (not by a fault or a leave)."""
    late: list[tuple[int, float, float]] = field(default_factory=list)
    """(robot, run time s, ms) of every event-loop wake-up `LATE_MS` or more late."""
    wakes: int = 0
    """Wake-ups of every robot's lateness probe (the late ones and the others)."""
    log_errors: list[str] = field(default_factory=list)
    """Per robot whose log has error lines (swarmd.base.logs JSON, level error): how many and
    the first one. A daemon logs an error for what it survives (a link that raised, a
    node bug): the run went on, but a summary must not pass over it."""
    interrupted: str | None = None
    """The signal that ended the run early (SIGINT, SIGTERM), None if it ran to the end."""
    ended_at: float | None = None
    """Run time (s) the robots were killed: `duration`, or earlier when interrupted."""


# -- orchestration --------------------------------------------------------------------------
