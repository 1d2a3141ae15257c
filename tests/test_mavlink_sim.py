"""`swarmd sim --link mavlink`: the flown swarm end to end through MAVLink (docs/sim.md).

Each robot process runs its daemon with the MAVLink link, talking over loopback UDP to a
simulated autopilot (PX4 or ArduPilot flavour) that flies the MuJoCo quadrotor. A fault
reaches the autopilot only; the daemon learns of it through MAVLink health.

Real-time runs, few and bounded by timeouts; the option checks need no process.
"""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from sim.run import SimError, SimOptions, run_sim
from sim.shared.faults import parse_fault
from swarmd.config import load_swarm

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"


@pytest.mark.parametrize(("kwargs", "says"), [
    ({"link": "mavlink", "physics": False}, "--link: mavlink needs physics"),
    ({"link": "mavlink", "virtual": True}, "--link: mavlink needs physics"),
    ({"link": "serial"}, "--link: 'serial' is not one of direct, mavlink"),
    ({"autopilot": "px4"}, "--autopilot: only with --link mavlink"),
    ({"link": "mavlink", "autopilot": "inav"}, "--autopilot: 'inav' is not one of"),
    ({"refuse_arm": (3,)}, "--refuse-arm: only with --link mavlink"),
])
def test_bad_link_options_are_refused_up_front(kwargs: dict[str, object], says: str) -> None:
    with pytest.raises(SimError) as err:
        SimOptions(swarm=PAPER, **kwargs)  # type: ignore[arg-type]
    assert len(err.value.lines) == 1 and err.value.lines[0].startswith(says)


def test_refuse_arm_of_an_unknown_robot_is_refused_before_anything_runs() -> None:
    with pytest.raises(SimError, match=r"--refuse-arm: robot 9 is not in"):
        run_sim(SimOptions(swarm=PAPER, link="mavlink", refuse_arm=(9,)))


def test_the_robot_link_follows_the_options() -> None:
    assert SimOptions(swarm=PAPER).robot_link == "quad"
    assert SimOptions(swarm=PAPER, physics=False).robot_link == "none"
    assert SimOptions(swarm=PAPER, link="mavlink").robot_link == "mavlink-px4"
    assert SimOptions(swarm=PAPER, link="mavlink",
                      autopilot="ardupilot").robot_link == "mavlink-ardupilot"


@pytest.mark.slow
@pytest.mark.parametrize(("flavour", "duration"), [("px4", 14.0), ("ardupilot", 14.0)])
async def test_motor_2_at_5_through_mavlink_ends_with_robot_6_in_f2s_slot(
        tmp_path: Path, flavour: str, duration: float) -> None:
    pytest.importorskip("mujoco")
    from sim.physics.render import trajectory_files
    from sim.physics.robot import load_trajectory
    from sim.realtime.orchestrator import run_realtime_async

    result = await asyncio.wait_for(
        run_realtime_async(PAPER, duration=duration, faults=[parse_fault("motor:2@5")],
                           report_dir=tmp_path, physics=True, link=f"mavlink-{flavour}"),
        timeout=duration + 45.0)
    assert result.problems == []
    ev = result.events
    # Noticed through MAVLink health: the motor fault only changed robot 2's autopilot
    # (SYS_STATUS motor bit, EMERGENCY); its own daemon hands f2 over (DESIGN rule 7).
    leave = [e for e in ev if e["event"] == "leave" and e["robot"] == 2]
    assert leave and leave[0]["function"] == "f2" and leave[0]["reason"] == "fault"
    assert 5.0 <= leave[0]["t"] < 7.0
    takeovers = [(e["robot"], e["function"]) for e in ev if e["event"] == "takeover"]
    assert takeovers == [(6, "f2")]

    trajs = {tr.robot: tr for tr in (load_trajectory(p, t0=result.t0)
                                     for p in trajectory_files(tmp_path))}
    slot = load_swarm(PAPER).function_spec("f2")["position"]
    six = trajs[6]
    assert six.t[-1] > duration - 1.0  # it flew to the end of the run
    assert math.dist(six.pos[-1], slot) < 0.5, six.pos[-1]
    assert six.functions[-1] == "f2"
    assert trajs[2].modes[-1] == "crashed"


@pytest.mark.slow
def test_a_refused_arm_is_a_health_problem_and_the_standby_takes_over() -> None:
    pytest.importorskip("mujoco")
    duration = 8.0
    proc = subprocess.run(
        [sys.executable, "-m", "swarmd.cli", "sim", str(PAPER), "--link", "mavlink",
         "--autopilot", "ardupilot", "--refuse-arm", "3", "--duration", str(duration),
         "--json"],
        capture_output=True, text=True, timeout=duration + 60.0, check=False, cwd=ROOT)
    summary = json.loads(proc.stdout) if proc.stdout.strip() else {}
    why = {k: summary.get(k) for k in ("violations", "problems", "warnings", "faults",
                                       "false_takeovers", "lateness_ms")}
    assert proc.returncode == 0, (why, proc.stderr[-2000:])
    # Robot 3's daemon heard the COMMAND_ACK refusal as a health problem and left f3;
    # standby 6 (it covers 2 and 3) holds it, and nothing else moved.
    assert summary["holders"] == {"f1": [1], "f2": [2], "f3": [6], "f4": [4]}
    [refused] = summary["faults"]
    assert refused["fault"] == "refuse-arm:3" and refused["function"] == "f3"
    assert refused["taken_over_by"] == 6 and refused["detection_latency"] is not None
    assert summary["false_takeovers"] == 0 and summary["violations"] == []
