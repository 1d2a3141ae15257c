"""The `ros2` robot link: the robot is a ROS 2 stack (docs/ros2.md).

Paper Fig. 4's one input and one output, as ROS 2 users expect them:
- health in: the robot's own diagnostic_msgs/DiagnosticStatus entries on /diagnostics
  (by `health_names`, else by `hardware_id`) from a node of the robot's namespace or
  the named `health_node` (`ros2_health`); the worst level of those heard within
  `health_timeout` decides (OK -> ok, WARN -> degraded, ERROR / STALE -> faulty), and
  none within it is a fault (STALE; DESIGN rule 7) once the robot was heard: before
  that the link waits and alerts, never hands the function away;
- the function out: its name as std_msgs/String on `function_topic`; for a slot function
  a geometry_msgs/PoseStamped goal on `goal_topic` (frame `frame_id`), re-published every
  `republish_interval` while held; a release publishes the empty name and the release
  action (`hold` / `land`) on `release_topic` (and an assign publishes `""` there, so
  the three latched topics never disagree). These are reliable and transient-local
  (depth 1): a stack that starts late still gets the current assignment. The whole
  assignment also goes out as one message on `assignment_topic` (`ros2_assignment`),
  with a sequence number, the daemon's boot id and a lease renewed every
  `republish_interval`: what a stack should trust.
- the swarm out: the daemon's view of its neighbourhood as DiagnosticStatus entries on
  /diagnostics (`ros2_status`), every `status_interval` and at every event.

rclpy runs in its own thread (`ros2_node.RosThread`): nothing here blocks the loop, and a
robot stack that hangs or floods only costs its own callbacks.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Mapping
from typing import Any

from swarmd.core.events import Event
from swarmd.core.records import Snapshot
from swarmd.core.roles import Health
from swarmd.link.base import CountedLog, HealthCallback
from swarmd.link.ros2_assignment import LEASE_PERIODS, Assignment
from swarmd.link.ros2_health import HealthFold, Publishers, StackState, StackWatch, node_fqn
from swarmd.link.ros2_node import RosThread
from swarmd.link.ros2_status import OK, STALE, WARN, SwarmStatus, to_message

log = logging.getLogger("swarmd.link.ros2")

DIAGNOSTICS = "/diagnostics"
HEALTH_OF_LEVEL = {OK: Health.OK, WARN: Health.DEGRADED}
"""Every other level (ERROR, STALE, anything unknown) is a fault."""
GRAPH_REFRESH = 0.2
"""s: the ROS graph (who publishes /diagnostics) is read at most this often."""


def latched_qos() -> Any:
    """Reliable, transient-local, depth 1: a late subscriber gets the last message."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def level_of(status: Any) -> int:
    """A DiagnosticStatus level as an int (rclpy gives a one-byte `bytes`)."""
    raw = status.level
    return raw[0] if isinstance(raw, bytes | bytearray) and raw else int(raw)


