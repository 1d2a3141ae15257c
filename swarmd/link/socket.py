"""The `socket` robot link: a Unix socket speaking JSON Lines (paper Fig. 4 as a wire).

swarmd listens; the robot's own software connects and

- sends its health, one object a line: `{"health": "ok" | "degraded" | "faulty", ...}`
  (other keys are allowed and ignored, e.g. a battery level for the robot's own logs);
- receives its task: `{"assign": "f2", "epoch": 3, "params": {...}}` and
  `{"release": "f2"}`. A robot that (re)connects is sent its current assignment at once,
  so a restarted robot controller learns what to do without waiting for a change.

Health timeout (DESIGN rule 7): a robot that has not reported health for
`health_timeout` seconds, or that never connected within that time after start, is
reported FAULTY, so the daemon stops heartbeating and its function is handed over. The
next good health line clears it.

Bad input never takes the daemon down: a line that is not JSON, not an object, too long,
or with an unknown health value is counted in `counters["bad_lines"]`, logged, and
ignored (it does not refresh the health timer).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback

log = logging.getLogger(__name__)

HEALTH_NAMES = {"ok": Health.OK, "degraded": Health.DEGRADED, "faulty": Health.FAULTY}
LINE_LIMIT = 64 * 1024
"""bytes. A longer line is garbage; the connection is dropped (and counted)."""
WRITE_BUFFER_LIMIT = 256 * 1024
"""bytes. A robot that stops reading is disconnected rather than growing our memory."""


class SocketLinkError(RuntimeError):
    """The socket could not be set up (path taken by a non-socket, no permission)."""


class SocketLink:
    """Unix socket server for one robot controller. See the module docstring."""

    def __init__(self, path: Path | str, *, health_timeout: float = 2.0) -> None:
        if health_timeout <= 0:
            raise ValueError(f"health_timeout must be > 0 s, got {health_timeout}")
        self.path = Path(path)
        self.health_timeout = health_timeout
        self.counters: dict[str, int] = {"bad_lines": 0, "health": 0, "timeouts": 0,
                                         "connections": 0, "write_errors": 0}
        self._on_health: HealthCallback | None = None
        self._server: asyncio.AbstractServer | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._tasks: set[asyncio.Task[None]] = set()
        self._timer: asyncio.TimerHandle | None = None
        self._timed_out = False
        self._current: dict[str, Any] | None = None

    async def start(self, on_health: HealthCallback) -> None:
        """Listen on the socket path and arm the health timer."""
        self._on_health = on_health
        self._remove_stale()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._server = await asyncio.start_unix_server(
                self._client, path=str(self.path), limit=LINE_LIMIT)
            # Only the daemon's user and group may drive the robot's task.
            os.chmod(self.path, 0o660)
        except OSError as exc:
            raise SocketLinkError(f"cannot listen on robot socket {self.path}: {exc}") from exc
        self._arm()

    def _remove_stale(self) -> None:
        try:
            st = os.lstat(self.path)
        except (FileNotFoundError, NotADirectoryError):
            return  # nothing there (a parent that is no directory fails in `start`)
        if not stat.S_ISSOCK(st.st_mode):
            raise SocketLinkError(f"{self.path} exists and is not a socket; refusing to "
                                  "replace it")
        os.unlink(self.path)  # a socket left by a daemon that crashed

    # -- health timer ---------------------------------------------------------------------
    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        loop = asyncio.get_running_loop()
        self._timer = loop.call_later(self.health_timeout, self._timeout)

    def _timeout(self) -> None:
        self._timer = None
        if not self._timed_out:
            self._timed_out = True
            self.counters["timeouts"] += 1
            log.warning("robot health timed out: reporting faulty",
                        extra={"link": "socket", "timeout_s": self.health_timeout})
            if self._on_health is not None:
                self._on_health(Health.FAULTY)

    # -- clients --------------------------------------------------------------------------
    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if task is not None:
            self._tasks.add(task)
        self.counters["connections"] += 1
        self._writers.add(writer)
        if self._current is not None:
            self._write(writer, self._current)
        try:
            while True:
                try:
                    line = await reader.readline()
                except (asyncio.LimitOverrunError, ValueError):
                    self._bad(f"line longer than {LINE_LIMIT} bytes; dropping connection")
                    break
                except OSError as exc:
                    log.warning("robot socket read failed", extra={"error": str(exc)})
                    break
                if not line:
                    break
                self._line(line)
        finally:
            self._writers.discard(writer)
            writer.close()
            with contextlib.suppress(OSError, asyncio.CancelledError):
                await writer.wait_closed()
            if task is not None:
                self._tasks.discard(task)

    def _bad(self, why: str) -> None:
        self.counters["bad_lines"] += 1
        log.warning("bad line from robot", extra={"link": "socket", "reason": why})

    def _line(self, line: bytes) -> None:
        text = line.strip()
        if not text:
            return
        try:
            msg = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            self._bad(f"not JSON: {exc}")
            return
        if not isinstance(msg, dict) or "health" not in msg:
            self._bad("expected an object with a 'health' key")
            return
        health = HEALTH_NAMES.get(msg["health"]) if isinstance(msg["health"], str) else None
        if health is None:
            self._bad(f"unknown health {msg['health']!r}; expected ok, degraded or faulty")
            return
        self.counters["health"] += 1
        self._timed_out = False
        self._arm()
        if self._on_health is not None:
            self._on_health(health)

    def _write(self, writer: asyncio.StreamWriter, msg: Mapping[str, Any]) -> None:
        try:
            if writer.transport.get_write_buffer_size() > WRITE_BUFFER_LIMIT:
                log.warning("robot is not reading its socket; disconnecting it")
                writer.close()
                return
            writer.write((json.dumps(msg, separators=(",", ":")) + "\n").encode())
        except (OSError, RuntimeError) as exc:
            self.counters["write_errors"] += 1
            log.warning("robot socket write failed", extra={"error": str(exc)})

    def _send(self, msg: dict[str, Any]) -> None:
        for writer in list(self._writers):
            self._write(writer, msg)

    # -- the daemon's output --------------------------------------------------------------
    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        self._current = {"assign": function, "epoch": epoch, "params": dict(params)}
        self._send(self._current)

    def release(self, function: str) -> None:
        if self._current is not None and self._current.get("assign") == function:
            self._current = None
        self._send({"release": function})

    async def close(self) -> None:
        """Stop listening, drop clients, remove the socket file."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._on_health = None
        if self._server is not None:
            self._server.close()
            for writer in list(self._writers):
                writer.close()
            for task in list(self._tasks):
                task.cancel()
            if self._tasks:
                await asyncio.gather(*self._tasks, return_exceptions=True)
            await self._server.wait_closed()
            self._server = None
        with contextlib.suppress(OSError):
            if stat.S_ISSOCK(os.lstat(self.path).st_mode):
                os.unlink(self.path)
