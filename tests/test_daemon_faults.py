"""The daemon against bad input and as a library: start-up faults name their config
field, SIGHUP faults keep the daemon and what it had, a cancelled `run_daemon` cleans
up, robot commands never write into the JSON log, drops are reported.

In-process daemons over UDP multicast on loopback (a random port each), waiting on
conditions with deadlines; no real-process test here (tests/test_start.py has those).
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import sys
from pathlib import Path
from typing import Any

import pytest
from swarms import paper_text, unsigned_paper
from test_runtime import GROUP, launch, robot_cfg, runtime_of, wait_until
from test_start import listener

from swarmd.base.eventlog import EventLog, EventLogError
from swarmd.config import load_robot
from swarmd.core import wire
from swarmd.daemon.daemon import EXIT_FAILURE, Daemon, run_daemon
from swarmd.link.exec import ExecLink, run_command
from swarmd.link.socket import SocketLink, SocketLinkError
from swarmd.services import runtime as runtime_mod
from swarmd.services.state import StateError, StateFile, StateWriteError, load, state_path
from swarmd.transport.base import TransportError
from swarmd.transport.udp import UdpTransport


def _messages(caplog: pytest.LogCaptureFixture, msg: str) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.getMessage() == msg]


def write_robot(tmp: Path, robot: int, port: int, extra: str = "",
                swarm: Path | None = None) -> Path:
    path = tmp / f"robot{robot}.yaml"
    if swarm is None:
        swarm = tmp / "paper.yaml"
        if not swarm.exists():
            unsigned_paper(tmp)
    path.write_text(f"robot: {robot}\nswarm: {swarm}\ntransport: {{kind: udp, port: {port}}}\n"
                    f"state_dir: {tmp / 'state'}\n{extra}")
    return path


# ------------------------------------------------------------------ state file
def test_state_file_of_binary_garbage_is_a_state_error(tmp_path: Path) -> None:
    # It was a UnicodeDecodeError that escaped load(): the daemon failed to start
    # instead of setting the file aside and starting fresh (docs/daemon.md).
    path = tmp_path / "s.json"
    path.write_bytes(b"\xff\x00garbage")
    with pytest.raises(StateError, match="not UTF-8"):
        load(path, robot=1, swarm=1)


def test_state_write_error_names_the_file(tmp_path: Path) -> None:
    (tmp_path / "dir").write_text("a file where the state directory should be")
    sf = StateFile(tmp_path / "dir" / "s.json", robot=1, swarm=1)
    with pytest.raises(StateWriteError, match=r"dir/s\.json: cannot write the state file"):
        sf.write_initial(None, 0)


async def test_daemon_starts_fresh_from_a_binary_state_file(tmp_path: Path, udp_port: int) -> None:
    cfg = robot_cfg(tmp_path, 1, udp_port)
    path = state_path(cfg.state_dir, 1543, 1)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"\xff\xfe\x00\x01")
    a = await launch(cfg)
    try:
        assert a.daemon is not None and a.daemon.state_errors == 1
        assert list(path.parent.glob("*.corrupt-*"))
    finally:
        assert await a.finish() == 0


# ------------------------------------------------------------------ start-up faults
@pytest.mark.parametrize(("extra", "field"), [
    ("event_log: {tmp}\n", "event_log"),                # a directory
    ("event_log: {tmp}/file/events.jsonl\n", "event_log"),  # under a regular file
    ("link: {{kind: socket, path: {tmp}/file/robot.sock}}\n", "robot socket"),
])
async def test_start_failure_names_the_field_and_sends_nothing(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, extra: str, field: str,
        udp_port: int) -> None:
    (tmp_path / "file").write_text("x")
    cfg = load_robot(write_robot(tmp_path, 1, udp_port, extra.format(tmp=tmp_path)))
    assert await asyncio.wait_for(run_daemon(cfg), 10.0) == EXIT_FAILURE
    [failed] = _messages(caplog, "daemon failed to start")
    assert field in failed.__dict__["error"] and str(tmp_path) in failed.__dict__["error"]
    # A daemon that never started sends no LEAVE into a closed channel (it did, and
    # logged a misleading "send_error: transport not open").
    assert not _messages(caplog, "channel: send_error")


async def test_state_dir_that_is_a_file_is_named_as_such(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int) -> None:
    (tmp_path / "state").write_text("x")
    cfg = load_robot(write_robot(tmp_path, 1, udp_port))
    assert await asyncio.wait_for(run_daemon(cfg), 10.0) == EXIT_FAILURE
    [failed] = _messages(caplog, "daemon failed to start")
    state = tmp_path / "state"
    assert failed.__dict__["error"] == f"state_dir {state}: exists and is not a directory"
    # Not blamed on the state file ("state file unusable; starting fresh" before).
    assert not _messages(caplog, "state file unusable; starting fresh")


async def test_udp_interface_not_on_this_host_names_the_field(udp_port: int) -> None:
    # TEST-NET-1 (RFC 5737) is on no interface here; the join fails before any send.
    transport = UdpTransport(interface="192.0.2.1", port=udp_port)
    with pytest.raises(TransportError, match=r"transport\.interface"):
        await transport.start(lambda data: None, lambda event: None)


async def test_socket_link_parent_that_cannot_be_made_is_a_link_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    link = SocketLink(tmp_path / "file" / "robot.sock")
    with pytest.raises(SocketLinkError, match="cannot listen on robot socket"):
        await link.start(lambda health: None)


# ------------------------------------------------------------------ SIGHUP faults
def test_event_log_reopen_failure_keeps_the_old_file(tmp_path: Path) -> None:
    log = EventLog(tmp_path / "a.jsonl")
    with pytest.raises(EventLogError, match="event_log"):
        log.reopen(tmp_path / "a.jsonl" / "b.jsonl")
    log.write({"event": "still here"})
    log.close()
    assert "still here" in (tmp_path / "a.jsonl").read_text()


async def test_sighup_with_an_unopenable_event_log_keeps_running_and_the_old_log(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int) -> None:
    port = udp_port
    events = tmp_path / "events.jsonl"
    path = write_robot(tmp_path, 1, port, f"event_log: {events}\n")
    daemon = Daemon(load_robot(path), config_path=path)
    await daemon.start()
    try:
        # The reload raised out of the signal handler (a traceback from the loop),
        # closed the old log first and skipped the rest of the reload.
        path.write_text(path.read_text().replace(str(events), str(events / "x.jsonl"))
                        + "handover_on_stop: false\n")
        daemon.reload()
        assert daemon.reload_errors == 1
        assert daemon.handover_on_stop is False  # the rest of the reload applied
        assert _messages(caplog, "SIGHUP: event log not reopened")
    finally:
        await daemon.stop()
    assert '"event":"stopped"' in events.read_text()  # nothing lost


async def test_sighup_restart_needed_compares_with_the_running_config(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int) -> None:
    caplog.set_level(logging.INFO)
    swarm = tmp_path / "swarm.yaml"
    swarm.write_text(paper_text())
    path = write_robot(tmp_path, 1, udp_port, swarm=swarm)
    daemon = Daemon(load_robot(path), config_path=path)
    await daemon.start()
    try:
        swarm.write_text(paper_text().replace("preset: udp", "preset: radio"))
        daemon.reload()
        swarm.write_text(paper_text())  # changed back: nothing to restart for
        daemon.reload()
        path.write_text(path.read_text().replace("robot: 1", "robot: 2"))
        daemon.reload()
    finally:
        await daemon.stop()
    wanted = [r.__dict__["restart_needed_for"]
              for r in _messages(caplog, "SIGHUP: config reloaded")]
    assert wanted == [["timing"], [], ["robot"]]


# ------------------------------------------------------------------ embedding
def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


async def test_embedded_swarm_takes_over_from_a_cancelled_daemon_which_cleans_up(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int) -> None:
    # As an outside user would (docs/daemon.md "Embedding"): load_robot + run_daemon
    # tasks in one loop, the paper swarm without robots 4 and 5.
    caplog.set_level(logging.INFO)
    port = udp_port
    events: list[dict[str, Any]] = []
    fds_before = _open_fds()
    tasks: dict[int, asyncio.Task[int]] = {}
    ready: dict[int, asyncio.Event] = {}
    for r in (1, 2, 3, 6):
        ready[r] = asyncio.Event()
        cfg = load_robot(write_robot(tmp_path, r, port))
        tasks[r] = asyncio.create_task(run_daemon(
            cfg, event_sink=events.append,
            on_ready=lambda d, ev=ready[r]: ev.set()))  # type: ignore[misc]
    await asyncio.wait_for(asyncio.gather(*(e.wait() for e in ready.values())), 10.0)
    sock = listener(port)
    try:
        tasks[2].cancel()
        with pytest.raises(asyncio.CancelledError):
            await asyncio.wait_for(tasks[2], 10.0)
        # Before the fix the cancelled daemon's timer kept heartbeating for ever:
        # the swarm never took over and its socket stayed open.
        await wait_until(lambda: any(e["event"] == "takeover" for e in events), 10.0,
                         "takeover of f2")
        takeover = next(e for e in events if e["event"] == "takeover")
        assert (takeover["robot"], takeover["function"], takeover["replaced"]) == (6, "f2", 2)
        from_two = []
        while True:
            try:
                frame = wire.decode(sock.recv(2048))
            except BlockingIOError:
                break
            if frame.sender == 2:
                from_two.append(frame.msg)
        # Cancelled = a crash to the swarm: no LEAVE, and silence after it.
        assert not any(isinstance(m, wire.Leave) for m in from_two)
    finally:
        sock.close()
        for t in tasks.values():
            t.cancel()
        await asyncio.gather(*tasks.values(), return_exceptions=True)
    two = [e["event"] for e in events if e["robot"] == 2]
    assert two[-1] == "stopped" and "leave" not in two
    assert len(_messages(caplog, "stopped")) == 4
    assert _open_fds() == fds_before  # every socket closed
    assert asyncio.all_tasks() == {asyncio.current_task()}


# ------------------------------------------------------------------ robot commands
async def test_command_output_goes_to_stderr_never_the_json_log(
        capfd: pytest.CaptureFixture[str]) -> None:
    status = await run_command("printf 'not json \\377\\n'; echo err >&2; exit 3", {}, 10.0)
    assert status == 3
    out, err = capfd.readouterr()
    assert out == ""  # stdout is the daemon's JSON log (journald)
    assert "not json" in err and "err" in err


async def test_exec_health_failure_is_logged_once_and_counted_each_time(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    link = ExecLink(on_assign="true", health_command=[str(tmp_path / "missing")],
                    health_interval=0.01)
    seen: list[object] = []
    await link.start(seen.append)
    try:
        await wait_until(lambda: link.counters["health_checks"] >= 5, 5.0, "health checks")
    finally:
        await link.close()
    assert link.counters["failures"] >= 5
    assert len(_messages(caplog, "robot link command cannot run")) == 1


async def test_exec_link_worker_survives_a_command_that_cannot_be_built() -> None:
    link = ExecLink(on_assign=["nul\0byte"], on_release=[sys.executable, "-c", "pass"])
    await link.start(lambda health: None)
    try:
        link.assign("f1", 1, {})
        link.release("f1")  # the worker must still be there for it
        await asyncio.wait_for(link.wait_idle(), 10.0)
    finally:
        await link.close()
    assert link.counters["runs"] == 2 and link.counters["failures"] == 1


# ------------------------------------------------------------------ hostile frames
async def test_a_stopping_daemon_reports_the_drops_since_its_last_report(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int) -> None:
    port = udp_port
    a = await launch(robot_cfg(tmp_path, 1, port))
    rt = runtime_of(a)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    try:
        await wait_until(lambda: rt.stats()["ticks"] > 1, 5.0, "first ticks")
        out.sendto(b"\x00" * 3, (GROUP, port))  # well inside the 10 s report interval
        await wait_until(lambda: rt.drop_counts().get("malformed", 0) == 1, 5.0, "the drop")
        assert not _messages(caplog, "dropped frames")
    finally:
        out.close()
        assert await a.finish() == 0
    (msg,) = _messages(caplog, "dropped frames")
    assert msg.__dict__["drops"] == {"malformed": 1}


async def test_dropped_frames_are_reported_by_reason(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int,
        monkeypatch: pytest.MonkeyPatch) -> None:
    port = udp_port
    monkeypatch.setattr(runtime_mod, "DROP_REPORT_S", 0.0)  # every tick (10 s in production)
    a = await launch(robot_cfg(tmp_path, 1, port))
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    other_swarm = wire.encode(wire.Frame(7, 2, 1, wire.Heartbeat(0, 0, 2, 0)))
    signed = wire.encode(wire.Frame(1543, 2, 1, wire.Heartbeat(0, 0, 2, 0)), bytes(32))
    try:
        for data in (b"\x00" * 3, other_swarm, signed, b"x" * 65000):
            out.sendto(data, (GROUP, port))

        def reported() -> dict[str, int]:
            got: dict[str, int] = {}
            for r in _messages(caplog, "dropped frames"):
                for k, v in r.__dict__["drops"].items():
                    got[k] = got.get(k, 0) + v
            return got

        await wait_until(lambda: sum(reported().values()) >= 4, 5.0, "drop report")
        # The 64 KiB datagram is cut to the receive buffer: its first byte says
        # version 7. Our own heartbeats echoed back ("own") are never reported.
        assert reported() == {"malformed": 1, "version": 1, "swarm": 1, "auth": 1}
    finally:
        out.close()
        assert await a.finish() == 0
