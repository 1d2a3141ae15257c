"""Protocol-core benchmark on the virtual-time simulator.

Prints, for the `udp()` preset on the paper swarm and on the 100-robot grid:
- crash -> takeover latency p50 / p99 / max over many seeds, at 0% and 20% loss;
- false takeovers per 10^5 robot-seconds at 20% loss (no faults injected);
- frame sizes (signed and unsigned);
- simulator speed (simulated robot-seconds per wall second, one core).

Goals: p99 <= 1.0 s at 0% loss and <= 1.5 s at 20%; zero false takeovers;
>= 1,000 robot-seconds per wall second per core at 100 robots.

    python bench/bench_core.py            # CI-sized: ~1 minute
    python bench/bench_core.py --seeds 2000 --robot-seconds 1e6   # thorough
    python bench/bench_core.py --auth none   # unsigned (default: per-robot, as shipped)
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.shared.faults import Fault, FaultKind  # noqa: E402
from sim.virtual.simulator import run_virtual  # noqa: E402
from swarmd.config import load_swarm  # noqa: E402
from swarmd.core import wire  # noqa: E402
from swarmd.core.params import Params  # noqa: E402
from swarmd.core.plan import SwarmPlan  # noqa: E402


def percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


AUTH = "per-robot"
"""The authentication mode of every run (`--auth`): the shipped default unless told."""


def takeover_latencies(plan: SwarmPlan, params: Params, *, seeds: int, loss: float
                       ) -> tuple[list[float], int, int]:
    """Crash one random ACTIVE robot (that a standby covers) per seed at a random time;
    return the latencies, the runs without a takeover, and total violations."""
    actives = [r for r, p in plan.robots.items()
               if p.function is not None and len(plan.covered_by(p.function)) > 1]
    lat: list[float] = []
    missing = violations = 0
    for seed in range(seeds):
        rng = random.Random(seed)
        victim = rng.choice(actives)
        at = rng.uniform(3.0, 4.0)
        res = run_virtual(plan, params, duration=at + 5.0, loss=loss, seed=seed,
                          faults=[Fault(FaultKind.CRASH, at, (victim,))], auth=AUTH)
        violations += len(res.violations)
        t = next((e["t"] for e in res.events
                  if e["event"] == "takeover" and e.get("replaced") == victim), None)
        if t is None:
            missing += 1
        else:
            lat.append(t - at)
    return lat, missing, violations


def false_takeovers(plan: SwarmPlan, params: Params, *, robot_seconds: float, loss: float
                    ) -> tuple[int, float, float]:
    """Fault-free runs under loss: takeovers are all false. Returns (count,
    robot-seconds simulated, robot-seconds per wall second)."""
    n = len(plan.robots)
    duration = 200.0
    runs = max(1, round(robot_seconds / (duration * n)))
    count = 0
    t0 = time.perf_counter()
    for seed in range(runs):
        res = run_virtual(plan, params, duration=duration, loss=loss, seed=10_000 + seed,
                          auth=AUTH)
        count += sum(1 for e in res.events if e["event"] == "takeover")
    wall = time.perf_counter() - t0
    simulated = runs * duration * n
    return count, simulated, simulated / wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200, help="crash runs per case")
    ap.add_argument("--robot-seconds", type=float, default=1e5,
                    help="fault-free robot-seconds per swarm for the false-takeover rate")
    ap.add_argument("--auth", choices=("per-robot", "shared", "none"), default="per-robot",
                    help="authentication mode of the runs (default: per-robot, as shipped)")
    args = ap.parse_args()
    global AUTH
    AUTH = args.auth
    console = Console(highlight=False)
    swarms = {"paper (6)": ROOT / "configs/paper.yaml", "grid (100)": ROOT / "configs/grid100.yaml"}

    lat_table = Table(title=f"crash -> takeover latency, udp() preset, auth {AUTH}",
                      title_justify="left")
    for col in ("swarm", "loss", "runs", "p50 s", "p99 s", "max s", "no takeover",
                "violations"):
        lat_table.add_column(col, justify="right")
    ft_table = Table(title="false takeovers at 20% loss, no faults", title_justify="left")
    for col in ("swarm", "robot-seconds", "takeovers", "per 10^5 robot-s",
                "sim speed robot-s/wall-s"):
        ft_table.add_column(col, justify="right")
    for name, path in swarms.items():
        cfg = load_swarm(path)
        plan, params = cfg.to_plan(), cfg.params()
        seeds = args.seeds if len(plan.robots) < 50 else max(20, args.seeds // 2)
        for loss in (0.0, 0.2):
            lat, missing, viol = takeover_latencies(plan, params, seeds=seeds, loss=loss)
            lat_table.add_row(name, f"{loss:.0%}", str(seeds),
                              f"{statistics.median(lat):.3f}", f"{percentile(lat, 0.99):.3f}",
                              f"{max(lat):.3f}", str(missing), str(viol))
        count, simulated, speed = false_takeovers(plan, params,
                                                  robot_seconds=args.robot_seconds, loss=0.2)
        ft_table.add_row(name, f"{simulated:,.0f}", str(count),
                         f"{count / simulated * 1e5:.2f}", f"{speed:,.0f}")
    console.print(lat_table)
    console.print(ft_table)

    sizes = Table(title="frame sizes (bytes)", title_justify="left")
    for col in ("message", "unsigned", "signed (HMAC-SHA256/8)"):
        sizes.add_column(col, justify="right")
    key = bytes(32)
    msgs: list[tuple[str, wire.Message]] = [
        ("HEARTBEAT", wire.Heartbeat(1, 1, 1, 0)), ("WARN", wire.Warn(2, 2, 1)),
        ("CLAIM", wire.Claim(2, 2, 2)), ("LEAVE", wire.Leave(2, 1, 0)),
    ]
    for label, msg in msgs:
        frame = wire.Frame(1543, 1, wire.seq_seed(time.time()), msg)
        sizes.add_row(label, str(len(wire.encode(frame))), str(len(wire.encode(frame, key))))
    console.print(sizes)


if __name__ == "__main__":
    main()
