"""How late the daemon's timers run while a local process floods the socket robot link
(swarmd/link/socket.py: one input budget per link per loop turn, reads resumed a few a
turn, at most `MAX_CONNECTIONS` connections).

A `SocketLink` on this process's event loop, and a 10 Hz timer standing for the
daemon's heartbeat; another process opens `--connections` connections to the link's
socket and writes `--kb` kB of short bad lines on each, as fast as the link takes them.
Printed: the timer's lateness (p50 / p99 / max, ms) during the flood, the lines and
bytes handled, the connections refused, and how long the flood took to be read.

    python bench/bench_link_flood.py [--connections 1,100,400] [--kb 300]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sim.shared.summary import percentile as pct
from swarmd.link.socket import SocketLink

FLOODER = r"""
import socket, sys, threading
path, n, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
blob = (b"x" * 20 + b"\n") * (size // 21)
def one():
    try:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(path)
        s.sendall(blob)
        s.shutdown(socket.SHUT_WR)
        s.recv(1)
        s.close()
    except OSError:
        pass  # refused (closed unread) or reset
threads = [threading.Thread(target=one) for _ in range(n)]
for t in threads: t.start()
for t in threads: t.join()
"""


async def run(connections: int, kb: int, period: float = 0.1) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "robot.sock"
        link = SocketLink(path, health_timeout=3600.0)
        await link.start(lambda health: None)
        loop = asyncio.get_running_loop()
        late: list[float] = []
        due = [loop.time() + period]

        def beat() -> None:
            late.append(loop.time() - due[0])
            due[0] += period
            loop.call_at(due[0], beat)

        handle = loop.call_at(due[0], beat)
        start = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-c", FLOODER, str(path), str(connections),
                                 str(kb * 1000)])
        while proc.poll() is None:
            await asyncio.sleep(0.05)
        took = time.monotonic() - start
        handle.cancel()
        await link.close()
    return {
        "connections": connections, "kb_each": kb,
        "timer_late_p50_ms": round(1000 * statistics.median(late), 2) if late else None,
        "timer_late_p99_ms": round(1000 * pct(late, 99), 2) if late else None,
        "timer_late_max_ms": round(1000 * max(late), 2) if late else None,
        "bad_lines": link.counters["bad_lines"],
        "bytes_read": link.counters.get("bytes_read"),
        "refused": link.counters.get("refused"),
        "flood_read_s": round(took, 2),
    }


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connections", default="1,100,400")
    ap.add_argument("--kb", type=int, default=300)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    for n in [int(x) for x in args.connections.split(",") if x]:
        row = await run(n, args.kb)
        rows.append(row)
        if not args.json:
            print("socket link flood:", json.dumps(row))
    if args.json:
        print(json.dumps({"cpus": os.cpu_count(), "load": os.getloadavg()[0], "rows": rows},
                         indent=2))


if __name__ == "__main__":
    del socket  # the flooder is another process; nothing here opens a socket itself
    asyncio.run(main())
