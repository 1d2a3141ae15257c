"""`swarmd start` as a real process: JSON logs, SIGHUP reload, SIGTERM -> LEAVE, exit 0."""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

import pytest
from swarms import unsigned_paper

from swarmd.core import wire
from swarmd.core.events import EVENTS
from swarmd.transport.addresses import DEFAULT_GROUP

PAPER = Path(__file__).resolve().parent.parent / "configs" / "paper.yaml"
GROUP = DEFAULT_GROUP


def listener(port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    s.bind((GROUP, port))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                 socket.inet_aton(GROUP) + socket.inet_aton("127.0.0.1"))
    s.setblocking(False)
    return s


def lines_of(stream: IO[str]) -> queue.Queue[str]:
    q: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        for line in stream:
            q.put(line)

    threading.Thread(target=pump, daemon=True).start()
    return q


def wait_line(q: queue.Queue[str], seen: list[dict[str, Any]], msg: str,
              timeout: float = 10.0) -> dict[str, Any]:
    end = time.monotonic() + timeout
    while True:
        try:
            line = q.get(timeout=max(0.01, end - time.monotonic()))
        except queue.Empty:
            raise AssertionError(f"no log line {msg!r} within {timeout} s; got {seen}") from None
        record: dict[str, Any] = json.loads(line)  # every stdout line is one JSON object
        seen.append(record)
        if record["msg"] == msg:
            return record


def start(config: Path) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    return subprocess.Popen(
        [sys.executable, "-m", "swarmd.cli", "start", "--config", str(config)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


@pytest.mark.slow
def test_start_logs_json_reloads_and_leaves_on_sigterm(tmp_path: Path, udp_port: int) -> None:
    port = udp_port
    config = tmp_path / "robot.yaml"
    events = tmp_path / "events.jsonl"
    config.write_text(
        f"robot: 1\nswarm: {unsigned_paper(tmp_path)}\ntransport: {{kind: udp, port: {port}}}\n"
        f"state_dir: {tmp_path / 'state'}\nevent_log: {events}\nhandover_on_stop: true\n")
    sock = listener(port)
    proc = start(config)
    try:
        assert proc.stdout is not None
        q = lines_of(proc.stdout)
        seen: list[dict[str, Any]] = []
        ready = wait_line(q, seen, "ready")
        assert ready["level"] == "info" and isinstance(ready["ts"], float)
        up = [r for r in seen if r.get("msg") == "channel: transport_up"]
        assert up and up[0]["channel"] == "transport_up" and up[0]["fields"]["port"] == port
        proc.send_signal(signal.SIGHUP)
        reloaded = wait_line(q, seen, "SIGHUP: config reloaded")
        assert reloaded["restart_needed_for"] == [] and reloaded["keys"] == 0  # unsigned
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        wait_line(q, seen, "stopped", timeout=2)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    leaves = []
    while True:
        try:
            data = sock.recv(2048)
        except BlockingIOError:
            break
        frame = wire.decode(data)
        if frame.sender == 1 and isinstance(frame.msg, wire.Leave):
            leaves.append(frame.msg)
    sock.close()
    assert leaves == [wire.Leave(function=1, epoch=0, reason=wire.LeaveReason.SHUTDOWN)]
    records = [json.loads(line) for line in events.read_text().splitlines()]
    names = [r["event"] for r in records]
    assert names[0] == "started"
    # Only DESIGN's names reach the event log; channel conditions go to the JSON log.
    assert set(names) <= set(EVENTS), names
    for r in records:
        assert set(EVENTS[r["event"]].contract()) <= r.keys(), r
    assert names[-2:] == ["leave", "stopped"]
    assert all(abs(r["t"] - time.time()) < 60 for r in records)  # Unix time in `start`


def test_start_bad_config_exits_2_naming_file_and_field(tmp_path: Path) -> None:
    config = tmp_path / "robot.yaml"
    config.write_text(f"robot: 9\nswarm: {PAPER}\nstate_dir: {tmp_path}\n")
    proc = start(config)
    out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 2
    errors = [json.loads(line) for line in out.splitlines()]
    assert errors and all(e["level"] == "error" for e in errors)
    assert any("robot.yaml" in e["msg"] and "robot 9" in e["msg"] for e in errors)
