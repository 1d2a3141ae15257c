"""What the robot executes, as one message (docs/ros2.md, "The assignment").

The function, its goal and the release action on three latched topics reach a stack that
starts late separately, in any order, each possibly older than the others. The
assignment carries them together, as one `diagnostic_msgs/DiagnosticStatus` on the
latched `assignment_topic`, with what a stack needs to check it:

- `seq`: raised at every change by this daemon; an assignment with a lower `seq` and the
  same `boot` is older than one already seen;
- `boot`: the daemon's start (Unix time in ns): a new value is a restarted daemon, whose
  first assignment says what the robot holds now (`execute` or the release action);
- `lease`: s. The daemon sends the assignment again every `republish_interval`; a stack
  that heard none for `lease` s must assume its daemon is gone and release (hold or land).

Pure data, no rclpy, but `to_message`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from swarmd.link.ros2_status import OK, WARN

LEASE_PERIODS = 3
"""The lease is this many republish intervals: one lost renewal is not a dead daemon."""


@dataclass(slots=True)
class Assignment:
    """The current assignment of one robot; `execute`/`release` change it."""

    robot: str
    frame_id: str
    lease: float
    boot: int = field(default_factory=time.time_ns)
    seq: int = 0
    function: str = ""
    action: str = "none"
    """`execute`, `hold` or `land` (a release), `none` before the daemon decided."""
    epoch: int = 0
    goal: tuple[float, float, float] | None = None

    def execute(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        self.seq += 1
        self.function, self.action, self.epoch = function, "execute", epoch
        position = params.get("position") if params.get("kind") == "slot" else None
        self.goal = None
        if isinstance(position, list | tuple) and len(position) == 3:
            x, y, z = (float(v) for v in position)
            self.goal = (x, y, z)

    def release(self, action: str) -> None:
        self.seq += 1
        self.function, self.action, self.epoch, self.goal = "", action, 0, None

    def values(self) -> tuple[tuple[str, str], ...]:
        out = [("function", self.function), ("action", self.action),
               ("epoch", str(self.epoch)), ("seq", str(self.seq)), ("boot", str(self.boot)),
               ("lease", f"{self.lease:g}")]
        if self.goal is not None:
            out += [("frame_id", self.frame_id), ("x", repr(self.goal[0])),
                    ("y", repr(self.goal[1])), ("z", repr(self.goal[2]))]
        return tuple(out)

    def message(self) -> str:
        if self.action == "execute":
            return f"execute {self.function}"
        return "no function yet" if self.action == "none" else f"release: {self.action}"

    def to_message(self) -> Any:
        """A diagnostic_msgs/DiagnosticStatus (rclpy installed)."""
        from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

        return DiagnosticStatus(
            level=bytes([OK if self.action == "execute" else WARN]),
            name=f"swarmd/assignment/{self.robot}", message=self.message(),
            hardware_id=self.robot,
            values=[KeyValue(key=k, value=v) for k, v in self.values()])
