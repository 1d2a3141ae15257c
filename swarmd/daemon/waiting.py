"""Who a starting robot waits for, said once in words a person can act on.

A robot started alone (the others not started yet, another swarm file, another
channel) hears nobody: after the start-up grace its watchdogs suspect the neighbours it
never heard (DESIGN rule 5) and, with no standby heard either, it raises rule 8's
`alert ... no standby left`. Those events are right and stay as they are; what the
person at the terminal lacks is why. So the daemon says at start which robots it must
hear (`Waiting.line`), says when it has heard them all, and, if the grace runs out
first, names the ones never heard and what to check (`Waiting.missing_line`).

The robots come from the plan alone, as `SwarmPlan.relevant` chooses what a robot
hears: the holders of the slots it covers, watches or is watched by (its neighbours),
and the standbys that cover those slots (rule 8 asks whether one is alive).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from swarmd.core.plan import SwarmPlan

log = logging.getLogger("swarmd.waiting")

CHECK_PERIOD = 0.25
"""s. How often the daemon looks at who it has heard, during the start-up grace."""


def _ids(robots: Iterable[int]) -> str:
    return ", ".join(map(str, sorted(robots)))


@dataclass(frozen=True, slots=True)
class Waiting:
    """The robots one robot must hear: `neighbours` (robot -> the slot it holds at
    start) and `standbys` (robot -> the nearby slots it covers)."""

    robot: int
    neighbours: Mapping[int, str]
    standbys: Mapping[int, tuple[str, ...]]

    @classmethod
    def of(cls, plan: SwarmPlan, robot: int) -> Waiting:
        mine = [f for f in plan.functions if robot in plan.covered_by(f)]
        near: list[str] = []
        for c in mine:
            for f in (c, *plan.watched(c), *plan.watched_by(c)):
                if f not in near:
                    near.append(f)
        neighbours: dict[int, str] = {}
        standbys: dict[int, list[str]] = {}
        for f in near:
            holder = plan.initial_holder(f)
            if holder is not None and holder != robot:
                neighbours[holder] = f
            for r in plan.covered_by(f):
                if r != robot and plan.robots[r].function is None:
                    standbys.setdefault(r, []).append(f)
        order = {f: i for i, f in enumerate(plan.functions)}
        return cls(robot, dict(sorted(neighbours.items())),
                   {r: tuple(sorted(fs, key=order.__getitem__))
                    for r, fs in sorted(standbys.items())})

    @property
    def robots(self) -> frozenset[int]:
        return frozenset(self.neighbours) | frozenset(self.standbys)

    def _words(self, robots: Iterable[int]) -> str:
        chosen = set(robots)
        parts = []
        near = [r for r in self.neighbours if r in chosen]
        if near:
            slots = ", ".join(self.neighbours[r] for r in near)
            who = "neighbours" if len(near) > 1 else "neighbour"
            parts.append(f"{_ids(near)} ({who}, holding {slots})")
        parts += [f"{r} (standby of {', '.join(self.standbys[r])})"
                  for r in self.standbys if r in chosen]
        return ", ".join(parts[:-1]) + (" and " if len(parts) > 1 else "") + parts[-1]

    def line(self) -> str:
        """`waiting for robots 1, 3 (neighbours, holding f1, f3) and 5, 6 (standbys of
        f1, f2, f3)`; an empty string for a robot that waits for nobody."""
        if not self.robots:
            return ""
        return f"waiting for robot{'s' if len(self.robots) > 1 else ''} " \
            f"{self._words(self.robots)}"

    def missing_line(self, missing: Iterable[int], grace: float, channel: str) -> str:
        """What to do about the robots never heard within the start-up grace."""
        missing = set(missing)
        return (f"never heard robot{'s' if len(missing) > 1 else ''} "
                f"{self._words(missing)} within the start-up grace of "
                f"{grace:g} s: start them (swarmd start on each), or check that they use "
                f"the same swarm file and channel ({channel}). Until they are heard their "
                "slots are suspected, and alerted when no standby is heard (DESIGN rules "
                "5 and 8)")


def describe_channel(transport: Any) -> str:
    """The channel of a robot file's `transport` in a few words."""
    kind = getattr(transport, "kind", "udp")
    if kind == "udp":
        return (f"udp {getattr(transport, 'group', '?')}:{getattr(transport, 'port', '?')} "
                f"on {getattr(transport, 'interface', '?')}")
    return f"{kind} {getattr(transport, 'port', '?')}"


async def report_waiting(waiting: Waiting, heard: Callable[[], Iterable[int]], *,
                         grace: float, channel: str,
                         clock: Callable[[], float] | None = None) -> None:
    """Log whom the robot waits for, then either that it heard them all or, once the
    start-up grace is over, the ones it never heard (a warning, once). `heard()` gives
    the robots heard so far."""
    first = waiting.line()
    if not first:
        return
    log.info(first, extra={"robots": sorted(waiting.robots)})
    now = clock or asyncio.get_running_loop().time
    end = now() + grace
    while True:
        missing = waiting.robots - set(heard())
        if not missing:
            log.info("heard every robot it waits for", extra={
                "robots": sorted(waiting.robots)})
            return
        if now() >= end:
            log.warning(waiting.missing_line(missing, grace, channel),
                        extra={"never_heard": sorted(missing)})
            return
        await asyncio.sleep(min(CHECK_PERIOD, max(0.0, end - now())))
