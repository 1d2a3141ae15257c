"""Benchmarks of the MuJoCo quadrotors.

1. single: physics real-time factor of one robot process: steps/s and RTF at 500 Hz
   physics + 100 Hz control (QuadRobot flying a slot), X2 and Crazyflie.
2. links: N robot processes (forkserver, mujoco preloaded), each running one QuadLink in
   real time (waking every 40 ms) while flying a slot, for S seconds: how late the
   wake-ups are (p50 / p99 / max) and the CPU the robots use. Largest N with p99 < 20 ms.
3. sim: the real `swarmd sim` with physics on grid swarms of N robots (configs/
   make_grid.py): daemons + physics in each process. Lateness of the physics wake-ups
   (from the stats lines of the robots' trajectory files), false suspicions, and whether
   every active robot holds its slot at the end.
4. e2e: the paper swarm, `crash:2@5` and `motor:2@5`: time from the fault to the
   takeover, and to robot 6 reaching f2's slot (within 0.5 m and 0.1 m).

    python bench/bench_physics.py [--parts single,links,sim,e2e] [--sizes 1,10,20,30,40,50]
        [--sim-sizes 10,20,30] [--seconds 5] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import multiprocessing
import os
import tempfile
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
from grids import grid_swarm  # bench/grids.py (scripts run with bench/ on sys.path)

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
LATE_OK_MS = 20.0
"""A robot process is "real time" when its p99 wake-up lateness stays below this."""


def pct(values: list[float], q: float) -> float:
    """Nearest-rank percentile (q in [0, 100])."""
    s = sorted(values)
    return s[min(len(s) - 1, max(0, math.ceil(q / 100 * len(s)) - 1))]


def table(rows: list[dict[str, Any]], title: str) -> None:
    print(f"\n{title}")
    if not rows:
        print("  (nothing)")
        return
    keys = list(rows[0])
    width = {k: max(len(k), *(len(str(r.get(k))) for r in rows)) for k in keys}
    print("  " + "  ".join(k.rjust(width[k]) for k in keys))
    for r in rows:
        print("  " + "  ".join(str(r.get(k)).rjust(width[k]) for k in keys))


# -- 1. one robot process -----------------------------------------------------------------


def bench_single(sim_seconds: float = 60.0) -> list[dict[str, Any]]:
    from sim.physics.model import PHYSICS_DT, crazyflie, x2
    from sim.physics.robot import QuadRobot

    rows = []
    for p in (x2(), crazyflie()):
        for flying in (True, False):
            r = QuadRobot(1, (0.0, 0.0, 0.0), p)
            if flying:
                r.assign("f1", {"kind": "slot", "position": [1.0, 1.0, 1.5]})
            t = time.perf_counter()
            r.step_until(sim_seconds)
            wall = time.perf_counter() - t
            rows.append({
                "craft": p.name,
                "state": "flying" if flying else "parked",
                "sim_s": sim_seconds,
                "wall_s": round(wall, 3),
                "steps_per_s": round(sim_seconds / PHYSICS_DT / wall),
                "rtf": round(sim_seconds / wall, 1),
                "us_per_sim_s": round(1e6 * wall / sim_seconds),
            })
    return rows


# -- 2. N QuadLink processes --------------------------------------------------------------


def _link_worker(rid: int, seconds: float, t_start: float, conn: Connection) -> None:
    from sim.physics.link import QuadLink

    async def run() -> dict[str, Any]:
        link = QuadLink(rid, (1.5 * rid, 0.0, 0.0))
        await asyncio.sleep(max(0.0, t_start - time.time()))  # everyone starts together
        cpu0 = time.process_time()
        await link.start(lambda h: None)
        link.assign("f", 1, {"kind": "slot", "position": [1.5 * rid, 0.0, 1.5]})
        await asyncio.sleep(seconds)
        # Measured before close(): it lands the craft, fast-forwarded (sim/physics/link.py).
        cpu, z = time.process_time() - cpu0, link.robot.position[2]
        await link.close()
        return {"late": list(link.lateness), "cpu": cpu, "z": z}

    conn.send(asyncio.run(run()))
    conn.close()


def bench_links(n: int, seconds: float) -> dict[str, Any]:
    ctx = multiprocessing.get_context("forkserver")
    # The same preload as `swarmd sim` with physics (sim.realtime): the forkserver is
    # one per process and keeps its first preload list, so preloading less here made
    # part 3's robots import the daemon themselves (20 robots ready in 4.7 s, not ~1 s).
    ctx.set_forkserver_preload(["sim.realtime.robot_proc", "sim.physics.link"])
    t0 = time.perf_counter()
    t_start = time.time() + 1.0 + 0.03 * n
    pipes, procs = [], []
    for rid in range(1, n + 1):
        r, w = ctx.Pipe(duplex=False)
        p = ctx.Process(target=_link_worker, args=(rid, seconds, t_start, w))
        p.start()
        w.close()
        pipes.append(r)
        procs.append(p)
    started = time.perf_counter() - t0
    results = [r.recv() for r in pipes]
    for p in procs:
        p.join(10)
    late = [x for res in results for x in res["late"][5:]]  # skip the first wakes
    cpu = sum(res["cpu"] for res in results)
    return {
        "robots": n,
        "spawn_s": round(started, 2),
        "wakes": len(late),
        "late_p50_ms": round(1000 * pct(late, 50), 2),
        "late_p99_ms": round(1000 * pct(late, 99), 2),
        "late_max_ms": round(1000 * max(late), 2),
        "cpu_cores": round(cpu / seconds, 2),
        "all_flying": all(res["z"] > 1.0 for res in results),
        "real_time": pct(late, 99) * 1000 < LATE_OK_MS,
    }


# -- 3. swarmd sim with physics -----------------------------------------------------------


async def bench_sim(n: int, seconds: float) -> dict[str, Any]:
    from sim.physics.link import read_stats
    from sim.physics.render import trajectory_files
    from sim.physics.robot import load_trajectory
    from sim.realtime.orchestrator import run_realtime_async
    from swarmd.config import load_swarm

    with tempfile.TemporaryDirectory() as tmp:
        swarm_path = grid_swarm(n, Path(tmp))
        swarm = load_swarm(swarm_path)
        report = Path(tmp) / "report"
        result = await run_realtime_async(swarm_path, duration=seconds, physics=True,
                                          live=False, report_dir=report)
        late: list[float] = []
        cpu = 0.0
        held = 0
        actives = 0
        for path in trajectory_files(report):
            stats = [s for s in read_stats(path) if s["w"] - result.t0 > 2.0]
            late += [s["late_p99_ms"] for s in stats]
            cpu += stats[-1]["cpu_s"] - stats[0]["cpu_s"] if len(stats) > 1 else 0.0
            tr = load_trajectory(path, t0=result.t0)
            fn = swarm.robot(tr.robot).holds
            if fn is not None:
                actives += 1
                pos = swarm.function_spec(fn)["position"]
                held += math.dist(tr.pos[-1], pos) < 0.1
    suspects = [e for e in result.events if e["event"] == "suspect"]
    p99 = max(late) if late else float("nan")
    return {
        "robots": n,
        "startup_s": round(result.startup_s, 2),
        "worst_2s_p99_late_ms": round(p99, 2),
        "robot_cpu_cores": round(cpu / max(1e-9, seconds - 4.0), 2),
        "false_suspicions": len(suspects),
        "slots_held": f"{held}/{actives}",
        "real_time": bool(late) and p99 < LATE_OK_MS and not suspects and held == actives,
        "problems": len(result.problems),
    }


# -- 4. crash to substitute in the slot ---------------------------------------------------


async def bench_e2e(fault: str, duration: float = 16.0) -> dict[str, Any]:
    from sim.physics.robot import load_trajectory
    from sim.realtime.orchestrator import run_realtime_async
    from sim.shared.faults import parse_fault
    from swarmd.config import load_swarm

    slot = np.array(load_swarm(PAPER).function_spec("f2")["position"])
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp)
        result = await run_realtime_async(PAPER, duration=duration, physics=True, live=False,
                                          faults=[parse_fault(fault)], report_dir=report)
        tr = load_trajectory(report / "realtime" / "state" / "6" / "traj-6.jsonl",
                             t0=result.t0)
    ev = result.events
    t_fault = next(e["t"] for e in ev if e["event"] == "fault")
    take = [e for e in ev if e["event"] == "takeover" and e["function"] == "f2"]
    d = np.linalg.norm(tr.pos - slot, axis=1)

    def reach(r: float) -> float | None:
        idx = np.nonzero((d < r) & (tr.t > t_fault))[0]
        return round(float(tr.t[idx[0]]) - t_fault, 2) if len(idx) else None

    taken = round(take[0]["t"] - t_fault, 3) if take else None
    near = reach(0.5)
    return {
        "fault": fault,
        "takeover_after_s": taken,
        "by": take[0]["robot"] if take else None,
        "in_slot_0.5m_after_s": near,
        "in_slot_0.1m_after_s": reach(0.1),
        "flight_to_0.5m_s": round(near - taken, 2) if near is not None and taken else None,
    }


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="single,links,sim,e2e")
    ap.add_argument("--sizes", default="1,10,20,30,40,50")
    ap.add_argument("--sim-sizes", default="10,20,30")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--json", action="store_true", help="also print one JSON document")
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    out: dict[str, Any] = {"cpus": os.cpu_count(), "loadavg": os.getloadavg()[0]}
    if "single" in parts:
        out["single"] = bench_single()
        table(out["single"], "1. one robot process (500 Hz physics, 100 Hz control)")
    if "links" in parts:
        rows = [bench_links(int(n), args.seconds) for n in args.sizes.split(",")]
        out["links"] = rows
        table(rows, f"2. N QuadLink processes in real time for {args.seconds:g} s "
                    f"(wake every 40 ms; real time = p99 < {LATE_OK_MS:g} ms)")
        ok = [r["robots"] for r in rows if r["real_time"]]
        print(f"  largest N in real time: {max(ok) if ok else 0}")
    if "sim" in parts:
        rows = [await bench_sim(int(n), args.seconds + 6.0)
                for n in args.sim_sizes.split(",")]
        out["sim"] = rows
        table(rows, "3. swarmd sim with physics (grid swarms, daemons + physics per process)")
        ok = [r["robots"] for r in rows if r["real_time"]]
        print(f"  largest swarm swarmd sim flies in real time: {max(ok) if ok else 0}")
    if "e2e" in parts:
        rows = [await bench_e2e(f) for f in ("crash:2@5", "motor:2@5")]
        out["e2e"] = rows
        table(rows, "4. paper swarm: fault on robot 2 -> robot 6 in f2's slot")
    out["loadavg_after"] = os.getloadavg()[0]
    print(f"\nload average (1 min) before/after: {out['loadavg']:.2f} / "
          f"{out['loadavg_after']:.2f} on {out['cpus']} CPUs")
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    asyncio.run(main())
