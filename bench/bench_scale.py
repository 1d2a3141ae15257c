"""Large swarms: one daemon's receive cost at 100, 1,000 and 5,000 robots, a 1,000-robot
virtual run's speed, and a 100-robot swarm on one 802.15.4 channel at `radio()`.

    python bench/bench_scale.py [--sizes 100,1000,5000] [--seconds 2] [--loss-runs 3]

1. Receive cost: one node (an active robot in the middle of a grid swarm,
   configs/make_grid.py, `udp()` preset, signed frames) is fed the heartbeats of the
   whole swarm, as a daemon on UDP multicast receives them, over `--seconds` of virtual
   time. Printed: the frames per second it receives, how many it processes (the rest
   is dropped by slot before the HMAC: DESIGN section 2, "What a robot hears"), CPU
   per frame (process time) and the share of one core that costs; the same with the
   early drop disabled.
2. A 1,000-robot grid in `sim.virtual` for 10 s with a crash at 5 s: robot-seconds per
   wall-second and the crash-to-takeover time.
3. configs/grid100-radio.yaml: its channel budget on 802.15.4 (signed and unsigned),
   the largest swarm of the paper's shape that fits below 30% airtime at `radio()`,
   false takeovers in `--loss-runs` virtual runs of 120 s at 20% loss, and the virtual
   crash-to-takeover median (bench/bench_radio.py measures it over emulated radios).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from grids import grid_swarm  # bench/grids.py (scripts run with bench/ on sys.path)

from sim.shared.faults import parse_fault
from sim.virtual.simulator import run_virtual
from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.node import Node
from swarmd.core.params import Params, udp
from swarmd.core.plan import SwarmPlan
from swarmd.services.budget import channel_budget, largest_swarm

ROOT = Path(__file__).resolve().parent.parent
KEY = b"b" * 32


def swarm_traffic(plan: SwarmPlan, params: Params, seconds: float) -> list[tuple[float, bytes]]:
    """Every robot's signed heartbeats for `seconds`, phases spread, in time order."""
    out: list[tuple[float, bytes]] = []
    n = len(plan.robots)
    for i, (rid, robot) in enumerate(sorted(plan.robots.items())):
        active = robot.function is not None
        period = params.heartbeat_interval if active else params.standby_heartbeat_interval
        slot = plan.slot(robot.function) if robot.function is not None else 0
        msg = wire.Heartbeat(slot, 0, 1 if active else 2, 0)
        t, seq = period * i / n, 1
        while t < seconds:
            out.append((t, wire.encode(wire.Frame(plan.swarm_id, rid, seq, msg), KEY)))
            t, seq = t + period, seq + 1
    out.sort(key=lambda x: x[0])
    return out


def receive_cost(plan: SwarmPlan, params: Params, robot: int,
                 traffic: list[tuple[float, bytes]]) -> tuple[float, int, int]:
    """(CPU seconds, frames processed, frames dropped as irrelevant) for one node."""
    node = Node(robot, plan, params, 0.0, keys=[KEY])
    deadline = node.next_deadline()
    start = time.process_time()
    for t, data in traffic:
        if deadline is not None and t >= deadline:
            node.tick(t)
            deadline = node.next_deadline()
        if node.receive(data, t):
            # A heartbeat only moves deadlines later: an early tick is harmless, so
            # only a frame that made the node act re-reads its deadline.
            deadline = node.next_deadline()
    cpu = time.process_time() - start
    snap = node.snapshot()
    return cpu, snap.frames_in, node.drops["irrelevant"]


