"""Pictures of a run: a timeline of roles and functions, and a top-down
trajectory plot. matplotlib with the Agg backend (no display needed).

The timeline is drawn from the event log alone (DESIGN section 3: JSON Lines records,
read back through `swarmd.core.events`), so it works for `--virtual` runs without physics
too.
`role_spans` turns the log into per-robot spans of (role, function), from the one fold of
the log (`sim.shared.holders`); `render` colours the crafts of the video with the same
spans.

Each picture says in words what its marks mean: the legends name roles and events as the
log names them and sit below the axes, wrapped to the figure's width (`fitted_legend`),
so that no swarm size pushes them off the picture; `timeline_figure` and
`trajectory_figure` return the figure unsaved, for tests to read its words back.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sim.shared.faults import FaultKind
from sim.shared.holders import HolderFold
from swarmd.core.events import Alert, Claim, Event, Fault, Suspect, Takeover, Warn, event_of

if TYPE_CHECKING:
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure
    from matplotlib.legend import Legend

    from sim.physics.robot import Trajectory

ROLE_COLORS: dict[str, str] = {
    "active": "#2ca02c",
    "standby": "#9e9e9e",
    "claiming": "#ff7f0e",
    "fenced": "#d62728",
    "crashed": "#000000",
}
"""Role colours shared by the timeline and the video (active green, standby grey,
claiming orange, fenced red, crashed black)."""

FENCE_SHOW = 1.0
"""s a FENCED span lasts when no later event ends it: the node rejoins as standby after
one heartbeat period and logs no event for that (roles.py FENCE_DONE)."""

DOWN_FAULTS: frozenset[str] = frozenset({FaultKind.CRASH, FaultKind.MOTOR, FaultKind.COLLIDE})
"""Injected faults after which the craft is down (black) until it starts again."""


@dataclass(frozen=True, slots=True)
class Span:
    """Robot `robot` had `role` (and executed `function`, if any) from start to end."""

    robot: int
    start: float
    end: float
    role: str
    function: str | None


def role_spans(
    events: Iterable[Mapping[str, Any]], end: float | None = None
) -> dict[int, list[Span]]:
    """Per robot, the spans of (role, function) the event log implies, in time order.

    The roles are `sim.shared.holders.HolderFold`'s (claiming shows the claimed function,
    fenced the one stopped), with a crash or motor failure shown as crashed until the
    robot starts again. Two things are drawn only here: fenced lasts FENCE_SHOW s and
    then the robot is a standby again; stopped ends the robot's lane (no span)."""
    evs = sorted(
        (e for e in events if isinstance(e.get("robot"), int) and e["robot"] > 0),
        key=lambda e: float(e.get("t", 0.0)),
    )
    t_end = end if end is not None else max((float(e.get("t", 0.0)) for e in evs), default=0.0)
    fold = HolderFold(down=DOWN_FAULTS)
    lanes = _Lanes()
    for e in evs:
        rid = int(e["robot"])
        t = float(e.get("t", 0.0))
        prev = lanes.state.get(rid)
        if prev is not None and prev[1] == "fenced" and t > prev[0] + FENCE_SHOW:
            lanes.enter(rid, prev[0] + FENCE_SHOW, "standby", None)
        holding = fold.feed(e)
        if holding is None:
            continue
        if holding.role == "stopped":
            lanes.close(rid, t)
        else:
            lanes.enter(rid, t, holding.role, holding.function)
    lanes.finish(t_end)
    return lanes.spans


@dataclass
class _Lanes:
    """`role_spans` under way: each robot's open span (since, role, function) and the
    spans already closed."""

    state: dict[int, tuple[float, str, str | None]] = field(default_factory=dict)
    spans: dict[int, list[Span]] = field(default_factory=dict)

    def close(self, rid: int, t: float) -> None:
        if rid in self.state:
            t0, role, fn = self.state.pop(rid)
            if t > t0:
                self.spans.setdefault(rid, []).append(Span(rid, t0, t, role, fn))

    def enter(self, rid: int, t: float, role: str, fn: str | None) -> None:
        prev = self.state.get(rid)
        if prev is not None and prev[1] == role and prev[2] == fn:
            return
        self.close(rid, t)
        self.state[rid] = (t, role, fn)

    def finish(self, t_end: float) -> None:
        """Close every open span at `t_end` (a fenced one after FENCE_SHOW)."""
        for rid, (t0, role, _fn) in list(self.state.items()):
            stop = t_end
            if role == "fenced":
                stop = min(t_end, t0 + FENCE_SHOW)
            self.close(rid, max(stop, t0))
            if role == "fenced" and stop < t_end:
                self.spans.setdefault(rid, []).append(Span(rid, stop, t_end, "standby", None))


