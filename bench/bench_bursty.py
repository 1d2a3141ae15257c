"""Detection on a bursty radio, virtual time: the paper swarm (configs/paper.yaml) at its
timing preset, with no fault on a lossy channel and with one crash.

    python bench/bench_bursty.py                 # 3 seeds x 600 s a pattern, 10 crashes each
    python bench/bench_bursty.py --quick         # 1 seed x 120 s, 3 crashes (about a minute)
    python bench/bench_bursty.py --auth shared   # none | shared | per-robot (the default)

Per loss pattern (`--loss-model burst`, Gilbert-Elliott per directed link: 30 % loss in
bursts of 8 frames, 40 % in bursts of 4, and 20 % independent losses), one line per
seed: false takeovers, alerts and false suspicions (`suspect` of a healthy robot) over
the run with no fault. Then robot 2 crashes `--crash-at` seconds in (after the watchers
have measured the link a while), on a clean channel and on each pattern: the median and
worst time from the crash to the takeover of f2 over the seeds, and how many crashes
were taken over at all (DESIGN "Detection": a belief per link).
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim.shared.faults import parse_fault
from sim.shared.summary import summarize
from sim.virtual.simulator import Channel, VirtualSwarm, run_virtual
from swarmd.config import load_swarm

ROOT = Path(__file__).resolve().parent.parent
PATTERNS = {"30% bursts of 8": (0.3, "burst", 8.0), "40% bursts of 4": (0.4, "burst", 4.0),
            "20% independent": (0.2, "bernoulli", 4.0)}


@dataclass(frozen=True)
class Swarm:
    plan: Any
    params: Any
    key: bytes | None


def swarm(path: Path) -> Swarm:
    cfg = load_swarm(path)
    return Swarm(cfg.to_plan(), cfg.params(), cfg.key())


def watched(plan: Any, robot: int) -> list[str]:
    """The slots `robot` judges the silence of: those its slot watches (an active) or
    those it covers (a standby's own ears)."""
    own = plan.robots[robot].function
    if own is not None:
        return list(plan.watched(own))
    return [f for f in plan.functions if robot in plan.covered_by(f)]


def quiet_run(s: Swarm, pattern: tuple[float, str, float], seconds: float, seed: int,
              auth: str) -> dict[str, Any]:
    """One run with no fault: what the channel alone made the swarm do, and the patience
    each watcher ended with for each active neighbour (DESIGN "Detection")."""
    loss, model, burst = pattern
    swarm = VirtualSwarm(s.plan, s.params, duration=seconds, seed=seed,
                         keys=(s.key,) if s.key else (), auth=auth,
                         channel=Channel(loss=loss, loss_model=model, burst_len=burst))
    result = swarm.run()
    summary = summarize(result.events, [], s.plan, s.params, loss=loss, duration=seconds,
                        mode="virtual", extra_violations=result.violations)
    holder = {p.function: r for r, p in s.plan.robots.items() if p.function is not None}
    waits = [robot.node.patience(holder[g]) for r, robot in swarm.robots.items()
             if robot.node is not None and hasattr(robot.node, "patience")
             for g in watched(s.plan, r)]
    return {"false_takeovers": len(summary.false_takeovers),
            "alerts": sum(1 for e in result.events if e["event"] == "alert"),
            "false_suspicions": summary.false_suspicions,
            "violations": len(summary.violations),
            "frames": result.frames_sent,
            "patience": (min(waits), max(waits)) if waits else None}


def crash_run(s: Swarm, pattern: tuple[float, str, float], at: float, seed: int,
              auth: str) -> float | None:
    """Seconds from robot 2's crash to the takeover of f2 (None: never)."""
    loss, model, burst = pattern
    fault = parse_fault(f"crash:2@{at}")
    result = run_virtual(s.plan, s.params, duration=at + 15.0, faults=[fault], loss=loss,
                         seed=seed, keys=(s.key,) if s.key else (), auth=auth,
                         loss_model=model, burst_len=burst)
    for e in result.events:
        if e["event"] == "takeover" and e["function"] == "f2" and e["t"] >= at:
            return float(e["t"]) - at
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds of the runs with no fault")
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--crashes", type=int, default=10, help="seeds of the crash runs")
    ap.add_argument("--crash-at", type=float, default=60.0)
    ap.add_argument("--auth", default="per-robot", choices=("none", "shared", "per-robot"))
    ap.add_argument("--swarm", type=Path, default=ROOT / "configs" / "paper.yaml")
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.seconds, args.crashes = 1, 120.0, 3
    s = swarm(args.swarm)
    started = time.monotonic()
    print(f"{args.swarm.name}, auth {args.auth}, {args.seconds:g} s with no fault")
    for name, pattern in PATTERNS.items():
        for seed in range(1, args.seeds + 1):
            r = quiet_run(s, pattern, args.seconds, seed, args.auth)
            wait = r["patience"]
            print(f"  {name:<16} seed {seed}: false takeovers {r['false_takeovers']:>3}, "
                  f"alerts {r['alerts']:>3}, false suspicions {r['false_suspicions']:>5}, "
                  f"violations {r['violations']}, frames {r['frames']}"
                  + (f", patience {wait[0]:.2f}-{wait[1]:.2f} s" if wait else ""),
                  flush=True)
    if args.crashes:
        crashes(s, args.crashes, args.crash_at, args.auth)
    print(f"wall time {time.monotonic() - started:.0f} s")


def crashes(s: Swarm, seeds: int, at: float, auth: str) -> None:
    print(f"robot 2 crashes {at:g} s in; seeds 1..{seeds}")
    for name, pattern in {"clean": (0.0, "bernoulli", 4.0), **PATTERNS}.items():
        got = [crash_run(s, pattern, at, seed, auth) for seed in range(1, seeds + 1)]
        done = sorted(x for x in got if x is not None)
        if done:
            print(f"  {name:<16}: takeover median {statistics.median(done):.3f} s, "
                  f"max {done[-1]:.3f} s, taken over {len(done)}/{len(got)}", flush=True)
        else:
            print(f"  {name:<16}: no crash taken over (0/{len(got)})", flush=True)


if __name__ == "__main__":
    main()
