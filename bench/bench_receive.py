"""The Python cost of one frame heard: `Node.receive` in a hot loop, per robot.

The paper swarm runs on virtual time (every node ticks at its deadline, every frame sent
goes to every other node as bytes, nothing lost), and the wall time of each `receive` of
robot 1 (active) and robot 6 (the standby) is taken. It prints, per robot, the frames it
heard and the mean cost of a `receive` over the fastest chunk of `--chunk` frames: on a
machine shared with other jobs the fastest chunk is the one least disturbed, so two
trees compare by it (`--tree`), where bench_daemon.py's CPU share moves with the load.
It measures the node alone: no socket, no event loop, warm caches (a daemon woken by a
frame pays more per frame, bench_daemon.py).

    python bench/bench_receive.py [--auth none|shared] [--seconds 300] [--chunk 100]
                                   [--tree PATH]
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
WATCHED = (1, 6)
"""Robot 1 (active, watches f2) and robot 6 (the standby), as bench_daemon.py."""


def run(root: Path, auth: str, seconds: float, chunk: int) -> dict[int, tuple[int, float]]:
    """robot -> (frames heard, us per `receive` over its fastest chunk)."""
    sys.path.insert(0, str(root))
    plan_of: Any = importlib.import_module("swarmd.config").load_swarm
    node_mod: Any = importlib.import_module("swarmd.core.node")
    broadcast: Any = importlib.import_module("swarmd.core.actions").Broadcast
    cfg = plan_of(root / "configs" / "paper.yaml")
    plan, params = cfg.to_plan(), cfg.params()
    keys = (bytes(32),) if auth == "shared" else ()
    nodes = {r: node_mod.Node(r, plan, params, 0.0, keys=keys, seq_start=1000 * r)
             for r in plan.robots}
    due = {r: n.next_deadline() for r, n in nodes.items()}
    times: dict[int, list[float]] = {r: [] for r in WATCHED}
    now, clock = 0.0, time.perf_counter
    while now < seconds:
        r = min(due, key=lambda k: due[k] if due[k] is not None else float("inf"))
        now = max(now, due[r])
        queue = [(r, a.frame) for a in nodes[r].tick(now) if isinstance(a, broadcast)]
        due[r] = nodes[r].next_deadline()
        while queue:
            src, frame = queue.pop()
            for d, node in nodes.items():
                if d == src:
                    continue
                t = clock()
                out = node.receive(frame, now)
                if d in times:
                    times[d].append(clock() - t)
                due[d] = node.next_deadline()
                queue.extend((d, a.frame) for a in out if isinstance(a, broadcast))
    return {r: (len(ts), fastest(ts, chunk)) for r, ts in times.items()}


def fastest(ts: list[float], chunk: int) -> float:
    """The mean of the fastest chunk of `chunk` consecutive frames, in us."""
    means = [sum(ts[i:i + chunk]) / chunk for i in range(0, len(ts) - chunk + 1, chunk)]
    return 1e6 * min(means) if means else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--auth", choices=("none", "shared"), default="none",
                    help="unsigned (default) or a shared swarm key; per robot needs keys "
                         "made for the run: bench_daemon.py measures it")
    ap.add_argument("--seconds", type=float, default=300.0, help="virtual seconds run")
    ap.add_argument("--chunk", type=int, default=100, help="frames per chunk")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the checkout measured")
    args = ap.parse_args()
    if args.chunk < 1 or args.seconds <= 0:
        ap.error("--chunk and --seconds must be positive")
    for robot, (frames, us) in run(args.tree.resolve(), args.auth, args.seconds,
                                   args.chunk).items():
        print(f"robot {robot}: {frames} frames heard, {us:.2f} us per receive "
              f"(fastest chunk of {args.chunk}, auth {args.auth})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
