"""Words on the video's frames: which robot each craft is and what it flies.

A frame of the replay (sim/physics/render.py) shows crafts coloured by role; this module
writes beside each craft its robot id and function (`r6 f2`, `r5 standby`, `r6 claims
f2`, `r2 crashed`: the roles of `sim.physics.plots.role_spans`, the timeline's), and on
a key frame named after an event rings the robots it is about: red the failed one, blue
its substitute, with a caption saying what happened. A key at the top names the
role colours.

The crafts' pixels come from the camera MuJoCo drew the frame with (`View`, built from
the scene's `mjvGLCamera`), so this module needs numpy and Pillow but never MuJoCo or GL:
the label drawing is tested without a GL backend.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.physics.plots import ROLE_COLORS, Span, role_at
from swarmd.core.events import Fault, Takeover, event_of

FAILED = (214, 39, 40)
"""Ring of the robot a key frame's event took down (the timeline's fault red)."""
SUBSTITUTE = (31, 119, 180)
"""Ring of the robot that took its function over (the timeline's takeover blue)."""
RING = 18
"""px: radius of a key frame's ring around a craft."""


@dataclass(frozen=True, slots=True)
class View:
    """The perspective camera a frame was drawn with, as MuJoCo's `mjvGLCamera` gives
    it (position, forward and up axes, near-plane frustum), and the image size."""

    pos: np.ndarray[Any, Any]
    forward: np.ndarray[Any, Any]
    up: np.ndarray[Any, Any]
    near: float
    top: float
    bottom: float
    center: float
    halfwidth: float
    width: int
    height: int

    @classmethod
    def of(cls, cam: Any, width: int, height: int) -> View:
        """From a `mjvGLCamera`. MuJoCo widens the frustum to the viewport's aspect
        when `frustum_width` is 0 (mjr_render), and so does this."""
        top, bottom = float(cam.frustum_top), float(cam.frustum_bottom)
        half = float(cam.frustum_width) or 0.5 * width / height * (top - bottom)
        return cls(np.array(cam.pos, dtype=float), np.array(cam.forward, dtype=float),
                   np.array(cam.up, dtype=float), float(cam.frustum_near), top, bottom,
                   float(cam.frustum_center), half, width, height)

    def pixel(self, point: Sequence[float] | np.ndarray[Any, Any]) -> tuple[float, float] | None:
        """(column, row) of a world point in the image; None behind the camera."""
        d = np.asarray(point, dtype=float) - self.pos
        depth = float(d @ self.forward)
        if depth <= self.near:
            return None
        right = np.cross(self.forward, self.up)
        x = float(d @ right) * self.near / depth
        y = float(d @ self.up) * self.near / depth
        col = (x - self.center + self.halfwidth) / (2 * self.halfwidth) * self.width
        row = (self.top - y) / (self.top - self.bottom) * self.height
        return col, row


@dataclass(frozen=True, slots=True)
class CraftLabel:
    """What a craft's label says and how it is drawn: its background is the role's
    colour; `ring` (an RGB) circles a craft a key frame is about."""

    robot: int
    text: str
    role: str
    ring: tuple[int, int, int] | None = None


def label_text(robot: int, span: Span | None) -> str:
    """`rN` and what robot N does: its function when active, else its role."""
    if span is None:
        return f"r{robot}"
    match span.role:
        case "active":
            return f"r{robot} {span.function}" if span.function else f"r{robot} active"
        case "claiming":
            return f"r{robot} claims {span.function}" if span.function else f"r{robot} claims"
        case role:
            return f"r{robot} {role}"


def craft_labels(robots: Sequence[int], spans: Mapping[int, Sequence[Span]], t: float,
                 moment: KeyMoment | None = None) -> list[CraftLabel]:
    """Each robot's label at run time `t`, ringed when `moment` is about it."""
    out = []
    for rid in robots:
        span = role_at(spans.get(rid, ()), t)
        ring = None
        if moment is not None and rid in moment.failed:
            ring = FAILED
        elif moment is not None and rid in moment.substitute:
            ring = SUBSTITUTE
        out.append(CraftLabel(rid, label_text(rid, span),
                              span.role if span is not None else "standby", ring))
    return out


@dataclass(frozen=True, slots=True)
class KeyMoment:
    """A moment worth a still: its time, the name its file carries, what the caption
    says, and the robots the event is about."""

    t: float
    name: str
    caption: str
    failed: tuple[int, ...] = ()
    substitute: tuple[int, ...] = ()


def key_moments(events: Sequence[Mapping[str, Any]]) -> list[KeyMoment]:
    """The faults (the faulty robot ringed red) and takeovers (the new holder blue, the
    robot it replaced red), in time order."""
    out = []
    for e in events:
        robot = e.get("robot")
        t = float(e.get("t", 0.0))
        rid = robot if isinstance(robot, int) and robot > 0 else None
        match event_of(e):
            case Fault(kind=kind):
                who = f"robot {rid} (red ring): " if rid is not None else ""
                out.append(KeyMoment(t, f"fault-{kind}-r{e.get('robot', '')}",
                                     f"{who}{kind} injected",
                                     failed=(rid,) if rid is not None else ()))
            case Takeover(function=function, epoch=epoch, replaced=replaced):
                gone = (replaced,) if isinstance(replaced, int) and replaced > 0 else ()
                was = f" from robot {replaced} (red ring)" if gone else ""
                out.append(KeyMoment(
                    t, f"takeover-{function}-r{e.get('robot', '')}",
                    f"robot {robot} (blue ring) took {function} over{was}, epoch {epoch}",
                    failed=gone, substitute=(rid,) if rid is not None else ()))
    return sorted(out, key=lambda m: m.t)


@dataclass(frozen=True, slots=True)
class Placed:
    """A label as drawn: its text, its box (left, top, right, bottom) and the craft's
    pixel (column, row) it names, the centre of its ring if it has one."""

    robot: int
    text: str
    box: tuple[int, int, int, int]
    at: tuple[int, int]


def _font(size: int) -> Any:
    """Pillow's built-in font at `size` px (the bitmap one where Pillow is too old to
    scale it)."""
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:
        return ImageFont.load_default()


def _rgb(hex_colour: str) -> tuple[int, int, int]:
    h = hex_colour.lstrip("#")
    return int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)


