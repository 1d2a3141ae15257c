"""Rendering the swarm from recorded trajectories (sim/physics/render.py).

Skips with the reason where no headless GL backend loads (CI installs libegl1,
libegl-mesa0, libgl1-mesa-dri and libosmesa6: scripts/system-deps.sh)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import imageio.v3 as iio
import numpy as np
import pytest
from PIL import Image

from sim.physics.labels import FAILED, RING, SUBSTITUTE, _rgb
from sim.physics.plots import ROLE_COLORS
from sim.physics.render import RenderResult, gl_available, key_times, render_swarm
from sim.physics.robot import QuadRobot, trajectory_of

EVENTS = [
    {"t": 0.0, "robot": 1, "event": "started", "role": "active", "function": "f1"},
    {"t": 0.0, "robot": 2, "event": "started", "role": "standby", "function": None},
    {"t": 1.0, "robot": 1, "event": "fault", "kind": "motor"},
    {"t": 1.5, "robot": 2, "event": "takeover", "function": "f1", "epoch": 1, "replaced": 1},
]


def test_key_times_are_faults_and_takeovers() -> None:
    assert key_times(EVENTS) == [(1.0, "fault-motor-r1"), (1.5, "takeover-f1-r2")]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> RenderResult:
    """Robot 1 flies f1, its motor fails at 1 s; robot 2 takes f1 over at 1.5 s."""
    ok, why = gl_available()
    if not ok:
        pytest.skip(why)
    a, b = QuadRobot(1, (0.0, 0.0, 0.0)), QuadRobot(2, (1.5, 0.0, 0.0))
    a.assign("f1", {"kind": "slot", "position": [0.0, 1.0, 1.0]})
    a.step_until(1.0)
    a.fail_motor(0)
    b.step_until(1.5)
    b.assign("f1", {"kind": "slot", "position": [0.0, 1.0, 1.0]})
    a.step_until(2.5)
    b.step_until(2.5)
    return render_swarm([trajectory_of(a), trajectory_of(b)], EVENTS,
                        tmp_path_factory.mktemp("render"), fps=10)


def test_render_writes_a_video_and_keyframes(rendered: RenderResult) -> None:
    res = rendered
    assert res.error is None, res.error
    assert res.frames == 26  # 2.5 s at 10 fps, both ends
    assert res.video is not None and res.video.stat().st_size > 1000
    frames = iio.imread(res.video, index=None)
    assert frames.shape[1:] == (480, 640, 3)
    assert len(res.keyframes) == 4  # start, fault, takeover, end
    for p in res.keyframes:
        with Image.open(p) as im:
            assert im.size == (640, 480)
            # not a blank frame: the floor's checker and the crafts give contrast
            lo, hi = im.convert("L").getextrema()
            assert isinstance(lo, int) and isinstance(hi, int) and hi - lo > 50


def _pixels(path: Path) -> np.ndarray[Any, Any]:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def test_keyframes_label_each_craft_and_ring_the_takeovers_robots(
        rendered: RenderResult) -> None:
    res = rendered
    assert res.error is None, res.error
    still = next(p for p in res.keyframes if p.name.endswith("takeover-f1-r2.png"))
    labels = {lab["robot"]: lab for lab in res.labels[still]}
    assert labels[2]["text"] == "r2 f1" and labels[1]["text"] == "r1 crashed"
    img = _pixels(still)
    for lab, role in ((labels[2], "active"), (labels[1], "crashed")):
        x0, y0, x1, y1 = lab["box"]
        fill = np.array(_rgb(ROLE_COLORS[role]))
        drawn = (img[y0:y1, x0:x1] == fill).all(axis=-1).mean()
        assert drawn > 0.4, (lab, drawn)  # the box is there, in the role's colour
    for robot, ring in ((1, FAILED), (2, SUBSTITUTE)):
        col, row = labels[robot]["at"]
        around = img[row - RING - 1:row + RING + 2, col - RING - 1:col + RING + 2]
        assert (around == np.array(ring)).all(axis=-1).sum() > 20, robot


def test_video_frames_label_the_crafts(rendered: RenderResult) -> None:
    res = rendered
    assert res.error is None and res.video is not None, res.error
    start = next(p for p in res.keyframes if p.name.endswith("start.png"))
    first = iio.imread(res.video, index=0)  # the start: the same instant as the still
    for lab in res.labels[start]:
        x0, y0, x1, y1 = lab["box"]
        still = _pixels(start)[y0:y1, x0:x1].astype(float)
        # lossy video: the same box of colour and words, not the same bytes
        assert abs(first[y0:y1, x0:x1].astype(float) - still).mean() < 25, lab


def test_no_backend_is_an_error_not_an_exception(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sim.physics.render.gl_available", lambda: (False, "no GL here"))
    res = render_swarm([], [], tmp_path)
    assert res.error == "no GL here" and res.video is None


def test_a_killed_robot_is_drawn_falling_to_the_ground() -> None:
    from sim.physics.render import _with_fall

    a = QuadRobot(2, (0.0, 0.0, 0.0))
    a.assign("f2", {"kind": "slot", "position": [0.0, 1.0, 1.5]})
    a.step_until(3.0)
    tr = trajectory_of(a)
    end = float(tr.t[-1])
    assert tr.pos[-1][2] > 1.0  # in the air when its process died
    crash = [{"t": end + 0.01, "robot": 2, "event": "fault", "kind": "crash"}]
    fell = _with_fall(tr, crash)
    assert fell.pos[-1][2] == pytest.approx(tr.pos[0][2])  # on the ground it started on
    assert fell.modes[-1] == "crashed"
    assert list(fell.pos[-1][:2]) == list(tr.pos[-1][:2])  # straight down
    assert all(b > a for a, b in zip(fell.t, fell.t[1:], strict=False))
    # Free fall from ~1.5 m: about 0.55 s.
    assert 0.4 < fell.t[-1] - end < 0.7
    # Not for a robot alive to the end, or one killed long before its samples end.
    assert _with_fall(tr, []) is tr
    assert _with_fall(tr, [{**crash[0], "t": 0.5}]) is tr