class Ros2Link:
    """`RobotLink` over ROS 2 topics; `cfg` is the robot file's `Ros2LinkConfig`."""

    def __init__(self, cfg: Any, *, wall: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self.wall = wall
        namespace = cfg.namespace or ""
        name = cfg.node_name or "swarmd"
        self.ros = RosThread(name, namespace=namespace, domain_id=cfg.domain_id,
                             localhost_only=cfg.localhost_only)
        self.health = HealthFold(tuple(cfg.health_names), cfg.hardware_id or "",
                                 cfg.health_timeout)
        self.publishers = Publishers(namespace, cfg.health_node,
                                     node_fqn("/" + namespace.strip("/"), name))
        self.stack = StackWatch(self.health, self.publishers, started_at=wall(),
                                startup_timeout=cfg.startup_timeout, topic=DIAGNOSTICS)
        self.stack_state = StackState(None, WARN, "starting")
        """The latest conclusion about the robot stack (read by the loop thread)."""
        self.assignment = Assignment(cfg.hardware_id or "", cfg.frame_id,
                                     LEASE_PERIODS * cfg.republish_interval)
        self.counters: dict[str, int] = {"statuses_in": 0, "published": 0, "status_out": 0,
                                         "foreign_statuses": 0}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_health: HealthCallback | None = None
        self._reported: int | None = None
        self._gids: dict[bytes, str] = {}
        self._foreign_log = CountedLog(log, f"statuses of {cfg.hardware_id} ignored "
                                            "(docs/ros2.md, 'Who may fault a robot')")
        self._gids_at = float("-inf")
        self._pubs: dict[str, Any] = {}
        self._goal: Any = None
        self._snapshot: Callable[[], Snapshot] | None = None
        self._status: SwarmStatus | None = None
        self._status_timer: asyncio.TimerHandle | None = None
        self._closed = False

    # -- the swarm's view (daemon.py calls this before `start`) ---------------------------
    def watch(self, snapshot: Callable[[], Snapshot], cfg: Any) -> Callable[[Event], None]:
        """Publish the daemon's view of the swarm from `snapshot()` (the node's, read on
        the loop thread only); returns the daemon's event callback."""
        self._snapshot = snapshot
        swarm = cfg.swarm
        self._status = SwarmStatus(swarm.to_plan(), cfg.robot, swarm.swarm.name or
                                   str(swarm.swarm.id), swarm.params().t_max)
        return self._on_event

    def _on_event(self, event: Event) -> None:
        if self._status is not None and self._status.on_event(event) and self._loop:
            self._loop.call_soon(self._publish_status, False)

    def _publish_status(self, rearm: bool = True) -> None:
        if self._closed or self._snapshot is None or self._status is None:
            return
        assert self._loop is not None
        if rearm:
            self._status_timer = self._loop.call_later(self.cfg.status_interval,
                                                       self._publish_status)
        state = self.stack_state
        stack = (state.level, state.message) if state.level is not None else None
        statuses = self._status.statuses(self._snapshot(), self._loop.time(), stack=stack)

        def publish(node: Any) -> None:
            self._pubs["diagnostics"].publish(to_message(statuses,
                                                         node.get_clock().now().to_msg()))
            self.counters["status_out"] += 1

        self.ros.call(publish)

    # -- RobotLink ------------------------------------------------------------------------
    async def start(self, on_health: HealthCallback) -> None:
        self._loop = asyncio.get_running_loop()
        self._on_health = on_health
        self.stack.started_at = self.wall()
        log.info("waiting for %s", self.stack.waiting_for(), extra={"link": "ros2"})
        await asyncio.to_thread(self.ros.start, self._setup)
        if self._snapshot is not None:
            self._loop.call_soon(self._publish_status)

    def _setup(self, node: Any) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import String

        cfg = self.cfg
        latched = latched_qos()
        self._pubs["goal"] = node.create_publisher(PoseStamped, cfg.goal_topic, latched)
        self._pubs["function"] = node.create_publisher(String, cfg.function_topic, latched)
        self._pubs["release"] = node.create_publisher(String, cfg.release_topic, latched)
        self._pubs["assignment"] = node.create_publisher(DiagnosticStatus,
                                                         cfg.assignment_topic, latched)
        # /diagnostics as diagnostic_updater publishes it (reliable, volatile, 10).
        self._pubs["diagnostics"] = node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
        node.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, 50)
        node.create_timer(cfg.republish_interval, self._republish)
        node.create_timer(min(0.25, cfg.health_timeout / 4), self._check_health)

    def _publisher_of(self, info: Any) -> str | None:
        """The node that sent a message (its fully qualified name), from the graph."""
        gid_info = info.get("publisher_gid") if isinstance(info, Mapping) else None
        if not gid_info:
            return None
        gid = bytes(gid_info["data"])
        fqn = self._gids.get(gid)
        if fqn is None and self.wall() - self._gids_at >= GRAPH_REFRESH:
            self._refresh_graph()
            fqn = self._gids.get(gid)
        return fqn

    def _refresh_graph(self) -> None:
        """Map every publisher of /diagnostics to its node; note the robot's first."""
        self._gids_at = now = self.wall()
        for info in self.ros.node.get_publishers_info_by_topic(DIAGNOSTICS):
            fqn = node_fqn(info.node_namespace, info.node_name)
            self._gids[bytes(info.endpoint_gid)] = fqn
            if self.publishers.accepts(fqn) and self.stack.found(fqn, now):
                log.info("robot health publisher found: %s; faulty after %g s without "
                         "a status", fqn, self.health.timeout, extra={"link": "ros2"})

    def _on_diagnostics(self, msg: Any, info: Any) -> None:
        publisher = self._publisher_of(info)
        if publisher is None or not self.publishers.accepts(publisher):
            self.counters["foreign_statuses"] += 1
            if any(self.health.mine(s.name, s.hardware_id) for s in msg.status):
                # The robot's name from a node that may not speak for it: a stack run
                # outside the namespace (the usual mistake), or anyone in the domain.
                self._foreign_log.hit(f"from {publisher or 'an unknown node'}, not "
                                      f"{self.publishers.describe()}", self.wall())
            return
        now = self.wall()
        self.stack.found(publisher, now)
        heard = False
        for s in msg.status:
            heard |= self.health.hear(publisher, s.name, s.hardware_id, level_of(s), now)
        if heard:
            self.counters["statuses_in"] += 1
            self._check_health()

    def _check_health(self) -> None:
        now = self.wall()
        self._foreign_log.tick(now)
        if self.stack.found_at is None and now - self._gids_at >= GRAPH_REFRESH:
            self._refresh_graph()  # discovery: when the start-up bound begins
        state, old = self.stack.state(now), self.stack_state
        self.stack_state = state
        if state.alert and not old.alert:
            log.error("%s; keeping the function and waiting (alert)", state.message,
                      extra={"link": "ros2"})
        if state.health is None or state.health == self._reported:
            return
        if state.health == STALE:
            log.warning("no robot health on %s for %g s: reporting faulty", DIAGNOSTICS,
                        self.health.timeout, extra={"link": "ros2"})
        self._reported = state.health
        health = HEALTH_OF_LEVEL.get(state.health, Health.FAULTY)
        loop, on_health = self._loop, self._on_health
        if loop is not None and on_health is not None and not loop.is_closed():
            loop.call_soon_threadsafe(on_health, health)

    def _republish(self) -> None:
        """Renew the lease (the assignment) and the goal while the function is held."""
        if self.assignment.action != "none":
            self._pubs["assignment"].publish(self.assignment.to_message())
        if self._goal is not None:
            self._publish_goal(self.ros.node)

    def _publish_goal(self, node: Any) -> None:
        self._goal.header.stamp = node.get_clock().now().to_msg()
        self._pubs["goal"].publish(self._goal)
        self.counters["published"] += 1

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import String

        def send(node: Any) -> None:
            self.assignment.execute(function, epoch, params)
            goal: Any = None
            if self.assignment.goal is not None:
                goal = PoseStamped()
                goal.header.frame_id = self.cfg.frame_id
                goal.pose.position.x, goal.pose.position.y, goal.pose.position.z = (
                    self.assignment.goal)
                goal.pose.orientation.w = 1.0
            self._goal = goal
            # The assignment first: a stack that trusts it never sees a mix.
            self._pubs["assignment"].publish(self.assignment.to_message())
            self._pubs["release"].publish(String(data=""))  # not released: no stale hold
            if goal is not None:
                self._publish_goal(node)
            self._pubs["function"].publish(String(data=function))

        self.ros.call(send)

    def release(self, function: str) -> None:
        from std_msgs.msg import String

        action = self.cfg.release

        def send(node: Any) -> None:
            self.assignment.release(action)
            self._goal = None
            self._pubs["assignment"].publish(self.assignment.to_message())
            self._pubs["function"].publish(String(data=""))
            self._pubs["release"].publish(String(data=action))

        self.ros.call(send)

    async def close(self) -> None:
        if self._closed:
            return
        if self._snapshot is not None and self._loop is not None:
            self._publish_status(rearm=False)  # the last view: `stopped`
        self._closed = True
        if self._status_timer is not None:
            self._status_timer.cancel()
        self._on_health = None
        await asyncio.to_thread(self.ros.stop)
