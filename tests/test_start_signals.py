"""SIGHUP and SIGTERM at any moment of `swarmd start`'s life, start-up included
(swarmd/base/signals.py). Real processes: the seam is the process's signal disposition.

Before: a SIGHUP before the event loop's handlers were installed ran the default action
and the daemon died of it (a reload under load killed a starting robot)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from swarms import ROOT, unsigned_paper

pytestmark = pytest.mark.slow

# The process's own first steps, as `swarmd start` runs them: the CLI module (the very
# first swarmd code that runs), then signals at chosen moments (while the CLI is still
# importing, while the config is read, while the daemon starts, once it runs).
SCRIPT = r"""
import os, signal, sys, threading, time
sys.argv = ["swarmd", "start", "--config", sys.argv[1], "--log-format", "json"]
import swarmd.cli  # the first swarmd code: from here on a signal is no death
os.kill(os.getpid(), signal.SIGHUP)  # a reload before the config is read
def burst():
    for _ in range(100):  # reloads all through the start-up, 10 ms apart
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.01)
threading.Thread(target=burst, daemon=True).start()
swarmd.cli.main()
"""


def _robot(tmp_path: Path, port: int) -> Path:
    swarm = unsigned_paper(tmp_path)
    robot = tmp_path / "robot1.yaml"
    robot.write_text(f"robot: 1\nswarm: {swarm}\nstate_dir: {tmp_path / 'state'}\n"
                     f"transport: {{kind: udp, port: {port}}}\n")
    return robot


def _wait_for(proc: subprocess.Popen[str], text: str, timeout: float) -> str:
    """stdout lines until one contains `text` (or the process ends)."""
    seen = []
    end = time.monotonic() + timeout
    assert proc.stdout is not None
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line)
        if text in line:
            return "".join(seen)
    raise AssertionError(f"no {text!r} in output; rc={proc.poll()}:\n{''.join(seen)}")


def test_reloads_while_starting_kill_no_daemon(tmp_path: Path, udp_port: int) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", SCRIPT, str(_robot(tmp_path, udp_port))],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env, cwd=ROOT)
    try:
        out = _wait_for(proc, '"ready"', 60.0)
        assert "signals received while starting" in out
        time.sleep(1.2)  # the burst ends; each one reloads
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_stop_while_starting_stops_cleanly_once_started(tmp_path: Path,
                                                         udp_port: int) -> None:
    """SIGTERM before the daemon's own handlers: recorded, then a clean stop (status 0,
    the state written), not a death by signal."""
    script = SCRIPT.replace('os.kill(os.getpid(), signal.SIGHUP)  # a reload',
                            'os.kill(os.getpid(), signal.SIGTERM)  # a stop')
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    robot = _robot(tmp_path, udp_port)
    proc = subprocess.run([sys.executable, "-c", script, str(robot)], capture_output=True,
                          text=True, env=env, cwd=ROOT, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "SIGTERM" in proc.stdout and (tmp_path / "state").exists()
