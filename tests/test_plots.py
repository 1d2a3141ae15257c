"""Report pictures: the role timeline and the top-down trajectories (sim/physics/plots.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from PIL import Image

from sim.physics.plots import Span, role_at, role_spans, timeline_png, trajectory_png
from sim.physics.robot import QuadRobot, trajectory_of

EVENTS: list[dict[str, Any]] = [
    {"t": 0.0, "robot": 1, "event": "started", "role": "active", "function": "f1"},
    {"t": 0.0, "robot": 2, "event": "started", "role": "active", "function": "f2"},
    {"t": 0.0, "robot": 6, "event": "started", "role": "standby", "function": None},
    {"t": 5.0, "robot": 2, "event": "fault", "kind": "motor"},
    {"t": 5.1, "robot": 2, "event": "leave", "function": "f2", "reason": "faulty"},
    {"t": 5.2, "robot": 1, "event": "suspect", "subject": 2, "function": "f2"},
    {"t": 5.3, "robot": 6, "event": "claim", "subject": 2, "function": "f2", "epoch": 1},
    {"t": 5.8, "robot": 6, "event": "takeover", "function": "f2", "epoch": 1, "replaced": 2},
    {"t": 7.0, "robot": 1, "event": "fenced", "function": "f1", "epoch": 2},
    {"t": 9.0, "robot": 0, "event": "fault", "kind": "partition"},
    {"t": 9.5, "robot": 6, "event": "alert", "function": "f3", "reason": "no standby"},
]


def test_role_spans_follow_the_event_log() -> None:
    spans = role_spans(EVENTS, end=12.0)
    assert spans[2] == [Span(2, 0.0, 5.0, "active", "f2"), Span(2, 5.0, 12.0, "crashed", None)]
    assert [(s.role, s.function) for s in spans[6]] == [
        ("standby", None), ("claiming", "f2"), ("active", "f2")]
    assert spans[6][-1].start == 5.8 and spans[6][-1].end == 12.0
    # fenced lasts FENCE_SHOW, then the robot is a standby again
    assert [(s.role, s.start, s.end) for s in spans[1]] == [
        ("active", 0.0, 7.0), ("fenced", 7.0, 8.0), ("standby", 8.0, 12.0)]
    assert 0 not in spans
    span = role_at(spans[6], 5.5)
    assert span is not None and span.role == "claiming"
    assert role_at(spans[6], 20.0) is None


def test_restart_after_a_crash_and_stop() -> None:
    spans = role_spans([
        {"t": 0, "robot": 3, "event": "started", "role": "ACTIVE", "function": "f3"},
        {"t": 2, "robot": 3, "event": "fault", "kind": "crash"},
        {"t": 3, "robot": 3, "event": "takeover", "function": "f3", "epoch": 1},  # ignored
        {"t": 4, "robot": 3, "event": "started", "role": "inactive", "function": None},
        {"t": 6, "robot": 3, "event": "stopped"},
    ], end=10.0)
    assert [(s.role, s.start, s.end) for s in spans[3]] == [
        ("active", 0, 2), ("crashed", 2, 4), ("standby", 4, 6)]


def _png_size(path: Path) -> tuple[int, int]:
    with Image.open(path) as im:
        im.verify()
    with Image.open(path) as im:
        assert im.format == "PNG"
        return im.size


def test_timeline_png_is_a_valid_image(tmp_path: Path) -> None:
    path = timeline_png(EVENTS, tmp_path / "out" / "timeline.png", end=12.0)
    w, h = _png_size(path)
    assert w == 1200 and h > 200


def test_timeline_of_an_empty_log(tmp_path: Path) -> None:
    w, _h = _png_size(timeline_png([], tmp_path / "t.png"))
    assert w == 1200


def test_trajectory_png_is_a_valid_image(tmp_path: Path) -> None:
    robots = [QuadRobot(1, (-1.0, -3.0, 0.0)), QuadRobot(2, (1.0, -3.0, 0.0))]
    functions: dict[str, dict[str, Any]] = {
        "f1": {"kind": "slot", "position": [0.0, 0.0, 1.0]},
        "f2": {"kind": "patrol", "waypoints": [[-2, 2, 1], [2, 2, 1], [0, 4, 1]], "speed": 1},
    }
    robots[0].assign("f1", functions["f1"])
    robots[1].assign("f2", functions["f2"])
    for r in robots:
        r.step_until(3.0)
    path = trajectory_png([trajectory_of(r) for r in robots], tmp_path / "traj.png", functions)
    assert _png_size(path) == (800, 800)