def role_at(spans: Sequence[Span], t: float) -> Span | None:
    """The span covering time t (None before the first and after a stop)."""
    for s in spans:
        if s.start <= t < s.end:
            return s
    if spans and abs(t - spans[-1].end) < 1e-9:
        return spans[-1]
    return None


def _save(fig: Figure, ax: Axes, title: str, path: Path) -> Path:
    """Title, write the PNG (creating its folder) and free the figure."""
    import matplotlib.pyplot as plt

    ax.set_title(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


@dataclass(frozen=True, slots=True)
class Mark:
    """How the timeline marks one kind of event: `marker` and `colour`, on the lane of
    the event's own robot (`lane="robot"`) or of the robot it is about (`"subject"`),
    and what the legend says after the event's name (`note`)."""

    marker: str
    colour: str
    lane: str
    note: str = ""

    def label(self, event: type[Event]) -> str:
        """The legend entry: the event's name as the log spells it, then the note."""
        return f"{event.name} ({self.note})" if self.note else event.name


MARKS: dict[type[Event], Mark] = {
    Fault: Mark("X", "#d62728", "robot", "injected; its kind beside it"),
    Suspect: Mark("v", "#9467bd", "subject", "on the silent robot's lane"),
    Warn: Mark(">", "#8c564b", "robot", "by the warner"),
    Claim: Mark("o", "#ff7f0e", "robot"),
    Takeover: Mark("*", "#1f77b4", "robot", "fN eK: took slot fN at epoch K"),
    Alert: Mark("$!$", "#d62728", "robot", "nobody can take the slot"),
}
"""The events the timeline marks (paper Fig. 7-9: suspect, warn, claim, takeover;
DESIGN rule 8: alert); roles, fenced included, are the bars' colours."""


def timeline_png(
    events: Sequence[Mapping[str, Any]],
    path: Path,
    *,
    end: float | None = None,
    title: str | None = None,
) -> Path:
    """`timeline_figure` written to `path` as a PNG."""
    fig = timeline_figure(events, end=end)
    return _save(fig, fig.axes[0], title or TIMELINE_TITLE, path)


TIMELINE_TITLE = "roles and functions over time"


def timeline_figure(
    events: Sequence[Mapping[str, Any]], *, end: float | None = None
) -> Figure:
    """One lane per robot: bars coloured by role with the function written on them;
    the events of `MARKS` as markers (a fault's kind and a takeover's `fN eK` written
    beside them); below, a legend of the roles and the markers, wrapped into as many
    rows as the figure's width needs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spans = role_spans(events, end)
    robots = sorted(
        (set(spans) | {int(e["robot"]) for e in events if isinstance(e.get("robot"), int)})
        - {0}
    )
    t_end = end if end is not None else max((float(e.get("t", 0.0)) for e in events), default=1.0)
    lane = {rid: i for i, rid in enumerate(robots)}
    fig, ax = plt.subplots(figsize=(12, 1.4 + 0.6 * max(1, len(robots))), dpi=100,
                           layout="constrained")
    for rid, ss in spans.items():
        for s in ss:
            row = lane[rid]
            ax.barh(row, s.end - s.start, left=s.start, height=0.6,
                    color=ROLE_COLORS.get(s.role, "#cccccc"), edgecolor="white", linewidth=0.5)
            if s.function and s.end - s.start > 0.03 * max(t_end, 1e-9):
                ax.text((s.start + s.end) / 2, row, s.function, ha="center", va="center",
                        color="white", fontsize=8, fontweight="bold")
    for e in events:
        _draw_marker(ax, e, lane)
    _timeline_axes(ax, robots, t_end)
    _timeline_legend(fig)
    return fig


def _draw_marker(ax: Axes, e: Mapping[str, Any], lane: Mapping[int, int]) -> None:
    """The event's marker on its robot's lane (`MARKS`), if it has one."""
    event = event_of(e)
    mark = MARKS.get(type(event)) if event is not None else None
    if mark is None:
        return
    who = e.get("subject") if mark.lane == "subject" else e.get("robot")
    if not isinstance(who, int) or who not in lane:
        if isinstance(event, Fault):  # robot 0: a partition; draw it across the chart
            ax.axvline(float(e.get("t", 0.0)), color=mark.colour, linestyle=":", linewidth=1)
        return
    t = float(e.get("t", 0.0))
    y = lane[who] + 0.38  # just below the bar (the y axis is inverted)
    ax.plot([t], [y], marker=mark.marker, color=mark.colour,
            markersize=8 if mark.marker in ("*", "$!$") else 6, linestyle="none")
    match event:
        case Fault(kind=kind):
            ax.text(t, y + 0.15, str(kind), fontsize=7, color=mark.colour, ha="left")
        case Takeover(function=function, epoch=epoch):
            ax.text(t, y + 0.15, f"{function} e{epoch}", fontsize=7, color=mark.colour,
                    ha="left")


def _timeline_axes(ax: Axes, robots: Sequence[int], t_end: float) -> None:
    """The timeline's lanes and time axis."""
    ax.set_yticks(range(len(robots)), [f"robot {r}" for r in robots])
    ax.set_ylim(-0.6, len(robots) - 0.2)
    ax.invert_yaxis()
    ax.set_xlim(0, max(t_end, 1e-3))
    ax.set_xlabel("time since the run's start (s)")
    ax.grid(axis="x", alpha=0.3)


def _timeline_legend(fig: Figure) -> None:
    """The roles (bar colours) and `MARKS` (markers), named, below the lanes."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Artist] = [Patch(color=c, label=r) for r, c in ROLE_COLORS.items()]
    handles += [
        Line2D([], [], marker=m.marker, color=m.colour, linestyle="none", label=m.label(ev))
        for ev, m in MARKS.items()
    ]
    fitted_legend(fig, handles)


def fitted_legend(fig: Figure, handles: Sequence[Artist]) -> Legend:
    """A legend of `handles` below the axes (constrained layout makes room for it), in
    the most columns that keep it inside the figure's width, so it wraps into rows
    instead of being cut at the edges; the figure grows by the rows it takes."""
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    width = fig.bbox.width
    for ncol in range(len(handles), 0, -1):
        legend = fig.legend(handles=handles, loc="outside lower center", ncol=ncol,
                            fontsize=8, frameon=False)
        box = legend.get_window_extent(renderer)
        if box.width <= 0.96 * width or ncol == 1:
            break
        legend.remove()
    rows = math.ceil(len(handles) / ncol)
    fig.set_figheight(fig.get_figheight() + rows * 0.2)
    return legend


def trajectory_png(
    trajectories: Sequence[Trajectory],
    path: Path,
    functions: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    title: str | None = None,
) -> Path:
    """`trajectory_figure` written to `path` as a PNG."""
    fig = trajectory_figure(trajectories, functions)
    return _save(fig, fig.axes[0], title or TRAJECTORY_TITLE, path)


TRAJECTORY_TITLE = "top-down trajectories"

TRAJECTORY_KEY: tuple[tuple[str, str, str], ...] = (
    ("s", "none", "home (start)"),
    ("o", "none", "end, labelled rN fK: robot N flying function fK"),
    ("X", "black", "crashed"),
)
"""The trajectory plot's symbols (marker, fill, what the legend says)."""

ROBOT_COLOURS = 10
"""Robots the legend names by colour (tab10's colours); a bigger swarm repeats colours,
so there only the labels at the paths' ends tell robots apart."""


def trajectory_figure(
    trajectories: Sequence[Trajectory],
    functions: Mapping[str, Mapping[str, Any]] | None = None,
) -> Figure:
    """Top-down (x, y) view: every robot's path from its home (square) to where it ended
    (dot, labelled with the robot and the function it flew last); slots as circles and
    patrol loops as dashed polygons, named; a legend of the symbols below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, ax = plt.subplots(figsize=(8, 8), dpi=100, layout="constrained")
    cmap = plt.get_cmap("tab10")
    for name, spec in (functions or {}).items():
        _draw_function(ax, name, spec)
    ordered = sorted(trajectories, key=lambda tr: tr.robot)
    handles: list[Artist] = [
        Line2D([], [], marker=m, color="#555555", markerfacecolor=fill if fill != "none" else
               "#555555", linestyle="none", label=label) for m, fill, label in TRAJECTORY_KEY]
    ends: list[tuple[float, float]] = []
    for i, tr in enumerate(ordered):
        (line,) = ax.plot(tr.pos[:, 0], tr.pos[:, 1], color=cmap(i % 10), linewidth=1.2,
                          label=f"robot {tr.robot}")
        _path_ends(ax, tr, line.get_color(), ends, 8 if len(ordered) <= DENSE else 6)
        if len(ordered) <= ROBOT_COLOURS:
            handles.append(line)
    ax.margins(0.1)  # room for the labels of the outermost paths' ends
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    fitted_legend(fig, handles)
    return fig


def end_label(tr: Trajectory) -> str:
    """`rN fK` for robot N ending on function fK (`rN` alone without one, `rN crashed`)."""
    if len(tr.pos) == 0:
        return f"r{tr.robot}"
    if tr.modes and tr.modes[-1] == "crashed":
        return f"r{tr.robot} crashed"
    function = tr.functions[-1] if tr.functions else None
    return f"r{tr.robot} {function}" if function else f"r{tr.robot}"


def _path_ends(ax: Axes, tr: Trajectory, colour: Any, ends: list[tuple[float, float]],
               size: float) -> None:
    """The robot's home (square), its end (dot, X if crashed) and its `end_label`,
    written under the labels of the earlier robots in `ends` that ended at the same
    place (a substitute on the slot its crashed predecessor fell from)."""
    if len(tr.pos) == 0:
        return
    ax.plot([tr.home[0]], [tr.home[1]], marker="s", color=colour, markersize=7)
    x, y = float(tr.pos[-1, 0]), float(tr.pos[-1, 1])
    ax.plot([x], [y], marker="o", color=colour, markersize=6)
    if tr.modes and tr.modes[-1] == "crashed":
        ax.plot([x], [y], marker="X", color="black", markersize=9)
    below = sum(1 for ex, ey in ends if math.hypot(ex - x, ey - y) < SAME_PLACE)
    ends.append((x, y))
    ax.annotate(end_label(tr), (x, y), xytext=(6, -12 - 12 * below),
                textcoords="offset points", fontsize=size, color=colour, fontweight="bold",
                bbox={"boxstyle": "round,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8})


SAME_PLACE = 0.5
"""m within which two paths' ends share a place and their labels are stacked."""

DENSE = 12
"""Robots above which the end labels are written smaller (they sit closer together)."""


def _draw_function(ax: Axes, name: str, spec: Mapping[str, Any]) -> None:
    """A slot as a circle, a patrol loop as a dashed polygon, each named."""
    from matplotlib.patches import Circle

    kind = spec.get("kind", "slot")
    if kind == "slot" and "position" in spec:
        x, y = float(spec["position"][0]), float(spec["position"][1])
        ax.add_patch(Circle((x, y), 0.25, fill=False, color="#555555", linewidth=1.5))
        ax.text(x + 0.3, y + 0.3, name, fontsize=10, color="#333333")
    elif kind == "patrol" and spec.get("waypoints"):
        wps = [(float(w[0]), float(w[1])) for w in spec["waypoints"]]
        xs = [w[0] for w in wps] + [wps[0][0]]
        ys = [w[1] for w in wps] + [wps[0][1]]
        ax.plot(xs, ys, linestyle="--", color="#555555", linewidth=1.2)
        for i, (x, y) in enumerate(wps):
            ax.text(x, y, f" {name}:{i}", fontsize=8, color="#333333")
