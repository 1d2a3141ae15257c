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
or with an unknown health value is counted in `counters["bad_lines"]` and ignored (it
does not refresh the health timer); the log says so once, then at most once every 10 s
with the count (`CountedLog`: "bad lines from the robot: 523 in the last 10 s").
The robot link never starves the protocol: the link as a whole, all its connections
together, handles at most `LINES_PER_TURN` lines or `BYTES_PER_TURN` bytes per turn of
the event loop, and a connection that holds more stops reading its socket and waits its
turn (round robin: each turn the budget goes first to whoever waited longest), so a
robot writing a megabyte of short garbage lines delays the daemon's timers by one
turn's budget (about a millisecond), not seconds, however many connections it opens;
the kernel's socket buffers then hold the writers back. Reading is budgeted too: a new
connection, and one whose last read was bulk (`BULK_READ`) or that holds lines for a
later turn, is paused and reads again only when its turn comes, `RESUMES_PER_TURN` a
turn, so a turn reads from a few sockets however many are open (a controller's health
lines are small: its connection is never paused for them). At most `MAX_CONNECTIONS`
are open at once: one more is closed unread (counted in `counters["refused"]`, logged
at most once every 10 s).

Whatever parsing a line raises (a RecursionError for `[` nested thousands deep, a
ValueError for an integer of thousands of digits) is such a bad line too; a line longer
than `LINE_LIMIT` is skipped up to its newline. The connection stays up and the next
good line counts.

