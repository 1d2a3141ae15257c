"""Signature checks under a flood of forged signed frames (DESIGN section 2, "Who can
still do what"; swarmd/base/verify_budget.py).

1. What one Ed25519 check costs on this machine (a good and a bad signature), and what
   the daemon's budget (`TOTAL_RATE` checks a second) costs at that price.
2. The paper swarm on real daemons (`swarmd sim --no-physics`, one process a robot,
   signed per robot as shipped), with a flooder on the channel sending forged anchors
   (heartbeats with a signature: the frames a receiver must check with Ed25519) in
   every robot's name, each with a fresh sequence number so no cheap check stops it,
   at `--rate` a second for `--flood` seconds. A passive listener times every real
   heartbeat (lateness = gap - period, its p50 / p99 / max), and the run's events say
   whether any healthy robot was suspected, taken over or fenced.

    python bench/bench_verify_flood.py [--rate 3000] [--flood 20] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import itertools
import json
import os
import random
import socket
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from sim.realtime.orchestrator import run_realtime_async
from sim.realtime.ports import PortLease
from sim.shared.invariants import check_events
from sim.shared.summary import lateness_figures
from sim.shared.summary import percentile as pct
from swarmd.base.identity import Ed25519Signer, Keyring, generate_identity
from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.auth import SIGNATURE_LEN
from swarmd.core.chain import LINK_LEN
from swarmd.core.roles import Role
from swarmd.transport.udp import UdpTransport

try:
    from swarmd.base.verify_budget import TOTAL_RATE
except ImportError:  # a tree from before the budget: measure it all the same
    TOTAL_RATE = 0.0

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
FORGED_SIG = bytes(SIGNATURE_LEN)
"""The flooder's signature: all zeros, so the listener tells its frames from the
robots' (the daemons check it as any other and find it bad)."""


def verify_cost(n: int = 2000) -> dict[str, Any]:
    priv, pub = generate_identity()
    ring = Keyring({1: pub})
    data = os.urandom(80)
    good = Ed25519Signer(1, priv).sign(data)
    out: dict[str, Any] = {}
    for name, sig in (("good", good), ("bad", FORGED_SIG)):
        t = time.perf_counter()
        for _ in range(n):
            ring.verify(1, data, sig)
        out[f"{name}_us"] = round((time.perf_counter() - t) / n * 1e6, 1)
    out["checks_per_s_one_core"] = round(1e6 / out["bad_us"])
    out["budget_checks_per_s"] = TOTAL_RATE
    out["budget_cpu_share"] = round(TOTAL_RATE * out["bad_us"] / 1e6, 3)
    return out


def forged_anchor(plan_swarm: int, sender: int, seq: int, slot: int) -> bytes:
    """An anchor as `sender` holding `slot` at epoch 0, with a made-up signature."""
    hb = wire.Heartbeat(slot, 0, int(Role.ACTIVE), 0, random.randrange(256),
                        os.urandom(LINK_LEN), anchor=False)

    class _Layout:  # lays the heartbeat out per robot; the signature is ours
        def sign(self, data: bytes) -> bytes:
            raise AssertionError

    body = wire.encode(wire.Frame(plan_swarm, sender, seq, hb), None, _Layout())  # type: ignore[arg-type]
    first = body[0] | 0x08  # signed: the 64 bytes after are its sender's signature
    return bytes((first,)) + body[1:] + FORGED_SIG


