"""The words on the video's frames (sim/physics/labels.py): each craft's robot id and
function, and on an event's key frame its failed robot and substitute ringed. No GL
needed: frames here are plain arrays; tests/test_render.py checks a rendered one."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from sim.physics.labels import (
    FAILED,
    RING,
    SUBSTITUTE,
    CraftLabel,
    View,
    annotate,
    craft_labels,
    key_moments,
)
from sim.physics.plots import role_spans

# The demo's story (`make demo`): robot 2 crashes at 5 s, robot 6 claims and takes f2 over.
EVENTS: list[dict[str, Any]] = [
    *({"t": 0.0, "robot": r, "event": "started", "role": "active", "function": f"f{r}"}
      for r in (1, 2, 3, 4)),
    {"t": 0.0, "robot": 5, "event": "started", "role": "standby", "function": None},
    {"t": 0.0, "robot": 6, "event": "started", "role": "standby", "function": None},
    {"t": 5.0, "robot": 2, "event": "fault", "kind": "crash"},
    {"t": 5.4, "robot": 6, "event": "claim", "subject": 2, "function": "f2", "epoch": 1},
    {"t": 5.65, "robot": 6, "event": "takeover", "function": "f2", "epoch": 1, "replaced": 2},
]
ROBOTS = [1, 2, 3, 4, 5, 6]


def test_key_moments_name_the_failed_robot_and_its_substitute() -> None:
    fault, takeover = key_moments(EVENTS)
    assert (fault.t, fault.name, fault.failed, fault.substitute) == (
        5.0, "fault-crash-r2", (2,), ())
    assert "robot 2" in fault.caption and "crash" in fault.caption
    assert (takeover.name, takeover.failed, takeover.substitute) == (
        "takeover-f2-r6", (2,), (6,))
    assert takeover.caption == (
        "robot 6 (blue ring) took f2 over from robot 2 (red ring), epoch 1")


def test_each_craft_says_its_robot_and_function() -> None:
    spans = role_spans(EVENTS, end=15.0)
    at = {lab.robot: lab.text for lab in craft_labels(ROBOTS, spans, 2.0)}
    assert at == {1: "r1 f1", 2: "r2 f2", 3: "r3 f3", 4: "r4 f4", 5: "r5 standby",
                  6: "r6 standby"}
    claiming = {lab.robot: lab for lab in craft_labels(ROBOTS, spans, 5.5)}
    assert claiming[6].text == "r6 claims f2" and claiming[6].role == "claiming"
    assert claiming[2].text == "r2 crashed"
    assert all(lab.ring is None for lab in claiming.values())  # no moment: no rings


def test_the_takeover_still_rings_the_failed_craft_and_its_substitute() -> None:
    spans = role_spans(EVENTS, end=15.0)
    takeover = key_moments(EVENTS)[1]
    labels = {lab.robot: lab for lab in craft_labels(ROBOTS, spans, 6.15, takeover)}
    assert (labels[6].text, labels[6].ring) == ("r6 f2", SUBSTITUTE)
    assert (labels[2].text, labels[2].ring) == ("r2 crashed", FAILED)
    assert {r for r, lab in labels.items() if lab.ring is not None} == {2, 6}


def _camera(**kw: Any) -> SimpleNamespace:
    """A mjvGLCamera at the origin looking along +y, z up, 90 degrees across."""
    cam = {"pos": [0, 0, 0], "forward": [0, 1, 0], "up": [0, 0, 1], "frustum_near": 1.0,
           "frustum_top": 0.75, "frustum_bottom": -0.75, "frustum_center": 0.0,
           "frustum_width": 0.0}
    return SimpleNamespace(**{**cam, **kw})


def test_view_projects_world_points_to_pixels() -> None:
    view = View.of(_camera(), 640, 480)  # half width 0.5 * 640/480 * 1.5 = 1.0
    assert view.pixel((0, 5, 0)) == pytest.approx((320, 240))
    assert view.pixel((5, 5, 0)) == pytest.approx((640, 240))  # 45 degrees right: the edge
    col, row = view.pixel((0, 4, 1)) or (0, 0)
    assert col == pytest.approx(320) and row < 240  # above the axis: higher in the image
    assert view.pixel((0, -3, 0)) is None  # behind the camera


def _grey() -> np.ndarray[Any, Any]:
    return np.full((480, 640, 3), 128, dtype=np.uint8)


def test_labels_are_drawn_beside_their_crafts_and_rings_around_them() -> None:
    labels = [CraftLabel(2, "r2 crashed", "crashed", FAILED),
              CraftLabel(6, "r6 f2", "active", SUBSTITUTE),
              CraftLabel(5, "r5 standby", "standby")]
    pixels: list[tuple[float, float] | None] = [(200.0, 300.0), (420.0, 200.0), None]
    img, placed = annotate(_grey(), "t = 6.1 s", labels, pixels, "robot 6 took f2 over")
    assert [(p.robot, p.text) for p in placed] == [(2, "r2 crashed"), (6, "r6 f2")]
    plain, _ = annotate(_grey(), "t = 6.1 s")
    for p in placed:
        x0, y0, x1, y1 = p.box
        assert 0 <= x0 < x1 <= 640 and 0 <= y0 < y1 <= 480
        assert y1 <= p.at[1]  # above its craft
        assert (img[y0:y1, x0:x1] != plain[y0:y1, x0:x1]).any()  # the words are there
    for (col, row), colour in (((200, 300), FAILED), ((420, 200), SUBSTITUTE)):
        ring = img[row - 1:row + 2, col + RING - 2:col + RING + 1].reshape(-1, 3)
        assert any(tuple(px) == colour for px in ring), ring
    assert (img[-24:, :200] != plain[-24:, :200]).any()  # the caption


def test_labels_of_crafts_close_together_do_not_cover_each_other() -> None:
    labels = [CraftLabel(r, f"r{r} standby", "standby") for r in (1, 2, 3)]
    pixels: list[tuple[float, float] | None] = [(300.0, 200.0), (310.0, 204.0), (305.0, 208.0)]
    _img, placed = annotate(_grey(), "t", labels, pixels)
    for i, a in enumerate(placed):
        for b in placed[i + 1:]:
            apart = (a.box[2] <= b.box[0] or b.box[2] <= a.box[0]
                     or a.box[3] <= b.box[1] or b.box[3] <= a.box[1])
            assert apart, (a, b)


def test_a_label_does_not_cover_another_craft() -> None:
    # Robot 1's craft sits just above robot 2's, where robot 2's label would go.
    labels = [CraftLabel(1, "r1 f1", "active"), CraftLabel(2, "r2 standby", "standby")]
    pixels: list[tuple[float, float] | None] = [(300.0, 180.0), (300.0, 230.0)]
    _img, placed = annotate(_grey(), "t", labels, pixels)
    crafts = {1: (300, 180), 2: (300, 230)}
    for p in placed:
        for robot, (col, row) in crafts.items():
            if robot != p.robot:
                x0, y0, x1, y1 = p.box
                apart = x1 <= col - RING or col + RING <= x0 or y1 <= row - RING or \
                    row + RING <= y0
                assert apart, (p, robot)
