"""The live view of a real-time run: one line per robot (process, role, function, epoch,
last event), folded from the merged events and drawn as a rich table while the run goes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sim.shared.faults import FaultKind
from sim.shared.holders import HolderFold
from swarmd.core.events import Fault, Started, Stopped, event_of

_PROCESS_AFTER: dict[str, str] = {
    FaultKind.CRASH: "killed", FaultKind.PAUSE: "paused", FaultKind.RESTART: "restarting",
    FaultKind.LEAVE: "leaving", FaultKind.COLLIDE: "collided"}
"""The process column after a fault of each kind (the others leave it as it was)."""


@dataclass(slots=True)
class RobotView:
    """One robot's line in the live table, folded from its events."""

    role: str = "?"
    function: str | None = None
    epoch: int | None = None
    process: str = "starting"
    last_event: str = ""
    last_t: float = 0.0


class SwarmView:
    """Folds events into the per-robot view shown live (role, function, last event).

    Role, function and epoch come from the one fold of the log (`sim.shared.holders`); the
    process column from the injected faults, which only the orchestrator knows."""

    def __init__(self, robots: Sequence[int]) -> None:
        self.robots = {r: RobotView() for r in robots}
        self.fold = HolderFold()

    def feed(self, rec: dict[str, Any]) -> None:
        view = self.robots.get(int(rec.get("robot", 0)))
        if view is None:
            return
        holding = self.fold.feed(rec)
        if holding is not None:
            # The process column says killed or stopped; the role column shows none.
            view.role = "-" if holding.role in ("crashed", "stopped") else holding.role.upper()
            view.function = holding.executing
            view.epoch = holding.epoch if holding.role in ("active", "claiming") else None
        event = event_of(rec)
        match event:
            case Started():
                view.process = "running"
            case Stopped():
                view.process = "stopped"
            case Fault(kind=kind):
                view.process = _PROCESS_AFTER.get(kind, view.process)
        view.last_event = ("" if event is None else f"fault {event.kind}"
                           if isinstance(event, Fault) else event.name)
        view.last_t = float(rec.get("t", 0.0))

    def set_process(self, robot: int, process: str) -> None:
        """The process column of `robot`, for what only the orchestrator sees (an exit,
        a resume)."""
        view = self.robots.get(robot)
        if view is not None:
            view.process = process

    def table(self, now: float) -> Any:
        """A rich Table of the swarm at run time `now`."""
        from rich.table import Table

        table = Table(title=f"swarmd sim (real time)  t = {now:6.1f} s")
        for col in ("robot", "process", "role", "function", "epoch", "last event", "at"):
            table.add_column(col)
        for rid, v in sorted(self.robots.items()):
            table.add_row(str(rid), v.process, v.role, v.function or "-",
                          "-" if v.epoch is None else str(v.epoch), v.last_event,
                          f"{v.last_t:.2f}")
        return table
