"""The `exec` robot link: run a configured command when a function is assigned or released.

For robots whose software is driven by scripts (start a mission, land). The commands
run one at a time in order, in the background (never on the loop's critical path), each
with a time limit, and get the task in environment variables:

    SWARMD_ACTION    assign | release
    SWARMD_FUNCTION  f2
    SWARMD_EPOCH     3            (assign only)
    SWARMD_PARAMS    {"kind": "slot", "position": [...]}   (JSON, assign only)

A command given as a list runs without a shell; a string runs with `/bin/sh -c`.

Health: with `health_command`, it runs every `health_interval` seconds: exit 0 = ok,
1 = degraded, anything else or a time-out = faulty (DESIGN rule 7: a robot whose health
check hangs is not healthy). The health command's own time limit is `health_timeout`
(5 s), far below the 30 s an assign command may take: a hung check must hand the
function over within seconds, not half a minute. Without it the robot counts as healthy.

Output: the commands' stdout and stderr go to the daemon's stderr. The daemon's stdout
is its JSON log (one object a line, journald); a command printing binary, non-UTF-8 or
endless lines there would break every reader of it.

A command that fails is logged and counted in `counters`, and reported through
`on_error` (the daemon turns it into a `link_error` log line); it never raises.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
from collections.abc import Mapping, Sequence
from typing import Any

from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback

log = logging.getLogger(__name__)

Command = str | Sequence[str]

HEALTH_TIMEOUT = 5.0
"""s. A health command still running after this is killed and the robot is faulty
(module docstring)."""


async def run_command(cmd: Command, env: Mapping[str, str], timeout: float) -> int:
    """Run a configured command (a string through `/bin/sh -c`, a list without a shell)
    with `env` added to the daemon's environment and stdin closed; return its exit
    status. Raises `OSError` if it cannot start, and `TimeoutError` once a command that
    overran `timeout` has been killed and reaped: a hung command must not stay behind
    (nor keep the robot healthy, DESIGN rule 7). The exec link and the alert hook
    (swarmd/daemon/daemon.py) both run their commands through it."""
    full_env = {**os.environ, **env}
    # stdout to our stderr (fd 2): our stdout carries only the JSON log (module doc).
    if isinstance(cmd, str):
        proc = await asyncio.create_subprocess_shell(
            cmd, env=full_env, stdin=asyncio.subprocess.DEVNULL, stdout=2)
    else:
        proc = await asyncio.create_subprocess_exec(
            *cmd, env=full_env, stdin=asyncio.subprocess.DEVNULL, stdout=2)
    try:
        return await asyncio.wait_for(proc.wait(), timeout)
    except TimeoutError:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        await proc.wait()
        raise


class ExecLink:
    """Run commands on assign / release; optional periodic health command."""

    def __init__(
        self,
        *,
        on_assign: Command | None = None,
        on_release: Command | None = None,
        health_command: Command | None = None,
        health_interval: float = 1.0,
        timeout: float = 30.0,
        health_timeout: float = HEALTH_TIMEOUT,
    ) -> None:
        self.on_assign = on_assign
        self.on_release = on_release
        self.health_command = health_command
        self.health_interval = health_interval
        self.timeout = timeout
        self.health_timeout = health_timeout
        self.counters: dict[str, int] = {"runs": 0, "failures": 0, "timeouts": 0,
                                         "health_checks": 0}
        self._queue: asyncio.Queue[tuple[Command, dict[str, str]]] = asyncio.Queue()
        self._tasks: list[asyncio.Task[None]] = []
        self._on_health: HealthCallback | None = None
        self._idle = asyncio.Event()
        self._idle.set()
        self._last_health_outcome: str | None = None

    async def start(self, on_health: HealthCallback) -> None:
        self._on_health = on_health
        self._tasks.append(asyncio.create_task(self._worker(), name="exec-link-worker"))
        if self.health_command is not None:
            self._tasks.append(asyncio.create_task(self._health_loop(), name="exec-health"))
        else:
            on_health(Health.OK)

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        if self.on_assign is None:
            return
        env = {"SWARMD_ACTION": "assign", "SWARMD_FUNCTION": function,
               "SWARMD_EPOCH": str(epoch), "SWARMD_PARAMS": json.dumps(dict(params))}
        self._enqueue(self.on_assign, env)

    def release(self, function: str) -> None:
        if self.on_release is None:
            return
        self._enqueue(self.on_release, {"SWARMD_ACTION": "release", "SWARMD_FUNCTION": function})

    def _enqueue(self, cmd: Command, env: dict[str, str]) -> None:
        self._idle.clear()
        self._queue.put_nowait((cmd, env))

    async def wait_idle(self) -> None:
        """Wait until every queued command has finished (tests, orderly shutdown)."""
        await self._idle.wait()

    async def _run(self, cmd: Command, env: Mapping[str, str], *, timeout: float | None = None,
                   quiet: bool = False) -> int | None:
        """Run one command; its exit status, or None when it could not run / timed out.
        `quiet` (the health command, every second) logs a failure only when it differs
        from the previous run's, so a missing health script is one line, not 86,400 a
        day; it is counted every time."""
        self.counters["runs"] += 1
        limit = self.timeout if timeout is None else timeout
        try:
            status = await run_command(cmd, env, limit)
        except TimeoutError:  # first: TimeoutError is an OSError
            self.counters["timeouts"] += 1
            if self._news(quiet, "timeout"):
                log.error("robot link command timed out; killed",
                          extra={"command": str(cmd), "timeout_s": limit})
            return None
        except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the command
            self.counters["failures"] += 1
            if self._news(quiet, f"oserror {exc}"):
                log.error("robot link command cannot run", extra={"command": str(cmd),
                                                                  "error": str(exc)})
            return None
        self._news(quiet, f"status {status}")
        return status

    def _news(self, quiet: bool, outcome: str) -> bool:
        """Whether to log this outcome (see `_run`)."""
        if not quiet:
            return True
        new, self._last_health_outcome = outcome != self._last_health_outcome, outcome
        return new

    async def _worker(self) -> None:
        while True:
            cmd, env = await self._queue.get()
            status = await self._run(cmd, env)
            if status not in (0, None):
                self.counters["failures"] += 1
                log.error("robot link command failed",
                          extra={"command": str(cmd), "status": status,
                                 "action": env.get("SWARMD_ACTION")})
            if self._queue.empty():
                self._idle.set()

    async def _health_loop(self) -> None:
        assert self.health_command is not None
        loop = asyncio.get_running_loop()
        deadline = loop.time()
        while True:
            status = await self._run(self.health_command, {"SWARMD_ACTION": "health"},
                                     timeout=self.health_timeout, quiet=True)
            self.counters["health_checks"] += 1
            if status == 0:
                health = Health.OK
            elif status == 1:
                health = Health.DEGRADED
            else:
                health = Health.FAULTY
            if self._on_health is not None:
                self._on_health(health)
            # Schedule from the previous deadline, not from now (no drift).
            deadline += self.health_interval
            await asyncio.sleep(max(0.0, deadline - loop.time()))

    async def close(self) -> None:
        """Let queued commands finish (a release at shutdown must reach the robot), within
        `timeout`, then stop."""
        self._on_health = None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._idle.wait(), self.timeout)
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks.clear()
