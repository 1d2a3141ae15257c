"""The swarm as diagnostic statuses: what a daemon (or the base station) publishes on
/diagnostics for rqt_robot_monitor and `ros2 topic echo` (docs/ros2.md).

Pure data, no rclpy: one `Status` per function the publisher knows and hears, named
`swarmd/<swarm>/<function>`, plus the publisher's own `swarmd/<swarm>/robot<id>`.
`hardware_id` is the publisher (`robot<id>`), so a listener tells the views apart.
Levels follow diagnostic_msgs: OK the holder is heard; WARN a suspicion or a claim is
under way (Figs. 7-9); ERROR an alert (no standby left, DESIGN rule 8); STALE the holder
has not been heard for t_max. The daemon reads its node only through `Node.snapshot()`
and its typed events (`swarmd.core.events`, DESIGN section 3).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from swarmd.core.events import (
    Alert,
    Backoff,
    Claim,
    Event,
    Fenced,
    Leave,
    Started,
    Stopped,
    Takeover,
)
from swarmd.core.plan import SwarmPlan
from swarmd.core.records import Snapshot
from swarmd.core.roles import Health, Role

OK, WARN, ERROR, STALE = 0, 1, 2, 3
"""diagnostic_msgs/DiagnosticStatus levels."""

LEVEL_OF_HEALTH = {Health.OK: OK, Health.DEGRADED: WARN, Health.FAULTY: ERROR}


@dataclass(frozen=True, slots=True)
class Status:
    """One DiagnosticStatus as plain data."""

    level: int
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


def status_prefix(swarm_name: str) -> str:
    return f"swarmd/{swarm_name}/"


class SwarmStatus:
    """A daemon's view of its neighbourhood, built from snapshots and events."""

    def __init__(self, plan: SwarmPlan, robot_id: int, swarm_name: str, t_max: float) -> None:
        self.plan = plan
        self.robot_id = robot_id
        self.prefix = status_prefix(swarm_name)
        self.hardware_id = f"robot{robot_id}"
        self.t_max = t_max
        slots = plan.relevant(robot_id).slots
        # Only the slots this robot hears ("What a robot hears"): of any other it knows
        # the plan's holder forever, and a listener would see it STALE from every robot.
        self.functions = tuple(f for f in plan.functions if plan.slot(f) in slots)
        self.alerts: dict[str, tuple[str, tuple[int, int] | None]] = {}
        """function -> (reason, the holder and epoch known when the alert came)."""
        self.claiming: set[str] = set()
        self.known: Mapping[str, tuple[int, int]] = {}

    def on_event(self, event: Event) -> bool:
        """Fold one event; True when it may change a status (publish now)."""
        function = getattr(event, "function", None)
        if not isinstance(function, str):
            return isinstance(event, Started | Stopped | Fenced | Leave)
        match event:
            case Alert(reason=reason):
                self.alerts[function] = (str(reason), self.known.get(function))
            case Claim():
                self.claiming.add(function)
            case Takeover() | Backoff():
                self.claiming.discard(function)
                self.alerts.pop(function, None)
        return True

    def statuses(self, snap: Snapshot, now: float,
                 stack: tuple[int, str] | None = None) -> list[Status]:
        """Every status, for the snapshot taken at `now` (the node's clock). `stack`:
        what the link knows of the robot's own stack when it does not execute what the
        daemon holds (waiting for it, never heard, faulty): its own function is then
        shown at that level, never OK (a function nobody executes)."""
        self.known = {f: (int(h[0]), int(h[1])) for f, h in snap.known.items()}
        role = snap.role.name.lower()
        out = []
        for f in self.functions:
            held = self.known.get(f)
            if held is None:
                continue
            holder, epoch = held
            alert = self.alerts.get(f)
            if alert is not None and alert[1] != held:
                del self.alerts[f]  # a new holder since: the alert is answered
                alert = None
            mine = snap.function == f and snap.role == Role.ACTIVE
            heard_at = snap.heard.get(holder, -math.inf)
            if alert is not None:
                level, message = ERROR, alert[0]
            elif f in snap.suspects or snap.votes.get(f) or f in self.claiming:
                level, message = WARN, "suspected: a takeover may be under way"
            elif mine and stack is not None:
                level, message = stack[0], f"held by robot {holder}: {stack[1]}"
            elif mine or now - heard_at <= self.t_max:
                level, message = OK, f"held by robot {holder}"
            else:
                level, message = STALE, f"robot {holder} not heard"
            out.append(Status(level, self.prefix + f, message, self.hardware_id,
                              (("holder", str(holder)), ("epoch", str(epoch)),
                               ("role", role))))
        out.append(self._own(snap, role, stack))
        return out

    def _own(self, snap: Snapshot, role: str, stack: tuple[int, str] | None) -> Status:
        """The publisher's own status: its role, function and health (and, when the link
        knows its robot does not execute, why)."""
        level = LEVEL_OF_HEALTH.get(snap.health, ERROR)
        message = f"{role} {snap.function or ''}".strip()
        if stack is not None:
            level, message = max(level, stack[0]), f"{message}: {stack[1]}"
        return Status(
            level, f"{self.prefix}{self.hardware_id}", message, self.hardware_id,
            (("role", role), ("function", snap.function or ""), ("epoch", str(snap.epoch)),
             ("health", snap.health.name.lower()), ("frames_in", str(snap.frames_in)),
             ("frames_out", str(snap.frames_out))))


def to_message(statuses: list[Status], stamp: Any) -> Any:
    """A diagnostic_msgs/DiagnosticArray of `statuses` (rclpy installed)."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    msg = DiagnosticArray()
    msg.header.stamp = stamp
    for s in statuses:
        msg.status.append(DiagnosticStatus(
            level=bytes([s.level]), name=s.name, message=s.message,
            hardware_id=s.hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in s.values]))
    return msg
