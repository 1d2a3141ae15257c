"""The socket robot link's input budget is the link's, not a connection's (swarmd/link/
socket.py): however many connections a local process opens and however much it writes,
one turn of the event loop handles at most `LINES_PER_TURN` lines and reads from at
most a few sockets, so the daemon's heartbeat timer is never held back by more than a
turn's budget; a connection beyond `MAX_CONNECTIONS` is closed unread.

Before: the budget was per connection, so 400 connections writing 300 kB of bad lines
each delayed the daemon's heartbeats by 1.2 s on real daemons (standby 6 took f2 over
and robot 2 was fenced); `bench/bench_link_flood.py` prints the figures."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from pathlib import Path

import pytest

from swarmd.core.roles import Health
from swarmd.link import socket as socket_link
from swarmd.link.socket import LINES_PER_TURN, RESUMES_PER_TURN, SocketLink

READ_MAX = 256 * 1024
"""What asyncio reads from one socket at once."""


async def _flood(path: Path, connections: int, size: int) -> list[socket.socket]:
    """`connections` clients, each writing `size` bytes of short bad lines (without
    waiting to be read: the kernel holds what does not fit)."""
    socks = []
    for _ in range(connections):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.setblocking(False)
        s.connect(str(path))
        socks.append(s)
    payload = b"x" * 20 + b"\n"
    blob = payload * (size // len(payload))

    async def write(s: socket.socket) -> None:
        await asyncio.get_running_loop().sock_sendall(s, blob)

    for s in socks:
        asyncio.get_running_loop().create_task(write(s))
    return socks


async def test_many_connections_share_one_budget_per_turn(tmp_path: Path) -> None:
    healths: list[Health] = []
    link = SocketLink(tmp_path / "robot.sock", health_timeout=60.0)
    await link.start(healths.append)
    loop = asyncio.get_running_loop()
    lines: list[int] = []
    reads: list[int] = []
    last = [0, 0]
    done = asyncio.Event()

    def turn() -> None:  # one call per turn of the loop
        lines.append(link.counters["bad_lines"] - last[0])
        reads.append(link.counters.get("bytes_read", 0) - last[1])
        last[:] = [link.counters["bad_lines"], link.counters.get("bytes_read", 0)]
        if not done.is_set():
            loop.call_soon(turn)

    loop.call_soon(turn)
    socks = await _flood(tmp_path / "robot.sock", 40, 40_000)
    try:
        _, writer = await asyncio.open_unix_connection(str(tmp_path / "robot.sock"))
        writer.write(b'{"health": "ok"}\n')
        await writer.drain()
        async with asyncio.timeout(60):
            while not healths or link.counters["bad_lines"] < 40 * (40_000 // 21):
                await asyncio.sleep(0.05)
        writer.close()
    finally:
        done.set()
        for s in socks:
            s.close()
        await link.close()
    assert healths == [Health.OK]
    assert link.counters["bad_lines"] == 40 * (40_000 // 21)
    # Between two of our turns, two of the link's at most (its budget is a turn's):
    # lines handled, and reads from a few sockets, whatever the number of connections.
    assert max(lines) <= 2 * LINES_PER_TURN
    assert max(reads) <= 2 * (RESUMES_PER_TURN + 1) * READ_MAX


async def test_a_connection_beyond_the_cap_is_closed_unread(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(socket_link, "MAX_CONNECTIONS", 3)
    healths: list[Health] = []
    link = SocketLink(tmp_path / "robot.sock", health_timeout=60.0)
    await link.start(healths.append)
    try:
        kept = [await asyncio.open_unix_connection(str(tmp_path / "robot.sock"))
                for _ in range(3)]
        reader, writer = await asyncio.open_unix_connection(str(tmp_path / "robot.sock"))
        writer.write(b'{"health": "faulty"}\n')
        with contextlib.suppress(ConnectionResetError, BrokenPipeError):  # closed, unread
            assert await asyncio.wait_for(reader.read(), 10.0) == b""
        kept[0][1].write(b'{"health": "ok"}\n')
        async with asyncio.timeout(10):
            while not healths:
                await asyncio.sleep(0.01)
        assert healths == [Health.OK] and link.counters["refused"] == 1
        for _, w in kept:
            w.close()
    finally:
        await link.close()
