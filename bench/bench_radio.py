"""Failover latency over emulated 802.15.4 radios at the `radio()` preset, and the
largest swarm whose heartbeats fit one 802.15.4 channel below 30% airtime.

    python bench/bench_radio.py [--runs 10] [--protocol 802.15.4] [--api-mode 1]

Each run: the paper swarm (robots 1-4 active in a ring, 5 covers f1/f4, 6 covers
f2/f3), six `Node`s each on its own `XBeeTransport` (real digi-xbee) on its own
emulated radio, all in one process. After a warm-up the holder of f2 or f3 (alternating)
is crashed, at a phase of the heartbeat period that differs run to run; latency is from
the crash to the substitute's `takeover` event. Timing is
the unmodified `radio()` preset, so a run takes ~20 s (startup grace excluded: the
crash comes after every robot has been heard).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time

from sim.xbee_emu import Medium
from sim.xbee_emu.swarm import RadioSwarm, paper_plan
from swarmd.core.params import radio
from swarmd.services.budget import budget_for, largest_swarm
from swarmd.transport.base import Transport
from swarmd.transport.xbee import XBeeTransport


async def one_run(protocol: str, api_mode: int, victim: int,
                  phase: float = 0.0) -> tuple[float | None, int]:
    params = radio()
    with tempfile.TemporaryDirectory() as tmp, \
            Medium(6, protocol=protocol, api_mode=api_mode, directory=tmp) as medium:
        transports: dict[int, Transport] = {
            r: XBeeTransport(port=medium.path(r), protocol=protocol, api_mode=api_mode)
            for r in range(1, 7)
        }
        swarm = RadioSwarm(paper_plan(), params, transports)
        await swarm.start()
        try:
            # Warm-up: two standby heartbeat periods, so everyone has heard everyone.
            # The crash lands `phase` of a heartbeat period later in each run: detection
            # depends on when the last heartbeat went out (Fig. 7), so the median is
            # taken over the whole period, not one point of it.
            await swarm.wait_for(lambda e: False, 2 * params.standby_heartbeat_interval
                                 + phase * params.heartbeat_interval)
            await swarm.kill(victim)
            t_crash = swarm.elapsed()
            function = f"f{victim}"
            ev = await swarm.wait_for(
                lambda e: e["event"] == "takeover" and e["function"] == function,
                params.takeover_bound() + 10)
            latency = None if ev is None else ev["t"] - t_crash
            wrong = sum(1 for e in swarm.events if e["event"] == "takeover"
                        and e["function"] != function)
            return latency, wrong
        finally:
            await swarm.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--protocol", default="802.15.4")
    ap.add_argument("--api-mode", type=int, default=1)
    args = ap.parse_args()
    params = radio()
    print(f"failover over emulated {args.protocol} radios (API mode {args.api_mode}), "
          f"radio() preset: heartbeat {params.heartbeat_interval} s, t_max {params.t_max} s, "
          f"claim_hold {params.claim_hold} s")
    latencies: list[float] = []
    failed = wrong_total = 0
    started = time.monotonic()
    for i in range(args.runs):
        victim = 2 if i % 2 == 0 else 3
        latency, wrong = asyncio.run(one_run(args.protocol, args.api_mode, victim,
                                             phase=i / args.runs))
        wrong_total += wrong
        if latency is None:
            failed += 1
            print(f"  run {i + 1}: robot {victim} crashed, NO takeover")
        else:
            latencies.append(latency)
            print(f"  run {i + 1}: robot {victim} crashed, taken over after {latency:.3f} s")
    if latencies:
        qs = sorted(latencies)
        print(f"failover latency over {len(qs)} runs: median {statistics.median(qs):.3f} s, "
              f"min {qs[0]:.3f} s, max {qs[-1]:.3f} s; missed {failed}; false takeovers "
              f"{wrong_total}; wall time {time.monotonic() - started:.1f} s")
    n = largest_swarm(params, medium="802.15.4", signed=True)
    standby = round(n / 3)
    b = budget_for(n - standby, standby, 2, params, medium="802.15.4", signed=True)
    print(f"largest swarm whose signed heartbeats fit one 802.15.4 channel below 30% "
          f"airtime at radio(): {n} robots ({n - standby} active at "
          f"{1 / params.heartbeat_interval:g} Hz + {standby} standby at "
          f"{1 / params.standby_heartbeat_interval:g} Hz): {b.frames_per_s:.0f} frames/s, "
          f"{b.airtime_share:.1%} airtime")


if __name__ == "__main__":
    main()