def flood(port: int, swarm_id: int, robots: list[int], rate: float, seconds: float,
          sent: list[int], window: list[float]) -> None:
    """Send forged anchors to the swarm's multicast group, `rate` a second, in bursts of
    10 ms (a thread; the frames are made beforehand, so sending is all it does)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    group = UdpTransport(port=port).group
    seq = wire.seq_seed(time.time())
    n = int(rate * seconds)
    frames = [forged_anchor(swarm_id, robots[i % len(robots)], seq + i,
                            robots[i % len(robots)] if robots[i % len(robots)] <= 4 else 0)
              for i in range(n)]
    start = time.monotonic()  # the loop's clock (asyncio: time.monotonic)
    window.append(start)
    burst = max(1, int(rate / 100))
    for i in range(0, n, burst):
        due = start + i / rate
        now = time.monotonic()
        if due > now:
            time.sleep(due - now)
        for frame in frames[i:i + burst]:
            try:
                sock.sendto(frame, (group, port))
                sent[0] += 1
            except OSError:
                pass
    window.append(time.monotonic())
    sock.close()


def _flood_process(port: int, swarm_id: int, robots: list[int], rate: float,
                   seconds: float) -> tuple[int, list[float]]:
    sent: list[int] = [0]
    window: list[float] = []
    flood(port, swarm_id, robots, rate, seconds, sent, window)
    return sent[0], window


class _Unchecked:
    """A `Verifier` that takes every signature: the listener only times heartbeats."""

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        return True


async def bench_flood(rate: float, flood_s: float, settle: float = 4.0) -> dict[str, Any]:
    # The run's multicast port, leased here rather than by the run, because the listener
    # and the flooder need it before the robots start. The lease holds it until the run
    # ended: a port probed free and closed again could go to another run meanwhile, whose
    # robots would then be flooded and timed too (sim/realtime/ports.py).
    with PortLease() as lease:
        return await _bench_flood(lease.port, rate, flood_s, settle)


async def _bench_flood(port: int, rate: float, flood_s: float,
                       settle: float) -> dict[str, Any]:
    load_before = os.getloadavg()[0]
    cfg = load_swarm(PAPER)
    params, plan = cfg.params(), cfg.to_plan()
    arrivals: dict[int, list[tuple[float, int]]] = {}
    loop = asyncio.get_running_loop()

    def on_frame(data: bytes) -> None:
        if data.endswith(FORGED_SIG):
            return  # the flood's own
        try:
            frame = wire.decode(data, (), _Unchecked())
        except wire.CodecError:
            return
        if isinstance(frame.msg, wire.Heartbeat):
            arrivals.setdefault(frame.sender, []).append((loop.time(), frame.msg.role))

    listener = UdpTransport(port=port)
    await listener.start(on_frame, lambda event: None)
    sent = [0]
    flood_window: list[float] = []

    async def flooder() -> None:
        # Its own process, so that the listener here times heartbeats undisturbed.
        await asyncio.sleep(settle)
        with concurrent.futures.ProcessPoolExecutor(1) as pool:
            got = await loop.run_in_executor(pool, _flood_process, port, plan.swarm_id,
                                             sorted(plan.robots), rate, flood_s)
        sent[0] = got[0]
        flood_window.extend(got[1])

    task = asyncio.create_task(flooder())
    with tempfile.TemporaryDirectory() as tmp:
        try:
            result = await run_realtime_async(PAPER, duration=settle + flood_s + 4.0,
                                              live=False, port=port,
                                              report_dir=Path(tmp) / "report")
        finally:
            await listener.close()
            task.cancel()
    late = []
    lo, hi = [*flood_window, float("inf"), float("inf")][:2]
    for ts in arrivals.values():
        for (a, _), (b, role) in itertools.pairwise(ts):
            if lo <= b <= hi:
                period = (params.heartbeat_interval if role == Role.ACTIVE
                          else params.standby_heartbeat_interval)
                late.append(b - a - period)
    checker = check_events(result.events, [], plan, params, loss=0.0,
                           duration=settle + flood_s + 4.0)
    named = {name: sum(1 for e in result.events if e["event"] == name)
             for name in ("suspect", "takeover", "fenced", "claim")}
    auth = sum(d.get("auth", 0) for d in result.drops.values()) \
        if isinstance(getattr(result, "drops", None), dict) else None
    return {
        "flood_rate_per_s": rate,
        "flood_s": flood_s,
        "forged_sent": sent[0],
        "forged_per_s_achieved": round(sent[0] / (hi - lo), 1) if len(flood_window) == 2
        else None,
        "heartbeats_timed": len(late),
        "lateness_p50_ms": round(1000 * statistics.median(late), 2) if late else None,
        "lateness_p99_ms": round(1000 * pct(late, 99), 2) if late else None,
        "lateness_max_ms": round(1000 * max(late), 2) if late else None,
        "suspicions": named["suspect"], "takeovers": named["takeover"],
        "fences": named["fenced"], "claims": named["claim"],
        "auth_drops": auth,
        "robots_loop_lateness_ms": lateness_figures(result.late, result.wakes, []),
        "violations": [v.as_dict() for v in checker.violations],
        "loadavg_1min_before_after": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "problems": result.problems,
    }


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=3000.0, help="forged frames a second")
    ap.add_argument("--flood", type=float, default=20.0, help="flood length, s")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    report = {"cpus": os.cpu_count(), "verify": verify_cost()}
    if not args.json:
        print("one signature check:", json.dumps(report["verify"]))
    report["flood"] = await bench_flood(args.rate, args.flood)
    print(json.dumps(report, indent=2) if args.json else
          "paper swarm, real daemons, forged anchors: " + json.dumps(report["flood"]))


if __name__ == "__main__":
    asyncio.run(main())
