"""One simulated robot: modes, health (DESIGN rule 7), patrol takeover, trajectories."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from sim.physics.robot import Mode, QuadRobot, load_trajectory, trajectory_of
from swarmd.base.functions import PatrolFlight, PatrolSpec, next_waypoint, parse_function
from swarmd.core.roles import Health

SLOT = {"kind": "slot", "position": [1.0, 1.0, 1.5]}
PATROL = {"kind": "patrol", "speed": 1.0,
          "waypoints": [[-2, -2, 1.5], [2, -2, 1.5], [2, 2, 1.5], [-2, 2, 1.5]]}


def mode_of(r: QuadRobot) -> Mode:
    """The mode, unnarrowed (mypy keeps an earlier `assert r.mode is ...`)."""
    return r.mode


def test_standby_stays_parked_at_home_and_healthy() -> None:
    r = QuadRobot(5, (1.5, -3.5, 0.0))
    r.step_until(3.0)
    assert r.mode is Mode.PARKED and r.health() is Health.OK
    assert r.position == pytest.approx((1.5, -3.5, r.preset.rest_height), abs=0.01)
    assert r.battery == 1.0  # motors off on the ground


def test_motor_failure_is_faulty_and_the_craft_falls() -> None:
    r = QuadRobot(2, (0.0, 0.0, 0.0))
    r.assign("f2", SLOT)
    r.step_until(5.0)
    assert r.health() is Health.OK and r.position[2] > 1.4
    r.fail_motor(2)
    assert r.health() is Health.FAULTY  # at once: the daemon leaves (rule 7)
    r.step_until(5.1)
    r.release("f2")  # what the daemon does after LEAVE: the craft cannot land, it falls
    r.step_until(8.0)
    assert r.position[2] < 0.3  # fell
    assert r.mode is Mode.CRASHED and r.crashed_at is not None
    assert not r.assign("f2", SLOT)  # a broken craft does not take off again
    # the trajectory says it fell, not that it landed
    modes = [s.mode for s in r.samples if s.t > 5.0]
    assert "landing" not in modes and modes[0] == "falling" and modes[-1] == "crashed"


def test_hitting_the_ground_while_flying_is_a_crash() -> None:
    r = QuadRobot(1, (0.0, 0.0, 0.0))
    r.assign("low", {"kind": "slot", "position": [0.0, 0.0, 1.0]})
    r.step_until(4.0)
    r.model.actuator_gainprm[:, 0] = 0.0  # every motor stops: no fail_motor bookkeeping
    r.step_until(6.0)
    assert r.mode is Mode.CRASHED and r.health() is Health.FAULTY


def test_release_lands_at_home_without_a_crash() -> None:
    home = (-1.0, -3.0, 0.0)
    r = QuadRobot(1, home)
    r.assign("f1", SLOT)
    r.step_until(6.0)
    r.release("other")  # not its function: ignored
    assert r.mode is Mode.FLYING
    r.release("f1")
    r.step_until(16.0)
    assert mode_of(r) is Mode.PARKED and r.health() is Health.OK
    assert math.dist(r.position[:2], home[:2]) < 0.1


def test_battery_degrades_then_faults() -> None:
    r = QuadRobot(1, (0.0, 0.0, 0.0), battery_s=10.0)
    r.assign("f1", SLOT)
    r.step_until(8.5)
    assert r.health() is Health.DEGRADED, r.battery  # ~85% of 10 s of hover used
    r.step_until(10.5)
    assert r.health() is Health.FAULTY


def test_standby_taking_over_a_patrol_resumes_at_the_failed_robots_next_waypoint() -> None:
    spec = parse_function("p", PATROL)
    assert isinstance(spec, PatrolSpec)
    holder = QuadRobot(1, (0.0, -4.0, 0.0))
    standby = QuadRobot(2, (3.0, -4.0, 0.0))
    holder.assign("p", PATROL)
    t_fail = 13.0  # on the clock: arc 13 of a 16 m loop, heading to waypoint 0
    holder.step_until(t_fail)
    standby.step_until(t_fail)
    assert isinstance(holder.flight, PatrolFlight)
    was_heading = holder.flight.heading_to()
    assert was_heading == next_waypoint(spec, t_fail) == 0
    holder.fail_motor(0)
    standby.assign("p", PATROL)
    assert isinstance(standby.flight, PatrolFlight)
    assert standby.flight.first == was_heading
    # Physics: the first waypoint the substitute reaches is that one, then the next.
    reached: list[int] = []
    t = t_fail
    while t < t_fail + 20.0 and len(reached) < 2:
        t += 0.05
        standby.step_until(t)
        for i, wp in enumerate(spec.waypoints):
            if math.dist(standby.position, wp) < 0.35 and (not reached or reached[-1] != i):
                reached.append(i)
    assert reached == [was_heading, (was_heading + 1) % 4]


def test_trajectory_round_trip(tmp_path: Path) -> None:
    r = QuadRobot(3, (0.5, -3.5, 0.0))
    r.assign("f3", SLOT)
    r.step_until(2.0)
    path = tmp_path / "traj-3.jsonl"
    r.write_trajectory(path, wall0=1000.0)
    with path.open("a") as f:
        f.write('{"t": 9, "p": [0, 0')  # a SIGKILL cut the last line: skipped
    tr = load_trajectory(path, t0=999.0)
    assert tr.robot == 3 and tr.home == (0.5, -3.5, 0.0)
    assert len(tr.t) == len(r.samples) == 41  # 20 Hz for 2 s, plus t = 0
    assert tr.t[0] == pytest.approx(1.0)  # robot time 0 is run time 1 s
    assert tr.functions[-1] == "f3" and tr.modes[0] == "parked"
    pos, _quat = tr.at(2.0)
    assert pos == pytest.approx(trajectory_of(r).at(1.0)[0])
    assert json.loads(path.read_text().splitlines()[0])["robot"] == 3


def test_assigning_the_same_function_again_keeps_the_flight() -> None:
    r = QuadRobot(1, (0.0, -4.0, 0.0))
    r.assign("p", PATROL)
    r.step_until(6.0)
    flight = r.flight
    assert r.assign("p", PATROL)  # a new epoch of the same function
    assert r.flight is flight
    r.assign("f1", SLOT)
    assert r.flight is not flight and r.function == "f1"


def test_a_restarted_robot_resumes_in_the_air_and_lands_at_home() -> None:
    # restart:R@T kills the robot's process; the new one must not show the craft
    # teleported home: it comes back where it was, holds no function, and lands.
    home = (2.0, -4.0, 0.0)
    r = QuadRobot(44, home)
    r.resume((1.0, -2.0, 0.6), (1.0, 0.0, 0.0, 0.0), "flying")
    assert mode_of(r) is Mode.LANDING and r.function is None
    assert r.samples[0].pos == pytest.approx((1.0, -2.0, 0.6))
    lowest = 1.0
    while r.t < 1.0:
        r.step_until(r.t + 0.05)
        if math.dist(r.position[:2], home[:2]) > 0.3:
            lowest = min(lowest, r.position[2])
    assert lowest > 0.5  # motors already spinning: no drop, no scrape on the way home
    r.step_until(12.0)
    assert mode_of(r) is Mode.PARKED and r.health() is Health.OK
    assert math.dist(r.position[:2], home[:2]) < 0.1


def test_a_restarted_broken_robot_stays_broken() -> None:
    r = QuadRobot(2, (0.0, 0.0, 0.0))
    r.resume((3.0, 1.0, 0.04), (1.0, 0.0, 0.0, 0.0), "crashed")
    assert r.health() is Health.FAULTY
    r.step_until(0.5)
    assert r.position == pytest.approx((3.0, 1.0, 0.04), abs=0.02)
    assert not r.assign("f1", SLOT)
    falling = QuadRobot(3, (0.0, 0.0, 0.0))
    falling.resume((3.0, 1.0, 1.2), (1.0, 0.0, 0.0, 0.0), "falling")
    assert falling.health() is Health.FAULTY
    falling.step_until(3.0)
    assert mode_of(falling) is Mode.CRASHED


def test_a_restarts_samples_replace_what_the_last_process_simulated_ahead(
    tmp_path: Path,
) -> None:
    # leave (close lands the craft, samples ahead of the clock) then restart at 1002:
    # from 1002 on only the new process's samples count.
    path = tmp_path / "traj-4.jsonl"
    head = {"robot": 4, "preset": "x2", "home": [0, 0, 0]}
    lines = [{**head, "wall0": 1000.0}]
    lines += [{"t": t, "p": [t, 0, 1], "q": [1, 0, 0, 0], "mode": "landing", "function": None,
               "w": 1000.0 + t} for t in (0.0, 1.0, 2.0, 3.0, 4.0)]
    lines += [{**head, "wall0": 1002.0}]
    lines += [{"t": t, "p": [9, 9, 0], "q": [1, 0, 0, 0], "mode": "parked", "function": None,
               "w": 1002.0 + t} for t in (0.0, 1.0)]
    path.write_text("".join(json.dumps(row) + "\n" for row in lines))
    tr = load_trajectory(path, t0=1000.0)
    assert list(tr.t) == [0.0, 1.0, 2.0, 3.0]
    assert list(tr.pos[:, 0]) == [0.0, 1.0, 9.0, 9.0]
