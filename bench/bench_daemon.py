"""CPU and memory of one idle daemon at 10 Hz heartbeats (goal < 1% of a core,
< 60 MB RSS).

Runs the paper swarm as real `swarmd start` processes on loopback multicast (random
port) and measures robot 1 (udp() timing: ACTIVE, heartbeating at 10 Hz, hearing its
neighbours' 10 Hz heartbeats and the standbys' 2 Hz ones) from /proc for `--duration`
seconds after READY. `--alone` runs robot 1 without its swarm: it then also warns about
its silent neighbours at 10 Hz (a busier case than idle). `--auth` picks how the swarm
signs: `per-robot` (the default, as configs/paper.yaml: keys made for the run), `shared`
or `none`. `--failover` kills robot 2 (SIGKILL) as the measurement starts and measures
robot 1 (a watcher of f2: it suspects, warns, sees the takeover) and robot 6 (the standby
that claims and takes f2 over) through the failover and after it.

    python bench/bench_daemon.py [--duration 10] [--alone | --failover]
                                 [--auth per-robot|shared|none]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd.identity import private_key_path, write_identity  # noqa: E402
from swarmd.keys import generate_key  # noqa: E402

AUTH = {"per-robot": "auth: {mode: per-robot, keys_dir: keys}",
        "shared": "auth: {mode: shared, key_file: swarm.key}", "none": "auth: none"}


def swarm_file(tmp: Path, auth: str) -> Path:
    """configs/paper.yaml in `tmp`, signed as `auth` says, with its keys made there."""
    text = (ROOT / "configs" / "paper.yaml").read_text()
    lines = [AUTH[auth] if line.startswith("auth:") else line for line in text.splitlines()]
    if auth == "per-robot":
        for robot in range(1, 7):
            write_identity(tmp / "keys", robot)
    elif auth == "shared":
        generate_key(tmp / "swarm.key")
    path = tmp / "paper.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    utime, stime = int(fields[11]), int(fields[12])  # fields 14 and 15 of proc(5)
    return (utime + stime) / os.sysconf("SC_CLK_TCK")


def status_kb(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="seconds measured")
    ap.add_argument("--alone", action="store_true", help="robot 1 without its swarm")
    ap.add_argument("--failover", action="store_true",
                    help="kill robot 2 as the measurement starts; measure robots 1 and 6")
    ap.add_argument("--auth", choices=sorted(AUTH), default="per-robot",
                    help="how the swarm signs (default per-robot)")
    args = ap.parse_args()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if k != "NOTIFY_SOCKET"}
    with tempfile.TemporaryDirectory() as tmp:
        swarm = swarm_file(Path(tmp), args.auth)

        def launch(robot: int) -> subprocess.Popen[str]:
            cfg = Path(tmp) / f"robot{robot}.yaml"
            identity = (f"identity_file: {private_key_path(Path(tmp) / 'keys', robot)}\n"
                        if args.auth == "per-robot" else "")
            cfg.write_text(f"robot: {robot}\nswarm: {swarm}\n"
                           f"transport: {{kind: udp, port: {port}}}\n"
                           f"state_dir: {tmp}/state{robot}\n" + identity)
            return subprocess.Popen([sys.executable, "-m", "swarmd.cli", "start", "--config",
                                     str(cfg)], stdout=subprocess.PIPE, text=True, env=env,
                                    cwd=ROOT)

        others = [] if args.alone else [launch(r) for r in (2, 3, 4, 5, 6)]
        standby = None if args.alone else others[-1]
        proc = launch(1)
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                if json.loads(line)["msg"] == "ready":
                    break
            else:
                print("daemon exited before READY", file=sys.stderr)
                return 1
            # Keep reading stdout so no pipe ever fills (the daemons log their events).
            for p in (proc, *others):
                out = p.stdout
                assert out is not None
                threading.Thread(target=out.read, daemon=True).start()
            t0, c0 = time.monotonic(), cpu_seconds(proc.pid)
            s0 = cpu_seconds(standby.pid) if standby is not None else 0.0
            if args.failover:
                others[0].kill()  # robot 2: a crash, nothing said
            time.sleep(args.duration)
            t1, c1 = time.monotonic(), cpu_seconds(proc.pid)
            s1 = cpu_seconds(standby.pid) if standby is not None else 0.0
            rss = status_kb(proc.pid, "VmRSS") / 1024
            hwm = status_kb(proc.pid, "VmHWM") / 1024
        finally:
            for p in (proc, *others):
                p.send_signal(signal.SIGTERM)
            for p in (proc, *others):
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
    cpu = 100.0 * (c1 - c0) / (t1 - t0)
    what = ("alone (warning at 10 Hz)" if args.alone else "in the paper swarm") + \
        (", robot 2 crashing as the measurement starts" if args.failover else "") + \
        f", auth {args.auth}"
    print(f"daemon of robot 1 {what}, 10 Hz heartbeats, {t1 - t0:.1f} s: "
          f"CPU {cpu:.2f}% of one core (goal < 1%), RSS {rss:.1f} MB, "
          f"peak RSS {hwm:.1f} MB (goal < 60 MB)")
    standby_cpu = 100.0 * (s1 - s0) / (t1 - t0)
    if args.failover:
        print(f"daemon of robot 6, the standby taking f2 over: CPU {standby_cpu:.2f}% of one core")
    print(json.dumps({"cpu_percent": round(cpu, 3), "standby_cpu_percent": round(standby_cpu, 3),
                      "rss_mb": round(rss, 1),
                      "peak_rss_mb": round(hwm, 1), "seconds": round(t1 - t0, 2),
                      "auth": args.auth}))
    return 0 if cpu < 1.0 and hwm < 60 else 2


if __name__ == "__main__":
    sys.exit(main())
