"""The quadrotor model and its SE(3) controller, stepped faster than real time."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from sim.physics.controller import Command, SE3Controller, mixer
from sim.physics.model import GRAVITY, Preset, crazyflie, preset, quad_xml, x2
from sim.physics.robot import QuadRobot

PRESETS = [crazyflie(), x2()]


def _dist(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    return math.dist(a, b)


@pytest.mark.parametrize("p", PRESETS, ids=lambda p: p.name)
def test_model_compiles_with_four_lagged_rotors(p: Preset) -> None:
    m = mujoco.MjModel.from_xml_string(quad_xml(p, (1.0, 2.0, 0.0)))
    assert m.nu == 4
    assert m.body("quad").mass[0] == pytest.approx(p.mass)
    assert list(m.actuator_dyntype) == [mujoco.mjtDyn.mjDYN_FILTEREXACT] * 4
    assert m.actuator_dynprm[:, 0] == pytest.approx([p.tau] * 4)
    # gear: thrust along z and the rotor's reaction torque, alternating spin
    assert m.actuator_gear[:, 2] == pytest.approx([1.0] * 4)
    assert sorted(np.sign(m.actuator_gear[:, 5])) == [-1, -1, 1, 1]
    assert m.actuator_ctrlrange[:, 1] == pytest.approx([p.max_thrust] * 4)


def test_presets_from_public_numbers() -> None:
    cf, big = crazyflie(), x2()
    assert cf.max_thrust * 4 / (cf.mass * GRAVITY) == pytest.approx(2.25)
    assert cf.kappa == pytest.approx(0.0251, abs=1e-4)
    assert big.hover_thrust == pytest.approx(3.25, abs=0.01)
    assert preset("x2") == big
    with pytest.raises(ValueError, match="crazyflie"):
        preset("nope")


@pytest.mark.parametrize("p", PRESETS, ids=lambda p: p.name)
def test_mixer_inverts_and_hover_is_even(p: Preset) -> None:
    a = mixer(p)
    assert a @ np.linalg.inv(a) == pytest.approx(np.eye(4))
    c = SE3Controller(p)
    level = np.eye(3)
    at = np.array((0.0, 0.0, 1.0))
    cmd = Command(at, np.zeros(3), np.zeros(3))
    f = c.update(at, np.zeros(3), level, np.zeros(3), cmd, 0.01)
    assert f == pytest.approx([p.hover_thrust] * 4, rel=1e-6)


def test_controller_saturates_a_far_target_to_a_bounded_tilt() -> None:
    p = x2()
    c = SE3Controller(p)
    cmd = Command(np.array((100.0, 0.0, 1.0)), np.zeros(3), np.zeros(3))
    thrust, moments = c.wrench(np.array((0.0, 0.0, 1.0)), np.zeros(3), np.eye(3),
                               np.zeros(3), cmd, 0.01)
    # Saturated error: the same command as a target 1 m away.
    near = Command(np.array((1.0, 0.0, 1.0)), np.zeros(3), np.zeros(3))
    thrust2, moments2 = SE3Controller(p).wrench(np.array((0.0, 0.0, 1.0)), np.zeros(3),
                                                np.eye(3), np.zeros(3), near, 0.01)
    assert thrust == pytest.approx(thrust2)
    assert moments == pytest.approx(moments2)
    assert moments[1] > 0  # pitch nose down to go +x


@pytest.mark.parametrize("p", PRESETS, ids=lambda p: p.name)
def test_holds_a_slot_within_5cm(p: Preset) -> None:
    r = QuadRobot(1, (0.0, 0.0, 0.0), p, record=False)
    slot = (1.0, -1.0, 1.5)
    r.assign("f1", {"kind": "slot", "position": list(slot)})
    r.step_until(6.0)  # take off and settle
    worst = 0.0
    t = 6.0
    while t < 12.0:
        t += 0.05
        r.step_until(t)
        worst = max(worst, _dist(r.position, slot))
    assert worst < 0.05, f"{p.name} wandered {worst:.3f} m from its slot"


def test_a_long_move_climbs_while_it_cruises() -> None:
    # Regression: one 3-D error saturation gave a 20 m move a 0.1 m/s climb, so a
    # standby crossed the field at take-off height and climbed at the far end.
    r = QuadRobot(1, (0.0, 0.0, 0.0), x2(), record=False)
    r.assign("far", {"kind": "slot", "position": [20.0, 0.0, 3.0]})
    t = 0.0
    while r.position[0] < 5.0 and t < 10.0:
        t += 0.1
        r.step_until(t)
    assert r.position[2] > 2.5, f"at x = {r.position[0]:.1f} m still at z = {r.position[2]:.2f}"


@pytest.mark.parametrize("p", PRESETS, ids=lambda p: p.name)
def test_reaches_a_3m_setpoint_within_5s(p: Preset) -> None:
    r = QuadRobot(1, (0.0, 0.0, 0.0), p, record=False)
    r.assign("a", {"kind": "slot", "position": [0.0, 0.0, 1.5]})
    r.step_until(6.0)
    assert _dist(r.position, (0.0, 0.0, 1.5)) < 0.05
    goal = (3.0, 0.0, 1.5)
    r.assign("b", {"kind": "slot", "position": list(goal)})
    reached = None
    t = 6.0
    while t < 11.0:
        t += 0.02
        r.step_until(t)
        if reached is None and _dist(r.position, goal) < 0.05:
            reached = t - 6.0
    assert reached is not None and reached < 5.0, f"{p.name}: {reached}"
    assert _dist(r.position, goal) < 0.05  # and stays there
