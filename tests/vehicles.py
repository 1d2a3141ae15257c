"""`swarmd sim vehicle` as a process of its own, for the tests that fly it with a ground
station or an SDK (tests/test_gcs_vehicle.py, test_mavproxy_vehicle.py,
test_mavsdk_vehicle.py, test_mavlink_autopilot.py).

The vehicle is started on `--port 0` and the port it got is read from its connect line.
A port probed free here and handed to it would be free only until the probe's socket
closed: another test's process could bind it before the vehicle did, and the vehicle
would exit with 'cannot listen'. The kernel's pick at the vehicle's own bind leaves no
such gap.
"""

from __future__ import annotations

import os
import re
import select
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CONNECT = re.compile(r"udpout://127\.0\.0\.1:(\d+)")
"""The MAVSDK URL in the vehicle's connect line, with the port it listens on."""


@dataclass
class Vehicle:
    proc: subprocess.Popen[str]
    port: int
    """The UDP port on 127.0.0.1 it listens on."""
    head: str
    """What it had printed when its connect line came, that line included:
    `proc.communicate()` returns only the rest."""


def vehicle_args(flavour: str, port: int, *options: str) -> list[str]:
    """The command line of a vehicle on `port` (0: the kernel's pick)."""
    return [sys.executable, "-m", "swarmd.cli", "sim", "vehicle", "--autopilot", flavour,
            "--port", str(port), *options]


def start_vehicle(flavour: str, *options: str, timeout: float = 30.0) -> Vehicle:
    """Start a vehicle on a port the kernel picks (`options`: more of its options) and
    wait, at most `timeout` s, for its connect line, which it prints once it listens.
    A vehicle that ends or stays silent instead is stopped and fails the test."""
    proc = subprocess.Popen(vehicle_args(flavour, 0, *options), cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        head = _read_until_connect(proc, timeout)
    except BaseException:
        proc.kill()
        _, err = proc.communicate()
        print(f"the vehicle's stderr (exit {proc.returncode}):\n{err[-2000:]}",
              file=sys.stderr)
        raise
    found = CONNECT.search(head)
    assert found is not None
    return Vehicle(proc, int(found.group(1)), head)


def _read_until_connect(proc: subprocess.Popen[str], timeout: float) -> str:
    """The vehicle's output up to and with its connect line (whole lines only, so that
    the port is never cut short). Read from the pipe's file descriptor, not through
    `proc.stdout`: what that buffers ahead would sit there unseen by `select`, and
    `proc.communicate()` still reads the rest after it."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    data = b""
    end = time.monotonic() + timeout
    while CONNECT.search(data[:data.rfind(b"\n") + 1].decode(errors="replace")) is None:
        ready, _, _ = select.select([fd], [], [], max(end - time.monotonic(), 0.0))
        if not ready:
            raise AssertionError(f"the vehicle named no port in {timeout:g} s: {data!r}")
        chunk = os.read(fd, 4096)
        if not chunk:
            raise AssertionError(f"the vehicle ended before it named its port: {data!r}")
        data += chunk
    return data.decode()
