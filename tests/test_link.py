"""Robot links: socket (JSON Lines both ways, health timeout), exec (commands), none."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import sys
from pathlib import Path

import pytest

from swarmd.core.roles import Health
from swarmd.link.exec import ExecLink, run_command
from swarmd.link.factory import LinkConfigError, make_link
from swarmd.link.none import NoneLink
from swarmd.link.socket import SocketLink, SocketLinkError


class HealthLog:
    def __init__(self) -> None:
        self.values: list[Health] = []
        self.changed = asyncio.Event()

    def __call__(self, h: Health) -> None:
        self.values.append(h)
        self.changed.set()

    async def next(self, timeout: float = 3.0) -> Health:
        await asyncio.wait_for(self.changed.wait(), timeout)
        self.changed.clear()
        return self.values[-1]


async def read_json(reader: asyncio.StreamReader) -> dict[str, object]:
    line = await asyncio.wait_for(reader.readline(), 3.0)
    out: dict[str, object] = json.loads(line)
    return out


async def test_socket_link_json_lines_both_ways(tmp_path: Path) -> None:
    path = tmp_path / "robot.sock"
    link = SocketLink(path, health_timeout=5.0)
    health = HealthLog()
    await link.start(health)
    try:
        assert path.stat().st_mode & 0o777 == 0o660
        reader, writer = await asyncio.open_unix_connection(str(path))
        writer.write(b'{"health": "ok", "battery": 0.9}\n')
        assert await health.next() == Health.OK
        link.assign("f2", 3, {"kind": "slot", "position": [0.0, 2.0, 1.5]})
        assert await read_json(reader) == {"assign": "f2", "epoch": 3,
                                           "params": {"kind": "slot",
                                                      "position": [0.0, 2.0, 1.5]}}
        writer.write(b'not json\n{"health": "sick"}\n[1]\n{"health": "degraded"}\n')
        assert await health.next() == Health.DEGRADED
        assert link.counters["bad_lines"] == 3
        # A robot controller that reconnects is told its current task at once.
        writer.close()
        r2, w2 = await asyncio.open_unix_connection(str(path))
        assert (await read_json(r2))["assign"] == "f2"
        link.release("f2")
        assert await read_json(r2) == {"release": "f2"}
        w2.close()
    finally:
        await link.close()
    assert not path.exists()


async def test_socket_link_health_timeout_reports_faulty_then_recovers(tmp_path: Path) -> None:
    link = SocketLink(tmp_path / "r.sock", health_timeout=0.2)
    health = HealthLog()
    await link.start(health)
    try:
        # Never connected within the timeout: faulty (DESIGN rule 7).
        assert await health.next() == Health.FAULTY
        _, writer = await asyncio.open_unix_connection(str(tmp_path / "r.sock"))
        writer.write(b'{"health": "ok"}\n')
        assert await health.next() == Health.OK
        # Then silence: faulty again, reported once per silence.
        assert await health.next() == Health.FAULTY
        assert link.counters["timeouts"] == 2
        writer.close()
    finally:
        await link.close()


async def test_socket_link_refuses_to_replace_a_regular_file(tmp_path: Path) -> None:
    path = tmp_path / "not-a-socket"
    path.write_text("precious")
    with pytest.raises(SocketLinkError, match="not a socket"):
        await SocketLink(path).start(HealthLog())
    assert path.read_text() == "precious"


async def test_socket_link_skips_an_overlong_line_and_keeps_the_client(tmp_path: Path) -> None:
    link = SocketLink(tmp_path / "r.sock", health_timeout=5.0)
    health = HealthLog()
    await link.start(health)
    try:
        _, writer = await asyncio.open_unix_connection(str(tmp_path / "r.sock"))
        writer.write(b"x" * (200 * 1024))  # no newline yet: buffered only up to the cap
        await writer.drain()
        writer.write(b"still the same line\n" + b'{"health": "degraded"}\n')
        assert await health.next() == Health.DEGRADED  # the next good line counts
        assert link.counters["bad_lines"] == 1
        assert link.counters["health"] == 1
        writer.close()
    finally:
        await link.close()


@pytest.mark.parametrize("garbage", [
    b"[" * 60000,                                   # RecursionError in json.loads
    b'{"health": ' + b"9" * 5000 + b"}",            # ValueError: > 4300 digits
    b"{" * 20000,
    b'{"health": [[[[1]]]]}',
], ids=["brackets-60k", "int-5000-digits", "braces-20k", "nested-health"])
async def test_socket_link_contains_any_parse_failure(tmp_path: Path, garbage: bytes) -> None:
    link = SocketLink(tmp_path / "r.sock", health_timeout=5.0)
    health = HealthLog()
    await link.start(health)
    try:
        _, writer = await asyncio.open_unix_connection(str(tmp_path / "r.sock"))
        writer.write(garbage + b"\n" + b'{"health": "faulty"}\n')
        assert await health.next() == Health.FAULTY  # the line after the garbage counts
        assert link.counters == {**link.counters, "bad_lines": 1, "health": 1,
                                 "connections": 1}
        writer.write(b'{"health": "ok"}\n')  # and the same connection still works
        assert await health.next() == Health.OK
        writer.close()
    finally:
        await link.close()


async def test_exec_link_runs_commands_with_the_task_in_env(tmp_path: Path) -> None:
    out = tmp_path / "out.txt"
    script = (f"import os; open({str(out)!r}, 'a').write(os.environ['SWARMD_ACTION'] + ' ' + "
              "os.environ['SWARMD_FUNCTION'] + ' ' + os.environ.get('SWARMD_EPOCH', '-') + "
              "' ' + os.environ.get('SWARMD_PARAMS', '-') + '\\n')")
    cmd = [sys.executable, "-c", script]
    link = ExecLink(on_assign=cmd, on_release=cmd)
    health = HealthLog()
    await link.start(health)
    try:
        assert health.values == [Health.OK]  # no health command: healthy
        link.assign("f2", 4, {"kind": "slot"})
        link.release("f2")
        await asyncio.wait_for(link.wait_idle(), 10.0)
    finally:
        await link.close()
    assert out.read_text().splitlines() == ['assign f2 4 {"kind": "slot"}', "release f2 - -"]
    assert link.counters["failures"] == 0


async def test_exec_link_health_command_and_failures(tmp_path: Path) -> None:
    link = ExecLink(on_assign="exit 3", health_command="exit 1", health_interval=0.05)
    health = HealthLog()
    await link.start(health)
    try:
        assert await health.next(5.0) == Health.DEGRADED
        link.assign("f1", 1, {})
        await asyncio.wait_for(link.wait_idle(), 10.0)
        assert link.counters["failures"] == 1
    finally:
        await link.close()


async def test_exec_link_kills_a_hanging_health_command() -> None:
    # The health command has its own limit, far below the 30 s of assign commands.
    link = ExecLink(on_assign="true", health_command="sleep 30", health_timeout=0.2)
    health = HealthLog()
    await link.start(health)
    try:
        assert await health.next(5.0) == Health.FAULTY
        assert link.counters["timeouts"] == 1
    finally:
        await link.close()


async def test_none_link_records_and_factory_builds_kinds(tmp_path: Path) -> None:
    link = NoneLink()
    health = HealthLog()
    await link.start(health)
    link.assign("f1", 0, {})
    link.release("f1")
    link.set_health(Health.FAULTY)
    assert link.history == [("assign", "f1", 0), ("release", "f1", None)]
    assert health.values == [Health.OK, Health.FAULTY]
    assert isinstance(make_link(None), NoneLink)

    class Cfg:
        kind = "socket"
        path = str(tmp_path / "s.sock")
        health_timeout = 1.0

    assert isinstance(make_link(Cfg()), SocketLink)
    Cfg.kind = "teleport"
    with pytest.raises(LinkConfigError, match="teleport"):
        make_link(Cfg())


async def test_run_command_list_without_shell_string_with_one(tmp_path: Path) -> None:
    # A list is argv as is: "$X" stays literal; a string goes through /bin/sh.
    out = tmp_path / "out"
    argv = [sys.executable, "-c",
            f"import os, sys; open({str(out)!r}, 'w').write(sys.argv[1] + os.environ['X'])",
            "$X"]
    assert await run_command(argv, {"X": "1"}, 10.0) == 0
    assert out.read_text() == "$X1"
    assert await run_command(f'printf "%s" "$X" > {out}; exit 4', {"X": "2"}, 10.0) == 4
    assert out.read_text() == "2"
    with pytest.raises(OSError):
        await run_command([str(tmp_path / "no-such-program")], {}, 10.0)
    with pytest.raises(TimeoutError):
        await run_command("sleep 30", {}, 0.1)


async def test_socket_link_keeps_the_health_line_of_a_client_that_resets(
        tmp_path: Path) -> None:
    # Audit reproducer: with a task assigned, every connection is sent it at once; a
    # robot that writes its health and closes without reading resets the connection,
    # and a StreamReader raised the reset before returning the line it had buffered:
    # the health was lost and the robot timed out to FAULTY.
    path = tmp_path / "r.sock"
    link = SocketLink(path, health_timeout=30.0)
    health = HealthLog()
    await link.start(health)
    link.assign("f2", 1, {})
    clients = 200

    def write_and_leave() -> None:
        for _ in range(clients):
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                s.connect(str(path))
                s.sendall(b'{"health": "ok"}\n')
                # Closed without reading: the assignment sent to us resets the link.

    try:
        # A thread, so the clients race the daemon's loop as separate programs do.
        await asyncio.to_thread(write_and_leave)

        async def all_seen() -> None:
            while link.counters["health"] < clients:
                await asyncio.sleep(0.01)

        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(all_seen(), 3.0)
        assert link.counters["health"] == clients
        assert health.values == [Health.OK] * clients
    finally:
        await link.close()
