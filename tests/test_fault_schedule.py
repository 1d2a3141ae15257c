"""The real-time run's fault schedule (sim/realtime/schedule.py): which faults are armed,
in what order they act, and that cancel drops what is left. Driven by a fake wall clock
whose t0 is in the past, so every armed fault is due at once: no timed assertion."""

from __future__ import annotations

import asyncio

from sim.realtime.schedule import FaultSchedule
from sim.shared.faults import Fault, parse_fault


async def test_faults_act_in_time_order_and_none_after_the_end() -> None:
    faults = [parse_fault(s) for s in ("leave:4@5", "crash:2@1", "crash:3@40",
                                       "partition:1,2|3,4,5,6@2+3")]
    schedule = FaultSchedule(faults, duration=30.0)
    assert [f.at for f in schedule.faults] == [1.0, 2.0, 5.0, 40.0]
    assert [(w.start, w.end) for w in schedule.partitions] == [(2.0, 5.0)]
    applied: list[Fault] = []
    schedule.arm(100.0, applied.append, clock=lambda: 1000.0)  # all due already
    assert schedule.armed == 3  # crash:3@40 is after the run's end
    for _ in range(3):
        await asyncio.sleep(0)
    assert [f.spec() for f in applied] == ["crash:2@1", "partition:1,2|3,4,5,6@2+3",
                                           "leave:4@5"]


async def test_cancel_drops_the_faults_still_to_come() -> None:
    schedule = FaultSchedule([parse_fault("crash:2@1")], duration=10.0)
    applied: list[Fault] = []
    schedule.arm(0.0, applied.append, clock=lambda: 0.0)  # due in 1 s: cancelled first
    schedule.cancel()
    assert schedule.armed == 0
    await asyncio.sleep(0)
    assert applied == []
