"""CPU cost of the `ros2` robot link per robot (docs/ros2.md).

One daemon (robot 1 of the paper's swarm, alone on a run's own UDP port) runs for
`--seconds` with the `none` link, then with the `ros2` link while a robot stack in
another process publishes its health on /diagnostics twice a second. Each daemon runs in
a child process that reports its own CPU time (every thread: the loop and rclpy's
executor) from `ready` to the end, so the difference is what the link costs: its rclpy
node, the health subscription, the goal re-published every second and the swarm's
statuses on /diagnostics once a second. Also how long the link took to start.

    python bench/bench_ros2.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"


async def _child(config: Path, seconds: float) -> dict[str, float]:
    from swarmd.config import load_robot
    from swarmd.daemon.daemon import run_daemon

    cfg = load_robot(config)
    stop = asyncio.Event()
    marks: dict[str, float] = {"t_start": time.monotonic()}

    def ready(_daemon: Any) -> None:
        marks["ready_s"] = time.monotonic() - marks["t_start"]
        marks["cpu0"] = time.process_time()
        asyncio.get_running_loop().call_later(seconds, stop.set)

    await run_daemon(cfg, stop_event=stop, on_ready=ready)
    marks["cpu_s"] = time.process_time() - marks["cpu0"]
    return {"ready_s": marks["ready_s"], "cpu_percent": 100 * marks["cpu_s"] / seconds}


def _stack(domain: int, seconds: float) -> None:
    from sim.realtime.ros2_robot import RobotStack
    from swarmd.config.robot import Ros2LinkConfig

    cfg = Ros2LinkConfig(kind="ros2", domain_id=domain, namespace="/swarmd/paper/robot1")

    async def run() -> None:
        stack = RobotStack(1, cfg, fly=lambda f, g: None, stop=lambda a: None)
        await asyncio.to_thread(stack.start, asyncio.get_running_loop())
        await asyncio.sleep(seconds)
        await asyncio.to_thread(stack.stop)

    asyncio.run(run())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--child", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--stack", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(asyncio.run(_child(args.child, args.seconds))))
        return 0
    if args.stack is not None:
        _stack(args.stack, args.seconds)
        return 0
    from sim.realtime.ports import PortLease
    from sim.realtime.robotfiles import sign_for_run, write_robot_file
    from sim.realtime.ros2_robot import DomainLease

    run_dir = Path(tempfile.mkdtemp(prefix="swarmd-bench-ros2-"))
    swarm, identities = sign_for_run(run_dir, PAPER)
    lease = DomainLease()
    results: dict[str, dict[str, float]] = {}
    try:
        for link in ("none", "ros2"):
            # The daemon's own multicast port, held until it ended: a port probed free
            # and closed again could go to another run's robots meanwhile, which this
            # daemon would then hear (sim/realtime/ports.py).
            port_lease = PortLease()
            config = write_robot_file(run_dir / link, swarm, 1, group="239.255.77.7",
                                      port=port_lease.port, identity_file=identities[1],
                                      link=lease.link_doc(1) if link == "ros2" else None)
            stack = None
            if link == "ros2":
                stack = subprocess.Popen([sys.executable, __file__, "--stack",
                                          str(lease.domain_id), "--seconds",
                                          str(args.seconds + 10)])
            try:
                done = subprocess.run([sys.executable, __file__, "--child", str(config),
                                       "--seconds", str(args.seconds)], capture_output=True,
                                      text=True, timeout=args.seconds + 60, check=True)
            finally:
                port_lease.release()
                if stack is not None:
                    stack.kill()
                    stack.wait()
            results[link] = json.loads(done.stdout.strip().splitlines()[-1])
    finally:
        lease.release()
    cost = results["ros2"]["cpu_percent"] - results["none"]["cpu_percent"]
    print(f"one daemon for {args.seconds:g} s (robot 1 of configs/paper.yaml, alone):")
    for link, r in results.items():
        print(f"  link {link:5s}: {r['cpu_percent']:.2f} % of one core, ready after "
              f"{r['ready_s']:.2f} s")
    print(f"ros2 link: +{cost:.2f} % of one core per robot")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
