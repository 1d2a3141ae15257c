"""Signals that arrive while `swarmd start` is still starting (docs/daemon.md).

SIGHUP's default action ends a process, and so do SIGTERM's and SIGINT's: a reload
(`systemctl reload`, a config tool that sends SIGHUP to every robot) that lands while a
daemon is importing its modules, reading its config or opening its radio would kill it.
`defer()` is the first thing `swarmd start` does (swarmd/cli.py, before its imports): from
then on these signals are only recorded, and `run_daemon` acts on what was recorded when
it installs its own handlers on the event loop (a SIGTERM or SIGINT stops the daemon
cleanly once started, a SIGHUP reloads it). What is left is the interpreter's own
start-up, before any of swarmd's code runs (tens of milliseconds).

Nothing here imports anything but `signal`: it must be cheap enough to run first.
"""

from __future__ import annotations

import signal
from types import FrameType

DEFERRED = (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)
_pending: list[int] = []


def _record(signum: int, _frame: FrameType | None) -> None:
    _pending.append(signum)


def defer() -> None:
    """Record SIGHUP, SIGTERM and SIGINT from now on instead of dying of them."""
    for sig in DEFERRED:
        signal.signal(sig, _record)


def take() -> list[int]:
    """The signals recorded since `defer()` (oldest first), forgotten once taken."""
    out, _pending[:] = list(_pending), []
    return out
