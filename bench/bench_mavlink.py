"""Benchmarks of the MAVLink robot link against the simulated autopilot (loopback UDP).

1. detect: a craft holds a slot; a motor fails; time until the daemon's link reports
   FAULTY from the autopilot's MAVLink telemetry (SYS_STATUS motor bit, EMERGENCY), per
   flavour, over `--runs` runs.
2. cpu: N links (each with its own simulated autopilot, all in this process) flying a
   slot for `--seconds`: the CPU time of each link's I/O thread (from
   /proc/self/task/<tid>/stat), i.e. the link's cost per robot on a companion computer,
   apart from the simulated physics.
3. substitute: the paper's swarm flown through MAVLink (`swarmd sim --link mavlink`,
   one process per robot, each daemon talking to its simulated autopilot), a motor of
   robot 2 failing at 5 s: the time from the failure to robot 2's `leave` (noticed
   through MAVLink health), to standby 6's `takeover` of f2, and to robot 6 within
   0.5 m of f2's slot (from its trajectory file), per flavour.

    python bench/bench_mavlink.py [--parts detect,cpu,substitute] [--runs 3]
        [--robots 1,5] [--seconds 10]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.physics.autopilot import SimMavlinkLink  # noqa: E402
from sim.physics.link import QuadLink  # noqa: E402
from sim.physics.render import trajectory_files  # noqa: E402
from sim.physics.robot import load_trajectory  # noqa: E402
from sim.realtime.orchestrator import run_realtime_async  # noqa: E402
from sim.shared.faults import parse_fault  # noqa: E402
from swarmd.config import load_swarm  # noqa: E402
from swarmd.core.roles import Health  # noqa: E402


async def until(cond: Callable[[], object], timeout: float) -> bool:
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            return False
        await asyncio.sleep(0.01)
    return True


async def fly(link: SimMavlinkLink, healths: list[Health], slot: tuple[float, float, float],
              timeout: float = 60.0) -> bool:
    await link.start(healths.append)
    if not await until(lambda: healths and healths[-1] is Health.OK, 15.0):
        return False
    link.assign("f1", 1, {"kind": "slot", "position": list(slot)})

    def there() -> bool:
        p = link.quad.robot.position
        return bool(sum((p[i] - slot[i]) ** 2 for i in range(3)) ** 0.5 < 0.5)

    return await until(there, timeout)


async def detect_once(flavour: str) -> float | None:
    healths: list[Health] = []
    # Port 0 (the default): the autopilot binds the port the kernel gives it and the link
    # talks to that one; a port probed free before could be taken by another process.
    link = SimMavlinkLink(QuadLink(1, (0.0, 0.0, 0.0)), flavour)  # type: ignore[arg-type]
    try:
        if not await fly(link, healths, (1.0, 1.0, 1.5)):
            return None
        t = time.monotonic()
        link.fail_motor(1)
        if not await until(lambda: healths[-1] is Health.FAULTY, 10.0):
            return None
        return time.monotonic() - t
    finally:
        await link.close()


def thread_cpu(tid: int) -> float:
    fields = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / ticks  # utime + stime


async def cpu(n: int, seconds: float) -> tuple[float, float, float]:
    links = [SimMavlinkLink(QuadLink(i + 1, (1.5 * i, -5.0, 0.0)), "px4")
             for i in range(n)]
    healths: list[list[Health]] = [[] for _ in links]
    try:
        oks = await asyncio.gather(*(fly(lk, h, (1.5 * i, 0.0, 1.5))
                                     for i, (lk, h) in enumerate(zip(links, healths,
                                                                      strict=True))))
        tids = [lk.link._thread.native_id for lk in links if lk.link._thread is not None]
        c0 = [thread_cpu(t) for t in tids if t is not None]
        p0, w0 = time.process_time(), time.monotonic()
        await asyncio.sleep(seconds)
        wall = time.monotonic() - w0
        c1 = [thread_cpu(t) for t in tids if t is not None]
        proc = (time.process_time() - p0) / wall
        per = [(b - a) / wall for a, b in zip(c0, c1, strict=True)]
        assert all(oks), "a craft did not reach its slot"
        return statistics.mean(per), max(per), proc
    finally:
        for lk in links:
            await lk.close()


PAPER = ROOT / "configs" / "paper.yaml"
FAIL_AT = 5.0


async def substitute_once(flavour: str, duration: float = 16.0,
                          ) -> tuple[float | None, float | None, float | None]:
    """(failure -> leave of 2, -> takeover of f2 by 6, -> 6 within 0.5 m of f2's slot), s;
    None for what did not happen within the run."""
    import tempfile

    slot = load_swarm(PAPER).function_spec("f2")["position"]
    with tempfile.TemporaryDirectory(prefix="bench-mavlink-") as tmp:
        result = await run_realtime_async(
            PAPER, duration=duration, faults=[parse_fault(f"motor:2@{FAIL_AT:g}")],
            report_dir=Path(tmp), physics=True, link=f"mavlink-{flavour}")
        trajs = {tr.robot: tr for tr in (load_trajectory(p, t0=result.t0)
                                         for p in trajectory_files(Path(tmp)))}
    fault = next((e["t"] for e in result.events if e["event"] == "fault"), FAIL_AT)
    leave = next((e["t"] - fault for e in result.events
                  if e["event"] == "leave" and e["robot"] == 2), None)
    take = next((e["t"] - fault for e in result.events
                 if e["event"] == "takeover" and e["robot"] == 6), None)
    six = trajs.get(6)
    there = None if six is None else next(
        (t - fault for t, p in zip(six.t, six.pos, strict=True)
         if t > fault and sum((p[i] - slot[i]) ** 2 for i in range(3)) ** 0.5 < 0.5), None)
    return leave, take, there


def _fmt(xs: list[float | None]) -> str:
    ok = [x for x in xs if x is not None]
    text = ", ".join(f"{x:.3f}" if x is not None else "-" for x in xs)
    return f"[{text}]" + (f" median {statistics.median(ok):.3f}" if ok else "")


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", default="detect,cpu,substitute")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--robots", default="1,5")
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    parts = args.parts.split(",")
    if "detect" in parts:
        print("motor failure -> FAULTY through MAVLink (s):")
        for flavour in ("px4", "ardupilot"):
            got = [await detect_once(flavour) for _ in range(args.runs)]
            ok = [g for g in got if g is not None]
            text = ", ".join(f"{g:.3f}" for g in ok)
            print(f"  {flavour:9s} runs={len(got)} ok={len(ok)} [{text}]"
                  + (f" median {statistics.median(ok):.3f}" if ok else ""))
    if "cpu" in parts:
        print(f"link I/O thread CPU per robot over {args.seconds:g} s (fraction of one core):")
        for n in (int(x) for x in args.robots.split(",")):
            mean, worst, proc = await cpu(n, args.seconds)
            print(f"  {n:3d} robots: link mean {mean:.4f} max {worst:.4f}; whole process "
                  f"(physics + autopilots + links) {proc:.3f}")


    if "substitute" in parts:
        runs = max(1, min(args.runs, 2))  # 20 s of a 6-process swarm each
        print(f"motor failure -> substitute within 0.5 m of the slot over MAVLink (s; "
              f"paper swarm, motor:2@{FAIL_AT:g}, {runs} run(s) per flavour):")
        for flavour in ("px4", "ardupilot"):
            subs = [await substitute_once(flavour) for _ in range(runs)]
            print(f"  {flavour:9s} leave (MAVLink health) {_fmt([g[0] for g in subs])}; "
                  f"takeover {_fmt([g[1] for g in subs])}; in the slot "
                  f"{_fmt([g[2] for g in subs])}")


if __name__ == "__main__":
    asyncio.run(main())
