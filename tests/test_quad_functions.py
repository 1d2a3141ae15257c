"""Function specs and their setpoints, without physics (swarmd/base/functions.py)."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmd.base.functions import (
    FunctionSpecError,
    PatrolFlight,
    PatrolSpec,
    SlotFlight,
    SlotSpec,
    flight_for,
    flight_problems,
    next_waypoint,
    parse_function,
    parse_functions,
)

SQUARE = {"kind": "patrol", "waypoints": [[0, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]],
          "speed": 1.0}
"""A 2 m square at 1 m/s: waypoints at arc 0, 2, 4, 6; loop 8 m."""


def test_parse_slot_and_patrol() -> None:
    specs = parse_functions({"f1": {"kind": "slot", "position": [1, 2, 3]}, "p": SQUARE})
    assert specs["f1"] == SlotSpec((1.0, 2.0, 3.0))
    p = specs["p"]
    assert isinstance(p, PatrolSpec)
    assert p.length == pytest.approx(8.0)
    assert p.arcs == pytest.approx((0, 2, 4, 6, 8))


def test_parse_ignores_runtime_extras() -> None:
    # A spec may carry the run's t0 for the link (sim/physics/link.py): not a field.
    assert parse_function("f", {"kind": "slot", "position": [0, 0, 1], "t0": 5.0}) == SlotSpec(
        (0.0, 0.0, 1.0)
    )


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ({"kind": "hover"}, "kind"),
        ({"kind": "slot", "position": [0, 0]}, "position"),
        ({"kind": "slot", "position": [0, "a", 1]}, "position"),
        ({"kind": "slot", "position": [0, math.nan, 1]}, "position"),
        ({"kind": "patrol", "waypoints": [[0, 0, 1]]}, "at least 2"),
        ({"kind": "patrol", "waypoints": [[0, 0, 1], [0, 0, 1]]}, "coincide"),
        ({"kind": "patrol", "waypoints": [[0, 0, 1], [1, 0, 1]], "speed": 0}, "speed"),
        ({"kind": "patrol", "waypoints": [[0, 0, 1], [1, 0, 1], [1, 1]]}, "waypoints[2]"),
        ({"kind": "slot", "position": [0, 0, -0.5]}, "position z = -0.5 m is under the ground"),
        ({"kind": "slot", "position": [0, 0, 0.1]}, "too close to the ground"),
        ({"kind": "patrol", "waypoints": [[0, 0, 1], [2, 0, -1]]}, "waypoints[1] z = -1"),
        # the loop closes: a last waypoint equal to the first is a zero-length leg
        ({"kind": "patrol", "waypoints": [[0, 0, 1], [1, 0, 1], [0, 0, 1]]},
         "waypoints[0] coincide with waypoints[2]"),
        ({"kind": "patrol", "waypoints": [[0, 0, 1], [1, 0, 1]], "speed": True}, "speed"),
    ],
)
def test_parse_rejects_with_the_field_named(spec: dict[str, object], words: str) -> None:
    with pytest.raises(FunctionSpecError) as err:
        parse_function("f7", spec)
    assert "f7" in str(err.value) and words in str(err.value)


def test_flight_problems_name_the_swarm_file_field() -> None:
    # What `swarmd sim` prints before starting any robot.
    functions: dict[str, Any] = {
        "f1": {"kind": "slot", "position": [0, 0, 1.5]},
        "p1": {"kind": "patrol", "waypoints": [[0, 0, 1.5], [2, 0, -1.0]], "speed": 1.0},
        "p2": {"kind": "patrol", "waypoints": [[0, 0, 1.5]]},
        "p3": SQUARE,
    }
    problems = flight_problems(functions)
    assert len(problems) == 2
    assert problems[0].startswith("functions.p1.waypoints[1]: z = -1.0 m is under the ground")
    assert problems[1].startswith("functions.p2.waypoints: must list at least 2 points")
    assert flight_problems({"f1": functions["f1"], "p3": SQUARE}) == []


@pytest.mark.parametrize(
    ("t", "expected"),
    [(0.0, 1), (1.5, 1), (2.0, 2), (3.9, 2), (6.0, 0), (7.99, 0), (8.0, 1), (8.5, 1),
     (17.0, 1), (19.0, 2), (-1.0, 0)],
)
def test_next_waypoint_follows_the_shared_clock(t: float, expected: int) -> None:
    spec = parse_function("p", SQUARE)
    assert isinstance(spec, PatrolSpec)
    assert next_waypoint(spec, t) == expected


@given(st.floats(min_value=0.0, max_value=1e4, allow_nan=False))
def test_next_waypoint_is_the_end_of_the_current_segment(t: float) -> None:
    spec = parse_function("p", {"kind": "patrol", "speed": 0.7,
                                "waypoints": [[0, 0, 1], [3, 0, 1], [3, 1, 1]]})
    assert isinstance(spec, PatrolSpec)
    s = spec.speed * t
    i, s_next = spec.next_after(s)
    longest = max(b - a for a, b in zip(spec.arcs, spec.arcs[1:], strict=False))
    assert s < s_next <= s + longest + 1e-6
    assert i == next_waypoint(spec, t)
    pos, _ = spec.point(s_next)
    assert pos == pytest.approx(spec.waypoints[i], abs=1e-6)


def test_slot_flight_holds_the_position() -> None:
    f = flight_for(SlotSpec((1.0, 2.0, 3.0)), 5.0)
    assert isinstance(f, SlotFlight)
    assert f.setpoint(9.0, (0.0, 0.0, 0.0)).position == (1.0, 2.0, 3.0)
    assert f.target == (1.0, 2.0, 3.0)


def _fly(flight: PatrolFlight, t_from: float, t_to: float, start: tuple[float, float, float],
         transit_speed: float = 2.0) -> list[int]:
    """Kinematic craft: flies to the setpoint at `transit_speed` at most; returns the
    sequence of distinct waypoints it heads to."""
    pos = start
    seen = [flight.heading_to()]
    dt = 0.01
    t = t_from
    while t < t_to:
        sp = flight.setpoint(t, pos)
        d = [sp.position[k] - pos[k] for k in range(3)]
        n = math.sqrt(sum(v * v for v in d))
        step = min(n, transit_speed * dt)
        u = step / n if n > 0 else 0.0
        pos = (pos[0] + d[0] * u, pos[1] + d[1] * u, pos[2] + d[2] * u)
        if flight.heading_to() != seen[-1]:
            seen.append(flight.heading_to())
        t += dt
    return seen


def test_substitute_resumes_at_the_failed_robots_next_waypoint() -> None:
    spec = parse_function("p", SQUARE)
    assert isinstance(spec, PatrolSpec)
    # At t = 5 the holder is on the segment 2 -> 3 (arc 5): the next waypoint is 3.
    f = PatrolFlight(spec, 5.0)
    assert f.first == 3
    seen = _fly(f, 5.0, 20.0, (0.0, -3.0, 0.0))
    # Straight to waypoint 3, then the loop in order from it, not from the start.
    assert seen[:5] == [3, 0, 1, 2, 3]


def test_late_substitute_catches_up_with_the_schedule() -> None:
    spec = parse_function("p", SQUARE)
    assert isinstance(spec, PatrolSpec)
    f = PatrolFlight(spec, 5.0)
    _fly(f, 5.0, 30.0, (0.0, -10.0, 0.0))  # far away: arrives well behind the schedule
    assert f.t_arrived is not None and spec.speed * f.t_arrived > f.s_first
    assert f.progress(30.0) == pytest.approx(spec.speed * 30.0)  # back on the clock


def test_early_substitute_waits_at_the_waypoint() -> None:
    spec = parse_function("p", SQUARE)
    assert isinstance(spec, PatrolSpec)
    f = PatrolFlight(spec, 4.5)  # heading to waypoint 3 (arc 6) from its position
    wp = spec.waypoints[3]
    sp = f.setpoint(4.6, wp)  # already there at 4.6: the schedule reaches it at 6.0
    assert sp.position == pytest.approx(wp) and sp.velocity == (0.0, 0.0, 0.0)
    assert f.setpoint(7.0, wp).position == pytest.approx(spec.point(7.0)[0])
