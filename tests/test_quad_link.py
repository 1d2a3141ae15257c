"""QuadLink: the simulated robot behind the robot-link interface (paper Fig. 4).

Real-time but short: the link's own task steps physics on the loop's clock; the tests
wait for conditions (bounded), never for fixed protocol delays.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import pytest

from sim.physics.link import QuadLink, default_home, read_stats
from sim.physics.robot import Mode, QuadRobot, load_trajectory
from swarmd.base.functions import PatrolFlight
from swarmd.core.roles import Health
from swarmd.link.base import RobotLink


async def _until(cond: Callable[[], bool], timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        await asyncio.sleep(0.02)


async def test_reports_health_and_flies_what_it_is_assigned(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("sim.physics.link.STATS_PERIOD", 0.2)
    link = QuadLink(4, (0.5, -3.5, 0.0), traj_path=tmp_path / "traj-4.jsonl", wake=0.02,
                    health_period=0.1)
    _: RobotLink = link  # it is a RobotLink
    seen: list[Health] = []
    t0 = time.time()
    await link.start(seen.append)
    try:
        assert seen == [Health.OK]  # at once
        await _until(lambda: len(seen) >= 3)  # and periodically (health_period)
        link.assign("f4", 1, {"kind": "slot", "position": [0.5, -3.5, 1.0], "t0": t0})
        await _until(lambda: link.robot.position[2] > 0.3)
        assert link.robot.function == "f4"
        link.fail_motor()
        assert seen[-1] is Health.FAULTY  # reported at once, the daemon still runs
        await _until(lambda: link.robot.mode is Mode.CRASHED)
    finally:
        await link.close()
    assert max(link.lateness) < 0.5
    tr = load_trajectory(tmp_path / "traj-4.jsonl", t0=t0)
    assert tr.robot == 4 and len(tr.t) > 5
    assert tr.modes[-1] == "crashed" and tr.pos[:, 2].max() > 0.3
    stats = read_stats(tmp_path / "traj-4.jsonl")
    assert stats and all(s["wakes"] > 0 and s["late_p99_ms"] <= s["late_max_ms"] for s in stats)
    assert -1e-3 <= tr.t[0] < 1.0  # run time, from each sample's Unix time (0.1 ms)


async def test_bad_assignment_is_counted_not_raised(caplog: pytest.LogCaptureFixture) -> None:
    link = QuadLink(1)
    await link.start(lambda h: None)
    try:
        link.assign("f1", 1, {"kind": "warp"})
        link.assign("f1", 1, {"kind": "slot", "position": [0, 0, 1], "t0": "soon"})
        assert link.errors == 2 and link.robot.mode is Mode.PARKED
        assert "cannot fly f1" in caplog.text
        link.release("f9")  # never assigned: harmless
    finally:
        await link.close()


async def test_forced_unhealthy_is_reported() -> None:
    seen: list[Health] = []
    link = QuadLink(1)
    await link.start(seen.append)
    try:
        link.set_health(Health.FAULTY)
        assert seen[-1] is Health.FAULTY and link.health() is Health.FAULTY
    finally:
        await link.close()


def test_for_robot_takes_home_and_state_dir(tmp_path: Path) -> None:
    cfg = SimpleNamespace(robot_id=6, entry=SimpleNamespace(home=(2.5, -3.5)),
                          state_dir=tmp_path / "state" / "6")
    link = QuadLink.for_robot(cfg)
    assert link.home == (2.5, -3.5, 0.0)
    assert link.traj_path == tmp_path / "state" / "6" / "traj-6.jsonl"
    no_home = QuadLink.for_robot(SimpleNamespace(robot_id=3, entry=SimpleNamespace(home=None),
                                                 state_dir=tmp_path))
    assert no_home.home == default_home(3)


async def test_restart_resumes_this_runs_craft_and_a_new_run_starts_afresh(
    tmp_path: Path,
) -> None:
    path = tmp_path / "traj-5.jsonl"
    t0 = time.time()
    first = QuadRobot(5, (0.0, 0.0, 0.0))
    first.assign("f1", {"kind": "slot", "position": [1.0, 0.0, 1.5]})
    first.step_until(4.0)
    first.write_trajectory(path, wall0=t0 - 1.0)
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    with path.open("w") as f:  # as QuadLink writes them: each sample with its Unix time
        for row in rows:
            if "t" in row:
                row["w"] = t0 - 1.0 + row["t"]
            f.write(json.dumps(row) + "\n")
        f.write('{"t": 4.1, "p": [0.0, ')  # cut by the SIGKILL
    # Restarted within the same run: the craft is where the killed process left it.
    again = QuadLink(5, (0.0, 0.0, 0.0), traj_path=path, restart_of=t0 - 1.0)
    assert again.robot.position == pytest.approx(first.position, abs=1e-3)
    assert again.robot.mode is Mode.LANDING
    # A new run into the same directory (its t0 later than every sample): parked at
    # home, and the stale file is replaced so the report shows this run only.
    fresh = QuadLink(5, (0.0, 0.0, 0.0), traj_path=path, restart_of=t0 + 10.0)
    assert fresh.robot.mode is Mode.PARKED
    new_run = QuadLink(5, (0.0, 0.0, 0.0), traj_path=path)
    await new_run.start(lambda h: None)
    await new_run.close()
    assert load_trajectory(path).t[0] == 0.0
    assert sum('"robot"' in line for line in path.read_text().splitlines()) == 1


async def test_a_stopping_robot_lands_its_craft_before_the_process_goes(
    tmp_path: Path,
) -> None:
    # leave:R@T ends the process; the trajectory must not end with the craft in the air.
    home = (3.0, 0.5, 0.0)
    link = QuadLink(3, home, traj_path=tmp_path / "traj-3.jsonl")
    link.robot.assign("pent", {"kind": "slot", "position": [0.0, 3.0, 2.5]})
    link.robot.step_until(6.0)  # airborne before the link starts (no real-time wait)
    await link.start(lambda h: None)
    await link.close()
    tr = load_trajectory(tmp_path / "traj-3.jsonl")
    assert tr.modes[-1] == "parked" and "crashed" not in tr.modes
    assert tr.pos[-1][:2] == pytest.approx(home[:2], abs=0.1)


def test_a_restarted_robot_keeps_the_runs_patrol_clock() -> None:
    # restart:R@T: the new process starts T s into the run. A patrol assigned to it must
    # be scheduled on the run's clock (heading where the holder would be), not its own.
    square = {"kind": "patrol", "speed": 1.0,
              "waypoints": [[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]]}
    run_t0 = 1000.0
    link = QuadLink(7, (0.0, 0.0, 0.0), wall=lambda: run_t0 + 5.0, restart_of=run_t0)
    link.assign("p", 1, square)  # 5 s into the run: arc 5 of 8, heading to waypoint 3
    flight = link.robot.flight
    assert isinstance(flight, PatrolFlight) and flight.first == 3
    fresh = QuadLink(8, (0.0, 0.0, 0.0), wall=lambda: run_t0 + 5.0)
    fresh.assign("p", 1, square)  # a first start: its own start is the run's t0
    assert isinstance(fresh.robot.flight, PatrolFlight) and fresh.robot.flight.first == 1