Each connection is an `asyncio.Protocol` (`_Connection`) whose lines are handled as they
arrive (`data_received`, a turn's share at a time). A robot that writes its health and
closes without reading what we sent (the assignment, sent on connect) resets the
connection, or makes our write fail first; a `StreamReader` raised that before returning
the line it had buffered, and a failed write closes the transport without reading again.
Either way the health was lost (about 180 of 200 such clients, tests/test_link.py) and
the robot timed out to FAULTY. Now the lines still queued on the socket are read in
`connection_lost` (`_Connection._drain`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import stat
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

from swarmd.core.roles import Health
from swarmd.link.base import CountedLog, HealthCallback

log = logging.getLogger(__name__)

HEALTH_NAMES = {"ok": Health.OK, "degraded": Health.DEGRADED, "faulty": Health.FAULTY}
LINE_LIMIT = 64 * 1024
"""bytes. A longer line is garbage: counted as one bad line and skipped to its newline."""
LINES_PER_TURN = 64
"""Lines the link handles per turn of the event loop, all connections together (module
docstring)."""
BYTES_PER_TURN = 64 * 1024
"""bytes of lines the link handles per turn of the event loop, all connections together
(at least one line a turn)."""
MAX_CONNECTIONS = 256
"""Connections open at once (the robot's controller and a few tools; a burst of one-line
clients). One more is closed unread, and counted."""
RESUMES_PER_TURN = 2
"""Connections that may read from their socket again per turn of the loop (module
docstring): what a turn reads is bounded by this many reads (asyncio's 256 KiB each),
not by how many connections are open."""
BULK_READ = 16 * 1024
"""bytes. A read this large pauses its connection until its turn to read comes again: a
controller's health lines (a few hundred bytes) never wait."""
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
                                         "connections": 0, "write_errors": 0, "refused": 0,
                                         "bytes_read": 0}
        self._on_health: HealthCallback | None = None
        self._server: asyncio.AbstractServer | None = None
        self._connections: set[_Connection] = set()
        self._timer: asyncio.TimerHandle | None = None
        self._timed_out = False
        self._current: dict[str, Any] | None = None
        self._bad_log = CountedLog(log, "bad lines from the robot")
        self._refused_log = CountedLog(log, "robot socket connections refused")
        self._turn_lines = self._turn_bytes = 0
        """What this turn of the loop has handled so far (`_spend`)."""
        self._turn_reset: asyncio.Handle | None = None
        self._waiting: dict[_Connection, None] = {}
        """Connections holding lines for a later turn, the longest waiting first."""
        self._to_resume: dict[_Connection, None] = {}
        """Paused connections waiting for their turn to read, the longest first."""

    async def start(self, on_health: HealthCallback) -> None:
        """Listen on the socket path and arm the health timer."""
        self._on_health = on_health
        self._remove_stale()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._server = await asyncio.get_running_loop().create_unix_server(
                lambda: _Connection(self), path=str(self.path))
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

    # -- clients (called by _Connection) --------------------------------------------------
    def _connected(self, conn: _Connection) -> bool:
        """A new connection: False (and closed) if `MAX_CONNECTIONS` are open."""
        if len(self._connections) >= MAX_CONNECTIONS:
            self.counters["refused"] += 1
            self._note(self._refused_log, f"{MAX_CONNECTIONS} connections already open")
            return False
        self.counters["connections"] += 1
        self._connections.add(conn)
        if self._current is not None:
            self._write(conn, self._current)
        return True

    def _spend(self, size: int) -> bool:
        """May one more line of `size` bytes be handled this turn (module docstring)?"""
        if self._turn_lines >= LINES_PER_TURN or (
                self._turn_lines and self._turn_bytes + size > BYTES_PER_TURN):
            return False
        if self._turn_reset is None:
            with contextlib.suppress(RuntimeError):  # no loop: the parser driven alone
                self._turn_reset = asyncio.get_running_loop().call_soon(self._next_turn)
        self._turn_lines += 1
        self._turn_bytes += size
        return True

    def _wait(self, conn: _Connection) -> None:
        """`conn` holds lines for a later turn: it is handled again next turn, after
        those that waited longer."""
        self._waiting[conn] = None
        self._turn_coming()

    def _read_later(self, conn: _Connection) -> None:
        """`conn` (paused) may read again when its turn comes (`RESUMES_PER_TURN`)."""
        self._to_resume[conn] = None
        self._turn_coming()

    def _turn_coming(self) -> None:
        if self._turn_reset is None:
            self._turn_reset = asyncio.get_running_loop().call_soon(self._next_turn)

    def _next_turn(self) -> None:
        """A new turn of the loop (run first in it): a fresh budget, spent first on the
        connections that waited, in order; then the next few paused connections may
        read again."""
        self._turn_reset = None
        self._turn_lines = self._turn_bytes = 0
        waiting, self._waiting = self._waiting, {}
        for conn in waiting:
            conn._handle()
        for conn in list(self._to_resume)[:RESUMES_PER_TURN]:
            del self._to_resume[conn]
            conn._resume()
        if self._to_resume:
            self._turn_coming()

    def _disconnected(self, conn: _Connection, exc: Exception | None) -> None:
        self._connections.discard(conn)
        if exc is not None and not isinstance(exc, ConnectionResetError | BrokenPipeError):
            # A reset is a robot that wrote and left without reading: normal.
            log.warning("robot socket read failed", extra={"error": str(exc)})

    def _bad(self, why: str) -> None:
        self.counters["bad_lines"] += 1
        self._note(self._bad_log, why)

    @staticmethod
    def _note(counted: CountedLog, why: str) -> None:
        """One more of what `counted` logs, at most once every 10 s with the count."""
        try:
            loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop()
        except RuntimeError:  # the line parser driven on its own (fuzzing, tests)
            loop = None
        now = loop.time() if loop is not None else time.monotonic()
        if counted.hit(why, now, link="socket") and loop is not None:
            running = loop
            running.call_at(counted.due, lambda: counted.tick(running.time()))

    def _line(self, line: bytes) -> None:
        text = line.strip()
        if not text:
            return
        try:
            msg = json.loads(text)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            self._bad(f"not JSON: {exc}")
            return
        except RecursionError:
            self._bad("JSON nested too deeply")
            return
        except Exception as exc:  # e.g. ValueError: an integer beyond 4300 digits
            self._bad(f"unusable JSON: {type(exc).__name__}: {str(exc)[:120]}")
            return
        if not isinstance(msg, dict) or "health" not in msg:
            self._bad("expected an object with a 'health' key")
            return
        health = HEALTH_NAMES.get(msg["health"]) if isinstance(msg["health"], str) else None
        if health is None:
            shown = repr(msg["health"]) if isinstance(msg["health"], str) else \
                type(msg["health"]).__name__
            self._bad(f"unknown health {shown[:60]}; expected ok, degraded or faulty")
            return
        self.counters["health"] += 1
        self._timed_out = False
        self._arm()
        if self._on_health is not None:
            self._on_health(health)

    def _write(self, conn: _Connection, msg: Mapping[str, Any]) -> None:
        transport = conn.transport
        if transport is None or transport.is_closing():
            return
        try:
            if transport.get_write_buffer_size() > WRITE_BUFFER_LIMIT:
                log.warning("robot is not reading its socket; disconnecting it")
                transport.close()
                return
            transport.write((json.dumps(msg, separators=(",", ":")) + "\n").encode())
        except (OSError, RuntimeError) as exc:
            self.counters["write_errors"] += 1
            log.warning("robot socket write failed", extra={"error": str(exc)})

    def _send(self, msg: dict[str, Any]) -> None:
        for conn in list(self._connections):
            self._write(conn, msg)

    # -- the daemon's output --------------------------------------------------------------
    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        self._current = {"assign": function, "epoch": epoch, "params": dict(params)}
        self._send(self._current)

    def release(self, function: str) -> None:
        # What a robot that (re)connects is told first: it holds nothing now ("" from a
        # daemon that starts as a standby: stop whatever you executed before).
        self._current = {"release": function}
        self._send(self._current)

    async def close(self) -> None:
        """Stop listening, drop clients, remove the socket file."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._on_health = None
        if self._server is not None:
            self._server.close()
            for conn in list(self._connections):
                if conn.transport is not None:
                    conn.transport.abort()  # connection_lost runs on the next loop pass
            await self._server.wait_closed()
            await asyncio.sleep(0)
            self._server = None
        with contextlib.suppress(OSError):
            if stat.S_ISSOCK(os.lstat(self.path).st_mode):
                os.unlink(self.path)


class _Connection(asyncio.Protocol):
    """One robot controller's connection: lines are handled as they arrive (see the
    module docstring for why not a StreamReader)."""

    def __init__(self, link: SocketLink) -> None:
        self.link = link
        self.transport: asyncio.Transport | None = None
        self._buffer = bytearray()
        self._skipping = False
        self._fd = -1
        self._paused = False
        self._lost = False
        self._later = False
        """Lines wait for a later turn (`SocketLink._wait`)."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # A stream transport; uvloop's has asyncio.Transport's methods without being a
        # subclass of it, so this is a cast, not a check.
        stream = cast(asyncio.Transport, transport)
        sock = stream.get_extra_info("socket")
        self.transport = stream
        self._fd = sock.fileno() if sock is not None else -1
        if not self.link._connected(self):
            self.transport, self._fd, self._lost = None, -1, True  # nothing of it is read
            stream.abort()
            return
        # It reads when its turn comes: a burst of new connections is read a few a turn.
        stream.pause_reading()
        self._paused = True
        self.link._read_later(self)

    def data_received(self, data: bytes) -> None:
        if self.transport is None:
            return
        self.link.counters["bytes_read"] += len(data)
        if self._skipping:  # the rest of an overlong line, up to its newline
            end = data.find(b"\n")
            if end < 0:
                return
            self._skipping = False
            data = data[end + 1:]
        self._buffer += data
        self._handle()
        if len(data) >= BULK_READ and not self._paused and self.transport is not None:
            self.transport.pause_reading()  # a bulk writer reads again in its turn
            self._paused = True
            self.link._read_later(self)

    def _handle(self) -> None:
        """Handle the complete lines held, as far as the link's budget for this turn
        goes; if more remain, stop reading and wait for a later turn (module docstring:
        the loop is never starved)."""
        self._later = False
        start = 0
        while (end := self._buffer.find(b"\n", start)) >= 0:
            if not self.link._spend(end + 1 - start):
                break
            if end - start > LINE_LIMIT:
                self.link._bad(f"line longer than {LINE_LIMIT} bytes; skipped")
            else:
                self.link._line(bytes(self._buffer[start : end + 1]))
            start = end + 1
        del self._buffer[:start]
        transport = self.transport
        if self._buffer.find(b"\n") >= 0:  # more in a later turn
            if transport is not None and not self._paused:
                transport.pause_reading()
                self._paused = True
            self._later = True
            self.link._wait(self)
            return
        if self._paused:
            self.link._read_later(self)
        if len(self._buffer) > LINE_LIMIT:
            self.link._bad(f"line longer than {LINE_LIMIT} bytes; skipped")
            self._buffer.clear()
            self._skipping = True
        if self._lost:
            self._rest()

    def _resume(self) -> None:
        """Its turn to read from its socket again (`SocketLink._next_turn`)."""
        transport = self.transport
        if self._paused and not self._later and transport is not None \
                and not transport.is_closing():
            transport.resume_reading()
            self._paused = False

    def eof_received(self) -> bool:
        # Close our side too; `connection_lost` follows and handles what is left (lines
        # still waiting for their turn, then a last one without a newline).
        return False

    def connection_lost(self, exc: Exception | None) -> None:
        self.transport = None
        self._lost = True
        if exc is not None:
            self._drain()
        if not self._later:
            self._handle()  # then a last line without a newline, also after a reset
        self.link._disconnected(self, exc)

    def _drain(self) -> None:
        """What the kernel still holds for us. A write that failed (the robot already
        closed: EPIPE) makes the transport close without reading again, though the
        robot's last lines are queued on our socket; the socket itself is closed only
        after `connection_lost` returns, so read them now (non-blocking)."""
        for _ in range(LINE_LIMIT // 4096 + 1):
            try:
                data = os.read(self._fd, 65536)
            except OSError:  # EAGAIN: nothing more; ECONNRESET after the data; EBADF
                return
            if not data:
                return
            if self._skipping:
                end = data.find(b"\n")
                if end < 0:
                    continue
                self._skipping = False
                data = data[end + 1:]
            self._buffer += data  # handled a turn's share at a time (`_handle`)

    def _rest(self) -> None:
        if self._buffer:
            line, self._buffer = bytes(self._buffer), bytearray()
            self.link._line(line)
