"""Who executes what: the event log folded into each robot's role and function.

Theory of operation
-------------------
The event log (DESIGN section 3; its records are `swarmd.core.events`) tells, robot by robot,
what the node did; `HolderFold` reads each record back as its typed event
(`Event.from_record`) and replays them into one `Holding` per robot, the role the
node is in (roles.py: active, standby, claiming, fenced) and the function that role is
about. Every reader of "who holds what" uses this one fold: the invariant checker
(`Checker.executing`), the summary (holder when a fault hit, holders at the end), the
timeline and the video colours (`sim.physics.plots.role_spans`) and the live table
(`sim.realtime.view.SwarmView`).

The transitions, by event (the node's own, roles.py TRANSITIONS):
  started{role,function} -> that role; it executes `function` only when active
  claim{function,epoch}  -> claiming `function` at `epoch`
  backoff                -> standby (BACKOFF / SUPERSEDED)
  refute{function}       -> standby when the robot was claiming `function` and the
                            suspect was heard alive (REFUTED); other refutes change nothing
  takeover{function,epoch} -> active, executing `function`
  fenced{function}       -> fenced: it stopped `function` (rule 2)
  leave                  -> standby (rule 7; a graceful stop logs `stopped` next)
  stopped                -> stopped: the node is gone
  fault{kind} in `down`  -> crashed: nothing the robot logs counts until it starts again
  fault{unhealthy|motor} -> a claim is dropped silently (FAULT from CLAIMING, no event)

Which injected faults take a robot down is the caller's choice: a crash kills the
process; a motor failure grounds the craft (the video shows it black) while the process
lives on and leaves by itself. The invariant checker passes none: it takes faults from
the injector's list, never from the log (see sim/shared/invariants.py).

The fold is per robot on purpose: two robots can hold one function (a stale holder
before it is fenced), and `holders()` lists them all rather than picking one.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from sim.shared.faults import FaultKind
from swarmd.core.events import (
    Backoff,
    Claim,
    Event,
    Fault,
    Fenced,
    Leave,
    Refute,
    Started,
    Stopped,
    Takeover,
    event_of,
)

CRASH: frozenset[str] = frozenset({FaultKind.CRASH, FaultKind.COLLIDE})
"""The default `down` faults: a crashed process logs nothing more until it restarts; a
collided craft is down whether its process lives on (physics) or not."""

_SILENT_FAULTS = frozenset({FaultKind.UNHEALTHY, FaultKind.MOTOR})
"""Injected health faults: a claiming node drops its claim without an event (node.py
robot_health); an active one logs `leave` itself."""


@dataclass(frozen=True, slots=True)
class Holding:
    """One robot's role and the function it is about.

    `function`: active -> the function it executes; claiming -> the one it claims;
    fenced -> the one it just stopped; otherwise None. `epoch`: of a takeover or claim,
    when the event told it."""

    role: str
    function: str | None = None
    epoch: int | None = None

    @property
    def executing(self) -> str | None:
        """The function the robot executes now (only an active robot executes)."""
        return self.function if self.role == "active" else None


STANDBY = Holding("standby")


def role_name(value: Any) -> str:
    """A role as the event log may spell it (`active`, `ACTIVE`, `Role.ACTIVE`, the
    paper's `inactive`), normalised to roles.py's lower-case names."""
    name = str(value).lower()
    if name.startswith("role."):
        name = name[5:]
    return "standby" if name == "inactive" else name


def _function(fn: Any) -> str | None:
    return None if fn is None else str(fn)


def _epoch(epoch: Any) -> int | None:
    return epoch if isinstance(epoch, int) else None


def _next(prev: Holding | None, event: Event, down: frozenset[str]) -> Holding | None:
    """The robot's holding after `event`, or None when the event changes nothing."""
    if prev is not None and prev.role == "crashed" and not isinstance(event, Started | Stopped):
        return None  # a downed robot's stray events do not bring it back
    match event:
        case Started(role=role_value, function=fn):
            role = role_name(role_value)
            return Holding(role, _function(fn) if role == "active" else None)
        case Claim(function=fn, epoch=epoch):
            return Holding("claiming", _function(fn), _epoch(epoch))
        case Backoff() | Leave():
            return STANDBY
        case Refute(function=fn):
            # A claimant that hears the suspect alive gives up its claim (REFUTED);
            # watchers and the suspect itself refute too, and stay what they were.
            if prev is not None and prev.role == "claiming" and prev.function == _function(fn):
                return STANDBY
            return None
        case Takeover(function=fn, epoch=epoch):
            return Holding("active", _function(fn), _epoch(epoch))
        case Fenced(function=fn):
            return Holding("fenced", _function(fn))
        case Stopped():
            return Holding("stopped")
        case Fault(kind=kind):
            if str(kind) in down:
                return Holding("crashed")
            if str(kind) in _SILENT_FAULTS and prev is not None and prev.role == "claiming":
                return STANDBY
            return None
        case _:
            return None


class HolderFold:
    """Events in (one at a time, in time order), each robot's `Holding` out."""

    __slots__ = ("down", "robots")

    def __init__(self, down: Iterable[str] = CRASH) -> None:
        self.down = frozenset(down)
        self.robots: dict[int, Holding] = {}

    def feed(self, rec: Mapping[str, Any]) -> Holding | None:
        """Apply one event record; the robot's new holding if it changed, else None.
        Records of robot 0 (a partition) or without a robot id change nothing, nor do
        records that are no event (`Event.from_record` refuses them)."""
        robot = rec.get("robot")
        if not isinstance(robot, int) or isinstance(robot, bool) or robot <= 0:
            return None
        event = event_of(rec)
        if event is None:
            return None  # no event of the contract: nothing the fold can read
        prev = self.robots.get(robot)
        new = _next(prev, event, self.down)
        if new is None or new == prev:
            return None
        self.robots[robot] = new
        return new

    def feed_all(self, events: Iterable[Mapping[str, Any]]) -> HolderFold:
        """Apply every record in order; returns self."""
        for rec in events:
            self.feed(rec)
        return self

    def forget(self, robot: int) -> None:
        """The robot is gone by a means the log does not tell (the checker's injected
        crash): it holds nothing until its next event."""
        self.robots.pop(robot, None)

    def executing(self) -> dict[int, str]:
        """robot -> the function it executes, for every active robot."""
        return {r: h.function for r, h in self.robots.items()
                if h.role == "active" and h.function is not None}

    def holders(self, exclude: Iterable[int] = ()) -> dict[str, list[int]]:
        """function -> every robot executing it (sorted), functions sorted; `exclude`
        drops robots known dead."""
        skip = set(exclude)
        out: dict[str, list[int]] = {}
        for r, f in sorted(self.executing().items()):
            if r not in skip:
                out.setdefault(f, []).append(r)
        return dict(sorted(out.items()))