def bench_receive(sizes: list[int], seconds: float, directory: Path) -> None:
    params = udp()
    print(f"one daemon's receive cost, fed the whole swarm's signed heartbeats for "
          f"{seconds:g} s (udp() preset: actives at {1 / params.heartbeat_interval:g} Hz, "
          f"standbys at {1 / params.standby_heartbeat_interval:g} Hz)")
    print(f"  {'robots':>7} {'frames/s in':>12} {'processed/s':>12} {'us/frame':>9} "
          f"{'core share':>11} {'us/frame, no early drop':>24} {'core share':>11}")
    for n in sizes:
        cfg = load_swarm(grid_swarm(n, directory))
        plan = cfg.to_plan()
        actives = sorted(r for r, p in plan.robots.items() if p.function is not None)
        robot = actives[len(actives) // 2]
        traffic = swarm_traffic(plan, params, seconds)
        cpu, processed, irrelevant = receive_cost(plan, params, robot, traffic)
        saved = Node._irrelevant
        Node._irrelevant = lambda *a, **k: False  # type: ignore[method-assign]
        try:
            cpu_all, _, _ = receive_cost(plan, params, robot, traffic)
        finally:
            Node._irrelevant = saved  # type: ignore[method-assign]
        rate = len(traffic) / seconds
        per, per_all = cpu / len(traffic), cpu_all / len(traffic)
        print(f"  {n:>7} {rate:>12.0f} {processed / seconds:>12.0f} {per * 1e6:>9.1f} "
              f"{per * rate:>10.1%} {per_all * 1e6:>24.1f} {per_all * rate:>10.1%}"
              f"   ({irrelevant} of {len(traffic)} dropped before the HMAC)")


def bench_virtual_1000(directory: Path) -> None:
    cfg = load_swarm(grid_swarm(1000, directory))
    plan, params = cfg.to_plan(), cfg.params()
    started = time.monotonic()
    res = run_virtual(plan, params, duration=10.0, faults=[parse_fault("crash:450@5")])
    wall = time.monotonic() - started
    took = [e["t"] - 5.0 for e in res.events if e["event"] == "takeover"]
    outcome = f"takeover {took[0]:.3f} s after the crash" if took else "NO takeover"
    print(f"1,000-robot grid, sim.virtual, 10 s with crash:450@5: {wall:.1f} s wall, "
          f"{res.robot_seconds / wall:.0f} robot-seconds per wall-second; {outcome}; "
          f"violations {len(res.violations)}")


def bench_radio_swarm(loss_runs: int) -> None:
    path = ROOT / "configs" / "grid100-radio.yaml"
    cfg = load_swarm(path)
    plan, params = cfg.to_plan(), cfg.params()
    print(f"{path.name}: {len(plan.robots)} robots at radio() (heartbeat "
          f"{params.heartbeat_interval:g} s, standby heartbeat "
          f"{params.standby_heartbeat_interval:g} s, t_max {params.t_max:g} s)")
    for signed in (True, False):
        b = channel_budget(plan, params, medium="802.15.4", signed=signed)
        print(f"  802.15.4, {'signed' if signed else 'unsigned'} {b.heartbeat_bytes} B "
              f"heartbeats: {b.frames_per_s:.1f} frames/s, {b.airtime_share:.1%} airtime, "
              f"{b.peak_airtime_share:.1%} during a failover")
    n = largest_swarm(params, medium="802.15.4", signed=True)
    print(f"  largest swarm of the paper's shape (2/3 active) below 30% at radio(), "
          f"signed: {n} robots")
    started = time.monotonic()
    false_takeovers = suspicions = claims = 0
    for seed in range(loss_runs):
        res = run_virtual(plan, params, duration=120.0, loss=0.2, seed=seed, keys=[KEY])
        false_takeovers += sum(1 for e in res.events if e["event"] == "takeover")
        suspicions += sum(1 for e in res.events if e["event"] == "suspect")
        claims += sum(1 for e in res.events if e["event"] == "claim")
    print(f"  20% loss, no fault, {loss_runs} x 120 s virtual: false takeovers "
          f"{false_takeovers}, claims {claims}, suspicions {suspicions} "
          f"({time.monotonic() - started:.0f} s wall)")
    latencies = []
    for seed in range(12):
        victim = 1 + (seed * 13) % 60
        res = run_virtual(plan, params, duration=20.0, seed=seed,
                          faults=[parse_fault(f"crash:{victim}@12")])
        latencies += [e["t"] - 12.0 for e in res.events if e["event"] == "takeover"]
    print(f"  crash -> takeover, 12 virtual runs (2 ms channel latency): median "
          f"{statistics.median(latencies):.2f} s, max {max(latencies):.2f} s; over "
          f"emulated 802.15.4 radios: python bench/bench_radio.py")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--sizes", default="100,1000,5000")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--loss-runs", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bench_receive([int(s) for s in args.sizes.split(",")], args.seconds, Path(tmp))
        bench_virtual_1000(Path(tmp))
    bench_radio_swarm(args.loss_runs)


if __name__ == "__main__":
    main()
