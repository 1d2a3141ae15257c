"""End to end with physics: `swarmd sim` of the paper's swarm with MuJoCo quadrotors:
a motor fails on robot 2 at 5 s; its daemon still runs, notices through the
robot's health (DESIGN rule 7: LEAVE), and standby 6 flies to f2's slot.

One real-time run (14 s), bounded by `asyncio.wait_for`; what happened is read from the
event log and from the trajectories the robot processes wrote.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest
from PIL import Image

from sim.physics.render import report_pictures, run_origin, trajectory_files
from sim.physics.robot import load_trajectory
from sim.realtime.orchestrator import run_realtime_async
from sim.shared.faults import parse_fault
from swarmd.config import load_swarm

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
DURATION = 14.0

pytestmark = pytest.mark.slow


async def test_motor_2_at_5_ends_with_robot_6_holding_f2(tmp_path: Path) -> None:
    result = await asyncio.wait_for(
        run_realtime_async(PAPER, duration=DURATION, faults=[parse_fault("motor:2@5")],
                           report_dir=tmp_path, physics=True),
        timeout=DURATION + 40.0,
    )
    assert result.problems == []
    ev = result.events
    # Noticed through health: robot 2's own daemon leaves (it was not silenced).
    leave = [e for e in ev if e["event"] == "leave" and e["robot"] == 2]
    assert leave and leave[0]["function"] == "f2" and 5.0 <= leave[0]["t"] < 6.0
    takeovers = [e for e in ev if e["event"] == "takeover"]
    assert [(e["robot"], e["function"]) for e in takeovers] == [(6, "f2")]

    files = trajectory_files(tmp_path)
    assert len(files) == 6
    t0 = run_origin(files)
    assert t0 is not None and abs(t0 - result.t0) < 0.5
    trajs = {tr.robot: tr for tr in (load_trajectory(p, t0=result.t0) for p in files)}
    slot = load_swarm(PAPER).function_spec("f2")["position"]
    six = trajs[6]
    assert six.t[-1] > DURATION - 1.0  # it flew to the end of the run
    assert math.dist(six.pos[-1], slot) < 0.5, six.pos[-1]
    assert six.functions[-1] == "f2"
    two = trajs[2]
    assert two.modes[-1] == "crashed" and two.pos[-1][2] < 0.3
    # The other active robots held their slots meanwhile.
    for rid in (1, 3, 4):
        spec = load_swarm(PAPER).function_spec(f"f{rid}")["position"]
        assert math.dist(trajs[rid].pos[-1], spec) < 0.1

    swarm = load_swarm(PAPER)
    functions = {name: swarm.function_spec(name) for name in swarm.functions}
    out = report_pictures(tmp_path, ev, functions, t0=result.t0, end=DURATION, video=False)
    with Image.open(out["trajectory_png"]) as im:
        # 800 px wide, taller by the legend's rows below the map
        assert im.format == "PNG" and im.size[0] == 800 and im.size[1] >= 800


async def test_collide_1_2_at_5_both_slots_taken_over_and_both_crafts_down(
        tmp_path: Path) -> None:
    # Two neighbours collide (DESIGN rule 9's likeliest double failure): both crafts lose
    # their motors and fall; f1 goes to standby 5 and f2 to standby 6 within 3 s.
    duration = 9.0
    result = await asyncio.wait_for(
        run_realtime_async(PAPER, duration=duration, faults=[parse_fault("collide:1,2@5")],
                           report_dir=tmp_path, physics=True),
        timeout=duration + 40.0,
    )
    assert result.problems == []
    took = {e["function"]: e for e in result.events if e["event"] == "takeover"}
    assert {f: e["robot"] for f, e in took.items()} == {"f1": 5, "f2": 6}
    assert all(e["t"] - 5.0 <= 3.0 for e in took.values()), took
    trajs = {tr.robot: tr for tr in (load_trajectory(p, t0=result.t0)
                                     for p in trajectory_files(tmp_path))}
    for down in (1, 2):
        assert trajs[down].modes[-1] == "crashed" and trajs[down].pos[-1][2] < 0.3