def annotate(img: np.ndarray[Any, Any], header: str, labels: Sequence[CraftLabel] = (),
             pixels: Sequence[tuple[float, float] | None] = (), caption: str | None = None
             ) -> tuple[np.ndarray[Any, Any], list[Placed]]:
    """The frame with `header` (top left), each craft's label beside its pixel (rings
    first, so a label is never hidden under one), the role key (top right) and
    `caption` (bottom left); and where each label went."""
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)
    font = _font(13)
    _boxed(draw, (4, 4), header, font, (255, 255, 255), (0, 0, 0))
    shown = [(lab, px) for lab, px in zip(labels, pixels, strict=True) if px is not None]
    for lab, (col, row) in shown:
        if lab.ring is not None:
            draw.ellipse((col - RING, row - RING, col + RING, row + RING), outline=lab.ring,
                         width=3)
    placed: list[Placed] = []
    crafts = [(c - RING, r - RING, c + RING, r + RING) for _lab, (c, r) in shown]
    for i, (lab, (col, row)) in sorted(enumerate(shown), key=lambda s: -s[1][1][1]):
        others = crafts[:i] + crafts[i + 1:]  # nearest craft first: it is the biggest
        placed.append(_place(draw, font, lab, col, row,
                             [*others, *(p.box for p in placed)], im.size))
    _role_key(draw, font, im.size)
    if caption:
        _boxed(draw, (4, im.size[1] - 24), caption, font, (255, 255, 255), (0, 0, 0))
    return np.asarray(im), placed


Box = tuple[float, float, float, float]
"""left, top, right, bottom in pixels."""


def _place(draw: Any, font: Any, lab: CraftLabel, col: float, row: float,
           taken: Sequence[Box], size: tuple[int, int]) -> Placed:
    """Draw `lab` next to its craft where it covers nothing in `taken` (the labels
    already drawn, the other crafts): just above the craft, else just below it, else
    above and moved up past what is in the way; always inside the image, clear of the
    header and the caption."""
    left, top, right, bottom = draw.textbbox((0, 0), lab.text, font=font)
    w, h = right - left + 8, bottom - top + 6
    x = int(min(max(col - w / 2, 0), size[0] - w))
    lo, hi = 28, size[1] - 28 - h

    def hits(y: float) -> list[Box]:
        return [b for b in taken if b[0] < x + w and x < b[2] and b[1] < y + h and y < b[3]]

    above, below = row - RING - 4 - h, row + RING + 4
    free = [y for y in (above, below) if lo <= y <= hi and not hits(y)]
    y = free[0] if free else above
    for _ in range(len(taken) if not free else 0):
        if not (hit := hits(y)):
            break
        y = min(b[1] for b in hit) - h - 1
    y = min(max(y, lo), hi)
    fill = _rgb(ROLE_COLORS.get(lab.role, "#cccccc"))
    ink = (0, 0, 0) if lab.role in ("standby", "claiming") else (255, 255, 255)
    # A dark edge keeps a grey standby label readable on the grey floor.
    edge, width = (lab.ring, 2) if lab.ring is not None else ((60, 60, 60), 1)
    box = _boxed(draw, (x, int(y)), lab.text, font, fill, ink, outline=edge, width=width)
    return Placed(lab.robot, lab.text, box, (round(col), round(row)))


def _boxed(draw: Any, at: tuple[int, int], text: str, font: Any,
           fill: tuple[int, int, int], ink: tuple[int, int, int],
           outline: tuple[int, int, int] | None = None, width: int = 0
           ) -> tuple[int, int, int, int]:
    """`text` on a filled box whose top left is `at`; the box drawn."""
    left, top, right, bottom = draw.textbbox((0, 0), text, font=font)
    box = (at[0], at[1], at[0] + right - left + 8, at[1] + bottom - top + 6)
    draw.rectangle(box, fill=fill, outline=outline, width=width)
    draw.text((at[0] + 4 - left, at[1] + 3 - top), text, fill=ink, font=font)
    return box


def _role_key(draw: Any, font: Any, size: tuple[int, int]) -> None:
    """The role colours, named, in one row at the top right."""
    x = size[0] - 4
    for role, colour in reversed(list(ROLE_COLORS.items())):
        left, top, right, _bottom = draw.textbbox((0, 0), role, font=font)
        x -= right - left + 22
        y = 4
        draw.rectangle((x, y, x + right - left + 20, y + 18), fill=(255, 255, 255))
        draw.rectangle((x + 3, y + 4, x + 13, y + 14), fill=_rgb(colour))
        draw.text((x + 16 - left, y + 3 - top), role, fill=(0, 0, 0), font=font)
