"""Pictures of a run: a timeline of roles and functions, and a top-down
trajectory plot. matplotlib with the Agg backend (no display needed).

The timeline is drawn from the event log alone (DESIGN section 3: JSON Lines records,
read back through `swarmd.core.events`), so it works for `--virtual` runs without physics
too.
`role_spans` turns the log into per-robot spans of (role, function), from the one fold of
the log (`sim.shared.holders`); `render` colours the crafts of the video with the same
spans.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sim.shared.faults import FaultKind
from sim.shared.holders import HolderFold
from swarmd.core.events import Alert, Claim, Event, Fault, Suspect, Takeover, event_of

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

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
        rid, t = int(e["robot"]), float(e.get("t", 0.0))
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
    """Title, lay out, write the PNG (creating its folder) and free the figure."""
    import matplotlib.pyplot as plt

    ax.set_title(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


_MARKERS: dict[type[Event], tuple[str, str, str]] = {
    # event -> (marker, colour, which robot's lane: the event's robot or its subject)
    Fault: ("X", "#d62728", "robot"),
    Suspect: ("v", "#9467bd", "subject"),
    Claim: ("o", "#ff7f0e", "robot"),
    Takeover: ("*", "#1f77b4", "robot"),
    Alert: ("!", "#d62728", "robot"),
}


def timeline_png(
    events: Sequence[Mapping[str, Any]],
    path: Path,
    *,
    end: float | None = None,
    title: str | None = None,
) -> Path:
    """One lane per robot: bars coloured by role with the function written on them;
    markers for faults (X, with the kind), suspicions (v, on the suspect's lane),
    claims (o), takeovers (*, with `fN eK`) and alerts."""
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
    fig, ax = plt.subplots(figsize=(12, 1.2 + 0.6 * max(1, len(robots))), dpi=100)
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
    return _save(fig, ax, title or "roles and functions over time", path)


def _draw_marker(ax: Axes, e: Mapping[str, Any], lane: Mapping[int, int]) -> None:
    """The event's marker on its robot's lane (`_MARKERS`), if it has one."""
    event = event_of(e)
    if event is None or type(event) not in _MARKERS:
        return
    marker, colour, which = _MARKERS[type(event)]
    who = e.get("subject") if which == "subject" else e.get("robot")
    if not isinstance(who, int) or who not in lane:
        if isinstance(event, Fault):  # robot 0: a partition; draw it across the chart
            ax.axvline(float(e.get("t", 0.0)), color=colour, linestyle=":", linewidth=1)
        return
    t = float(e.get("t", 0.0))
    y = lane[who] + 0.38  # just below the bar (the y axis is inverted)
    if marker == "!":
        ax.text(t, y, "!", color=colour, fontsize=12, fontweight="bold", ha="center")
    else:
        ax.plot([t], [y], marker=marker, color=colour, markersize=8 if marker == "*" else 6,
                linestyle="none")
    match event:
        case Fault(kind=kind):
            ax.text(t, y + 0.15, str(kind), fontsize=7, color=colour, ha="left")
        case Takeover(function=function, epoch=epoch):
            ax.text(t, y + 0.15, f"{function} e{epoch}", fontsize=7, color=colour,
                    ha="left")


def _timeline_axes(ax: Axes, robots: Sequence[int], t_end: float) -> None:
    """The timeline's lanes, time axis and legend of roles and markers."""
    from matplotlib.artist import Artist
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    ax.set_yticks(range(len(robots)), [f"robot {r}" for r in robots])
    ax.set_ylim(-0.6, len(robots) - 0.2)
    ax.invert_yaxis()
    ax.set_xlim(0, max(t_end, 1e-3))
    ax.set_xlabel("time since the run's start (s)")
    ax.grid(axis="x", alpha=0.3)
    handles: list[Artist] = [Patch(color=c, label=r) for r, c in ROLE_COLORS.items()]
    handles += [
        Line2D([], [], marker=m, color=c, linestyle="none", label=n)
        for n, (m, c, _w) in _MARKERS.items() if m != "!"
    ]
    below = -0.18 - 0.3 / max(1, len(robots))
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, below),
              ncol=len(handles), fontsize=8, frameon=False)


def trajectory_png(
    trajectories: Sequence[Trajectory],
    path: Path,
    functions: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    title: str | None = None,
) -> Path:
    """Top-down (x, y) view: every robot's path from its home (square) to where it ended
    (dot); slots as circles and patrol loops as dashed polygons, named."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 8), dpi=100)
    cmap = plt.get_cmap("tab10")
    for name, spec in (functions or {}).items():
        _draw_function(ax, name, spec)
    for i, tr in enumerate(sorted(trajectories, key=lambda tr: tr.robot)):
        c = cmap(i % 10)
        ax.plot(tr.pos[:, 0], tr.pos[:, 1], color=c, linewidth=1.2, label=f"robot {tr.robot}")
        ax.plot([tr.home[0]], [tr.home[1]], marker="s", color=c, markersize=7)
        ax.plot([tr.pos[-1, 0]], [tr.pos[-1, 1]], marker="o", color=c, markersize=6)
        if tr.modes and tr.modes[-1] == "crashed":
            ax.plot([tr.pos[-1, 0]], [tr.pos[-1, 1]], marker="X", color="black", markersize=9)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    if trajectories:
        ax.legend(loc="best", fontsize=8)
    return _save(fig, ax, title or "top-down trajectories (square: home, dot: end, X: crashed)",
                 path)


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
