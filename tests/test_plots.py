"""Report pictures: the role timeline and the top-down trajectories (sim/physics/plots.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from PIL import Image

from sim.physics.plots import Span, role_at, role_spans, timeline_png, trajectory_png
from sim.physics.robot import QuadRobot, Trajectory, trajectory_of

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from matplotlib.legend import Legend

EVENTS: list[dict[str, Any]] = [
    {"t": 0.0, "robot": 1, "event": "started", "role": "active", "function": "f1"},
    {"t": 0.0, "robot": 2, "event": "started", "role": "active", "function": "f2"},
    {"t": 0.0, "robot": 6, "event": "started", "role": "standby", "function": None},
    {"t": 5.0, "robot": 2, "event": "fault", "kind": "motor"},
    {"t": 5.1, "robot": 2, "event": "leave", "function": "f2", "reason": "fault"},
    {"t": 5.2, "robot": 1, "event": "suspect", "subject": 2, "function": "f2"},
    {"t": 5.3, "robot": 6, "event": "claim", "subject": 2, "function": "f2", "epoch": 1},
    {"t": 5.8, "robot": 6, "event": "takeover", "function": "f2", "epoch": 1, "replaced": 2},
    {"t": 7.0, "robot": 1, "event": "fenced", "function": "f1", "epoch": 2},
    {"t": 9.0, "robot": 0, "event": "fault", "kind": "partition"},
    {"t": 9.5, "robot": 6, "event": "alert", "function": "f3", "reason": "no standby left"},
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
    w, h = _png_size(path)
    assert w == 800 and h >= 800  # taller by the legend's rows below the map


# -- the pictures' words --------------------------------------------------------------------
# Each figure is captured as it is saved (plt.close is where `timeline_png` and
# `trajectory_png` let go of it) and read back from its matplotlib objects: legend, labels,
# title, and where the legend lies in the saved image.

EVENT_NAMES = ("fault", "suspect", "warn", "claim", "takeover", "alert")
ROLES = ("active", "standby", "claiming", "fenced", "crashed")


def _swarm_events(n: int) -> list[dict[str, Any]]:
    """n robots, robots 1..n-1 active on f1..f(n-1), robot n standby; robot 2 crashes
    at 5 s and robot n takes f2 over; robot 1 is fenced, an alert is raised."""
    evs: list[dict[str, Any]] = [
        {"t": 0.0, "robot": r, "event": "started", "role": "active", "function": f"f{r}"}
        for r in range(1, n)]
    evs.append({"t": 0.0, "robot": n, "event": "started", "role": "standby", "function": None})
    evs += [
        {"t": 5.0, "robot": 2, "event": "fault", "kind": "crash"},
        {"t": 5.4, "robot": 1, "event": "suspect", "subject": 2, "function": "f2"},
        {"t": 5.4, "robot": 1, "event": "warn", "subject": 2, "function": "f2"},
        {"t": 5.5, "robot": n, "event": "claim", "subject": 2, "function": "f2", "epoch": 1},
        {"t": 5.7, "robot": n, "event": "takeover", "function": "f2", "epoch": 1,
         "replaced": 2},
        {"t": 8.0, "robot": 1, "event": "fenced", "function": "f1", "epoch": 3},
        {"t": 9.0, "robot": 3, "event": "alert", "function": "f9", "reason": "no standby"},
    ]
    return evs


def _saved(monkeypatch: pytest.MonkeyPatch, draw: Callable[[], Path]) -> tuple[Figure, Path]:
    """The figure `draw()` saved, kept open (plt.close recorded, not done), and its PNG."""
    import matplotlib.pyplot as plt

    kept: list[Figure] = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    path = draw()
    assert len(kept) == 1
    return kept[0], path


def _legends(fig: Figure) -> list[Legend]:
    found = list(fig.legends) + [ax.get_legend() for ax in fig.axes]
    return [leg for leg in found if leg is not None]


def _legend_texts(fig: Figure) -> list[str]:
    return [t.get_text() for leg in _legends(fig) for t in leg.get_texts()]


def _assert_legends_inside(fig: Figure, png: Path) -> None:
    """Every legend's box lies inside the saved image (which is the figure's box)."""
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    with Image.open(png) as im:
        w, h = im.size
    assert (w, h) == (round(fig.bbox.width), round(fig.bbox.height))
    assert _legends(fig), "no legend"
    for leg in _legends(fig):
        box = leg.get_window_extent(renderer)
        assert box.x0 >= 0 and box.y0 >= 0, (box, w, h)
        assert box.x1 <= w and box.y1 <= h, (box, w, h)


def test_timeline_legend_names_roles_and_events(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fig, _png = _saved(monkeypatch, lambda: timeline_png(
        _swarm_events(6), tmp_path / "timeline.png", end=12.0))
    texts = _legend_texts(fig)
    firsts = [t.split(" ")[0] for t in texts]
    for word in (*ROLES, *EVENT_NAMES):
        assert word in firsts, (word, texts)
    assert not any("<" in t or "class" in t for t in texts), texts


@pytest.mark.parametrize("robots", [1, 6, 32])
def test_timeline_legend_lies_inside_the_figure(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, robots: int) -> None:
    evs = _swarm_events(robots) if robots > 1 else EVENTS[:1]
    fig, png = _saved(monkeypatch, lambda: timeline_png(
        evs, tmp_path / "timeline.png", end=12.0, title="swarmd sim (real time)"))
    _assert_legends_inside(fig, png)
    ax = fig.axes[0]
    assert ax.get_title() == "swarmd sim (real time)"
    assert ax.get_xlabel() == "time since the run's start (s)"
    lanes = [t.get_text() for t in ax.get_yticklabels()]
    assert lanes == [f"robot {r}" for r in range(1, robots + 1)]


def test_timeline_explains_the_takeovers_epoch_label(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fig, _png = _saved(monkeypatch, lambda: timeline_png(
        _swarm_events(6), tmp_path / "timeline.png", end=12.0))
    drawn = [t.get_text() for t in fig.axes[0].texts]
    assert "f2 e1" in drawn and "crash" in drawn  # beside the takeover and the fault
    takeover = [t for t in _legend_texts(fig) if t.startswith("takeover")]
    assert len(takeover) == 1 and "fN eK" in takeover[0] and "epoch" in takeover[0]


def _flown(n: int) -> list[Trajectory]:
    """n robots in a row; robot 2 crashes on f2's slot and robot n ends there with f2."""
    slot = [0.0, 2.0, 1.5]
    out = []
    for r in range(1, n + 1):
        tr = trajectory_of(QuadRobot(r, (float(r) - n / 2, -3.0, 0.0)))
        fn = "f2" if r in (2, n) else f"f{r}" if r < n else None
        end = np.array([slot if r in (2, n) else [float(r) - n / 2, 0.0, 1.5]])
        out.append(Trajectory(r, np.array([0.0, 5.0]), np.vstack([tr.pos[:1], end]),
                              np.array([[1.0, 0, 0, 0]] * 2), ("parked", "crashed" if r == 2
                                                                  else "flying"),
                              (None, None if r == 2 else fn), tr.home))
    return out


@pytest.mark.parametrize("robots", [6, 32])
def test_trajectories_name_each_robot_at_its_end_inside_the_figure(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, robots: int) -> None:
    functions = {"f2": {"kind": "slot", "position": [0.0, 2.0, 1.5]}}
    fig, png = _saved(monkeypatch, lambda: trajectory_png(
        _flown(robots), tmp_path / "traj.png", functions))
    drawn = [t.get_text() for t in fig.axes[0].texts]
    assert "r2 crashed" in drawn and f"r{robots} f2" in drawn, drawn
    assert "r1 f1" in drawn
    for r in range(1, robots + 1):
        assert any(t.split(" ")[0] == f"r{r}" for t in drawn), (r, drawn)
    texts = " ".join(_legend_texts(fig))
    assert "home" in texts and "crashed" in texts and "end" in texts, texts
    _assert_legends_inside(fig, png)
    assert fig.axes[0].get_xlabel() == "x (m)" and fig.axes[0].get_title()
