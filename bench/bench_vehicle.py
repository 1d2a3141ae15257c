"""What a ground station measures of `swarmd sim vehicle` (one real vehicle process per
flavour, a point mass, loopback UDP; a pymavlink client as system 255):

1. params: PARAM_SET of the cruise speed and the return altitude (PX4 MPC_XY_CRUISE,
   RTL_RETURN_ALT; ArduPilot WPNAV_SPEED, RTL_ALT), the echoed PARAM_VALUE and a
   PARAM_REQUEST_READ read-back; the round trip of each.
2. rates: the rate a client asks for (SET_MESSAGE_INTERVAL ATTITUDE 25 Hz and
   GLOBAL_POSITION_INT 2 Hz; ArduPilot also REQUEST_DATA_STREAM EXTRA1 4 Hz) against the
   rate that arrives, from arrival times over `--seconds`; GET_MESSAGE_INTERVAL's answer;
   then GLOBAL_POSITION_INT off (-1) and the count that still arrives.

    python bench/bench_vehicle.py [--seconds 5] [--flavours px4,ardupilot]
"""

from __future__ import annotations

import argparse
import re
import signal
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from pymavlink import mavutil

ROOT = Path(__file__).resolve().parent.parent


def start_vehicle(flavour: str) -> tuple[subprocess.Popen[str], int]:
    """A vehicle process on `--port 0`, and the port the kernel gave it, read from its
    connect line. A port probed free here and handed to it could be taken by another
    process before the vehicle bound it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarmd.cli", "sim", "vehicle", "--autopilot", flavour,
         "--port", "0", "--gcs-port", "0", "--no-physics"], cwd=ROOT,
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    # A vehicle silent for 30 s is killed, which ends the read below.
    watchdog = threading.Timer(30.0, proc.kill)
    watchdog.start()
    try:
        for line in proc.stdout:
            found = re.search(r"udpout://127\.0\.0\.1:(\d+)", line)
            if found:
                return proc, int(found.group(1))
    finally:
        watchdog.cancel()
    proc.wait()
    raise RuntimeError(f"the {flavour} vehicle ended (exit {proc.returncode}) before it "
                       "named its port")


class Client:
    def __init__(self, port: int) -> None:
        self.link = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255,
                                               source_component=190)
        self.mav = self.link.mav

    def wait(self, kind: str, timeout: float = 5.0, **match: Any) -> Any:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.mav.heartbeat_send(6, 8, 0, 0, 4)
            m = self.link.recv_match(type=kind, blocking=True, timeout=0.2)
            if m is not None and all(getattr(m, k) == v for k, v in match.items()):
                return m
        raise TimeoutError(f"no {kind} {match} within {timeout} s")

    def arrivals(self, kinds: list[str], seconds: float) -> dict[str, list[float]]:
        times: dict[str, list[float]] = {k: [] for k in kinds}
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = self.link.recv_match(type=kinds, blocking=True, timeout=0.1)
            if m is not None:
                times[m.get_type()].append(time.monotonic())
        return times


def hz(stamps: list[float]) -> float:
    return 0.0 if len(stamps) < 2 else (len(stamps) - 1) / (stamps[-1] - stamps[0])


def params(c: Client, flavour: str) -> None:
    table = {"px4": [("MPC_XY_CRUISE", 3.0), ("RTL_RETURN_ALT", 25.0)],
             "ardupilot": [("WPNAV_SPEED", 300.0), ("RTL_ALT", 2500)]}[flavour]
    for name, value in table:
        kind = 6 if isinstance(value, int) else 9
        wire = float(value)
        if flavour == "px4" and kind == 6:
            wire = struct.unpack("<f", struct.pack("<i", value))[0]
        t0 = time.monotonic()
        c.mav.param_set_send(1, 1, name.encode(), wire, kind)
        echo = c.wait("PARAM_VALUE", param_id=name)
        t1 = time.monotonic()
        c.mav.param_request_read_send(1, 1, name.encode(), -1)
        read = c.wait("PARAM_VALUE", param_id=name)
        t2 = time.monotonic()
        print(f"  {name:<15} set {value:>7} -> echo {echo.param_value:g} "
              f"({1000 * (t1 - t0):.1f} ms), read back {read.param_value:g} "
              f"({1000 * (t2 - t1):.1f} ms)")


def command(c: Client, cmd: int, *p: float) -> int:
    c.mav.command_long_send(1, 1, cmd, 0, *p, *([0.0] * (7 - len(p))))
    return int(c.wait("COMMAND_ACK", command=cmd).result)


def rates(c: Client, flavour: str, seconds: float) -> None:
    kinds = ["ATTITUDE", "GLOBAL_POSITION_INT"]
    before = c.arrivals(kinds, seconds)
    print(f"  default: ATTITUDE {hz(before['ATTITUDE']):.2f} Hz, GLOBAL_POSITION_INT "
          f"{hz(before['GLOBAL_POSITION_INT']):.2f} Hz")
    r1, r2 = command(c, 511, 30, 40000), command(c, 511, 33, 500000)
    got = c.arrivals(kinds, seconds)
    print(f"  asked ATTITUDE 25 Hz (result {r1}): {hz(got['ATTITUDE']):.2f} Hz; "
          f"GLOBAL_POSITION_INT 2 Hz (result {r2}): {hz(got['GLOBAL_POSITION_INT']):.2f} Hz")
    command(c, 510, 33)
    interval = c.wait("MESSAGE_INTERVAL", message_id=33)
    print(f"  GET_MESSAGE_INTERVAL GLOBAL_POSITION_INT: {interval.interval_us} us")
    command(c, 511, 33, -1)
    off = c.arrivals(["GLOBAL_POSITION_INT"], seconds)
    print(f"  GLOBAL_POSITION_INT off: {len(off['GLOBAL_POSITION_INT'])} in {seconds:g} s")
    if flavour == "ardupilot":
        command(c, 511, 30, 0)  # ATTITUDE back to its group's rate
        c.mav.request_data_stream_send(1, 1, 10, 4, 1)
        got = c.arrivals(["ATTITUDE"], seconds)
        c.mav.param_request_read_send(1, 1, b"SR0_EXTRA1", -1)
        sr0 = c.wait("PARAM_VALUE", param_id="SR0_EXTRA1").param_value
        print(f"  REQUEST_DATA_STREAM EXTRA1 4 Hz: ATTITUDE {hz(got['ATTITUDE']):.2f} Hz, "
              f"SR0_EXTRA1 {sr0:g}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--flavours", default="px4,ardupilot")
    args = ap.parse_args()
    for flavour in args.flavours.split(","):
        proc, port = start_vehicle(flavour)
        try:
            c = Client(port)
            c.wait("HEARTBEAT", 15.0)
            print(f"{flavour}:")
            params(c, flavour)
            rates(c, flavour, args.seconds)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(15)


if __name__ == "__main__":
    main()
