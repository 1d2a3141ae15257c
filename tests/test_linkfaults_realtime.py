"""Link faults on real daemons (DESIGN, "Convergence"): losses one way, applied in each
robot process's receive filter (sim/realtime/netfilter.py), on the shipped per-robot
signed paper swarm.

The shape that once left two robots executing f2 for good: robot 2's transmissions fade
while it still hears everyone, and standby 6 stays deaf to robot 2 a little longer.
Short (robot 2's answers are lost for less than a takeover) or long (6 takes f2 over
while 2 refutes unheard), both runs must end with exactly one robot executing f2 and no
invariant broken. The two runs go concurrently, so the module costs about one run.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from sim.realtime.netfilter import PartitionWindow, ReceiveFilter, link_windows
from sim.realtime.orchestrator import RealtimeResult, run_realtime_async
from sim.realtime.view import SwarmView
from sim.shared.faults import parse_fault
from sim.shared.invariants import check_events
from swarmd.config import load_swarm
from swarmd.core import wire

PAPER = Path(__file__).resolve().parent.parent / "configs" / "paper.yaml"
DURATION = 8.0
SHAPES = {
    "short": ("fade:2@3+0.46", "deaf:6:2@3+0.86"),
    "long": ("fade:2@3+0.9", "deaf:6:2@3+1.9"),
}


def _holders(result: RealtimeResult) -> dict[int, str]:
    view = SwarmView(result.robots)
    for rec in result.events:
        view.feed(rec)
    return {r: v.function for r, v in view.robots.items()
            if v.function is not None and v.role == "ACTIVE"}


@pytest.mark.slow
async def test_a_fade_and_a_longer_deafness_end_with_one_holder(tmp_path: Path) -> None:
    async def one(name: str) -> RealtimeResult:
        faults = [parse_fault(s) for s in SHAPES[name]]
        return await asyncio.wait_for(
            run_realtime_async(PAPER, duration=DURATION, faults=faults,
                               report_dir=tmp_path / name, seed=1), timeout=DURATION + 40)

    results = dict(zip(SHAPES, await asyncio.gather(*(one(n) for n in SHAPES)),
                       strict=True))
    swarm = load_swarm(PAPER)
    for name, result in results.items():
        assert result.problems == [], (name, result.problems)
        faults = [parse_fault(s) for s in SHAPES[name]]
        checker = check_events(result.events, faults, swarm.to_plan(), swarm.params(),
                               loss=0.0, duration=DURATION)
        assert [v.as_dict() for v in checker.violations] == [], name
        doers = sorted(r for r, f in _holders(result).items() if f == "f2")
        assert len(doers) == 1, (name, doers)
        took = [e for e in result.events if e["event"] == "takeover" and e["robot"] == 6]
        if took:  # 6 took f2 over while 2 refuted unheard: it stepped down after the heal
            fenced = [e for e in result.events if e["event"] == "fenced" and e["robot"] == 6]
            assert fenced and fenced[-1]["t"] > took[-1]["t"], name
            assert doers == [2], name


def _frame(sender: int) -> bytes:
    return wire.encode(wire.Frame(1543, sender, 1, wire.Heartbeat(1, 0, 1, 0)))


def test_the_receive_filter_cuts_one_way_by_the_clock() -> None:
    clock = [0.0]
    windows = link_windows([parse_fault("fade:2@1+1"), parse_fault("deaf:6:3@1+2"),
                            parse_fault("partition:1,4|5@1+1")])
    six = ReceiveFilter(6, partitions=windows, clock=lambda: clock[0])
    two = ReceiveFilter(2, partitions=windows, clock=lambda: clock[0])
    assert six(_frame(2), 0.0) and six(_frame(3), 0.0)  # before
    clock[0] = 1.5
    assert not six(_frame(2), 0.0) and not six(_frame(3), 0.0)  # 2 faded, 6 deaf to 3
    assert two(_frame(6), 0.0) and two(_frame(3), 0.0)  # a fading robot still hears
    clock[0] = 2.5
    assert six(_frame(2), 0.0) and not six(_frame(3), 0.0)  # the fade healed first
    clock[0] = 3.5
    assert six(_frame(3), 0.0)
    assert all(isinstance(w, PartitionWindow) for w in windows)


def test_the_receive_filter_loses_in_bursts_at_the_mean_loss() -> None:
    f = ReceiveFilter(6, loss=0.2, seed=3, loss_model="burst", burst_len=5.0,
                      clock=lambda: 0.0)
    kept = [f(_frame(2), 0.0) for _ in range(20_000)]
    lost = kept.count(False) / len(kept)
    runs, n = [], 0
    for k in kept:
        if not k:
            n += 1
        elif n:
            runs.append(n)
            n = 0
    assert 0.15 < lost < 0.25
    assert 3.5 < sum(runs) / len(runs) < 6.5  # bursts, not single losses
