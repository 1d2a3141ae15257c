"""The robot processes of a real-time run: how they are started (a forkserver that
preloads swarmd) and signalled (their process group), and what the orchestrator knows of
each one."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any


@dataclass(slots=True)
class RobotProcess:
    """One robot process as the orchestrator sees it."""

    robot_id: int
    process: BaseProcess
    events: Connection
    control: Connection
    ready: bool = False
    alive: bool = True
    """Not killed by the orchestrator, nor seen to end."""
    eof: bool = False
    error: str | None = None
    spawned_at: float = 0.0
    """Run time the process was started (0 for the robots started before t0)."""
    left: bool = False
    """Told to leave: its own exit is the expected end."""
    died_at: float | None = None
    """Run time its event pipe closed although nobody killed it."""
    drops: dict[str, int] = field(default_factory=dict)
    """Its daemon's counted drops, by reason, as of its last report (`DropReporter`)."""


def forkserver_context(physics: bool) -> Any:
    """The multiprocessing context robots are started from.

    Preloading swarmd in the forkserver makes each robot a cheap fork (~20 ms instead of
    a ~0.5 s interpreter start-up): 50 robots start within about a second. With physics,
    MuJoCo and the quadrotor link are preloaded too, or every robot imports them after
    the fork (docs/physics.md: 30 flying robots start in 0.46 s preloaded, 7.4 s not).
    uvloop, the daemons' event loop (swarmd/base/eventloop.py), is imported only when a
    loop is made: preloaded, its pages are shared rather than copied into every robot
    (about 1 MB each; the forkserver skips a module that is not installed). The
    forkserver is one per parent process and keeps the list it started with."""
    ctx = multiprocessing.get_context("forkserver")
    preload = ["sim.realtime.robot_proc", "uvloop"] + (["sim.physics.link"] if physics
                                                       else [])
    ctx.set_forkserver_preload(preload)
    return ctx


@contextlib.contextmanager
def main_not_reimported() -> Iterator[None]:
    """Hide `__main__`'s file from multiprocessing while a robot process is started.

    A forkserver child re-imports the parent's main script (as `__mp_main__`) before it
    runs its target. The robots need nothing from it (their entry is in
    sim/realtime/robot_proc.py, preloaded in the forkserver), and re-importing it costs each
    robot the whole CLI's imports, or re-runs a script that has no main guard."""
    main = sys.modules.get("__main__")
    if main is None:
        yield
        return
    saved: dict[str, Any] = {
        k: main.__dict__[k] for k in ("__file__", "__spec__") if k in main.__dict__
    }
    main.__dict__.pop("__file__", None)
    main.__dict__["__spec__"] = None
    try:
        yield
    finally:
        main.__dict__.pop("__spec__", None)
        main.__dict__.update(saved)


def kill_group(pid: int, sig: int) -> None:
    """Send `sig` to a robot's process group.

    Robots lead their own process group (robot_proc), so anything a robot link started
    dies with it. Before the child's setpgid ran, fall back to the pid."""
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, sig)
