"""`swarmd monitor --ros2`: the base station's view of the swarm on /diagnostics.

The same statuses the daemons of a ROS 2 swarm publish (`swarmd.link.ros2_status`), built
from what the passive monitor heard on the swarm channel (`MonitorState`), so a ROS 2
operator sees every function in rqt_robot_monitor even when the robots themselves are
not ROS 2 stacks. `hardware_id` is `base_station`, its own status
`swarmd/<swarm>/base_station`. Published at every change seen at the monitor's refresh
(4 Hz) and at least once a second, from rclpy's own thread (`RosThread`).
"""

from __future__ import annotations

from typing import Any

from swarmd.core.roles import Role
from swarmd.daemon.monitor import MonitorState
from swarmd.link.ros2_status import ERROR, OK, STALE, WARN, Status, status_prefix, to_message

HARDWARE_ID = "base_station"
REPUBLISH = 1.0
"""s: the statuses go out at least this often, changed or not."""


def monitor_statuses(state: MonitorState, swarm_name: str, now: float) -> list[Status]:
    """One status per function of the plan, as the monitor sees its holder, and its own."""
    prefix = status_prefix(swarm_name)
    rows = {r["robot"]: r for r in state.rows(now)}
    out = []
    for f in state.plan.functions:
        newest = state.newest.get(f)
        epoch, holder = newest if newest is not None else (0, state.plan.initial_holder(f))
        row = rows.get(holder) if holder is not None else None
        claim = state.claims.get(f)
        claiming = claim is not None and claim[1] > epoch \
            and now - claim[2] <= state.params.vote_window
        level, message = _level(f, holder, row, claiming)
        out.append(Status(level, prefix + f, message, HARDWARE_ID,
                          (("holder", str(holder or 0)), ("epoch", str(epoch)),
                           ("role", "monitor"))))
    alerts = state.alerts(now)
    out.append(Status(WARN if alerts else OK, prefix + HARDWARE_ID,
                      "; ".join(alerts) or f"{len(state.robots)} robots heard", HARDWARE_ID,
                      (("role", "monitor"), ("robots", str(len(state.robots))))))
    return out


def _level(f: str, holder: int | None, row: dict[str, Any] | None,
           claiming: bool) -> tuple[int, str]:
    """f's level and message, in the daemons' words (`ros2_status`): STALE when its
    holder is not heard (never, silent, left), never OK unless the holder's own
    heartbeat says it executes f."""
    if row is None:
        return STALE, "holder never heard"
    # A silent holder is STALE, as the daemons show it; ERROR is for what nobody
    # answered (no claim, no standby: rule 8).
    alerts = [a for a in row["alerts"] if not a.startswith("holder of ")]
    if alerts:
        return ERROR, "; ".join(alerts)
    if row["warned_by"] or claiming:
        return WARN, "suspected: a takeover may be under way"
    if row["status"] == "left":
        return STALE, f"robot {holder} left"
    if "silent" in row["status"]:
        return STALE, f"robot {holder} not heard"
    if row["function"] != f or row["role"] != Role.ACTIVE.name:
        role = str(row["role"] or "unknown").lower()
        return WARN, f"robot {holder} does not execute {f} ({role})"
    return OK, f"held by robot {holder}"


class MonitorPublisher:
    """Publishes `monitor_statuses` on /diagnostics; `refresh(now)` is the monitor's
    refresh callback (the loop thread), the node spins in its own thread."""

    def __init__(self, state: MonitorState, swarm_name: str, *,
                 domain_id: int | None = None) -> None:
        from swarmd.link.ros2_node import RosThread

        self.state = state
        self.swarm_name = swarm_name
        self.ros = RosThread("swarmd_monitor", domain_id=domain_id)
        self._pub: Any = None
        self._last: list[Status] | None = None
        self._at = float("-inf")
        self.published = 0

    def start(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        def setup(node: Any) -> None:
            self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)

        self.ros.start(setup)

    def refresh(self, now: float) -> None:
        statuses = monitor_statuses(self.state, self.swarm_name, now)
        if statuses == self._last and now - self._at < REPUBLISH:
            return
        self._last, self._at = statuses, now

        def publish(node: Any) -> None:
            self._pub.publish(to_message(statuses, node.get_clock().now().to_msg()))
            self.published += 1

        self.ros.call(publish)

    def stop(self) -> None:
        self.ros.stop()
