"""A simulated robot that is a ROS 2 stack: `swarmd sim --link ros2` (docs/ros2.md).

`RobotStack` is a small rclpy robot written only against the ros2 link's interface, as a
user's robot would be: it publishes its health as a DiagnosticStatus (hardware_id
`robot<id>`) on /diagnostics twice a second, and flies the goal pose it gets on the goal
topic (slot functions), holds on the function topic's empty name and does the release
action. It knows nothing of swarmd but those topics; each robot's topics live under its
own namespace (the link's default, `/swarmd/<swarm>/robot<id>`) in the run's ROS domain.

`SimRos2Link` is what the robot process hands the daemon: the daemon's real `Ros2Link`,
the stack beside it (its own rclpy context and executor thread) and, with physics, the
MuJoCo quadrotor the stack flies (`QuadLink`, driven only by the stack). The
`unhealthy` fault makes the stack publish ERROR; `motor` fails a rotor, which the
craft's own health reports through the stack. The stack writes what it received, with
Unix receive times, to `<run>/ros2/robot<id>.jsonl` (tests compare them to the event log).
"""

from __future__ import annotations

import asyncio
import json
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from swarmd.core.events import Event
from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback, RobotLink
from swarmd.link.ros2 import DIAGNOSTICS, latched_qos
from swarmd.link.ros2_node import RosThread

HEALTH_PERIOD = 0.5
"""s between two health statuses of the stack (diagnostic_updater's default is 1 s)."""
LEVEL = {Health.OK: 0, Health.DEGRADED: 1, Health.FAULTY: 2}
SIM_HEALTH_TIMEOUT = 20.0
"""s: the simulated robots' ros2 link health_timeout (`DomainLease.link_doc`)."""


class RobotStack:
    """The robot side, from topics only. `fly(function, position | None)` and
    `land()` are called on the asyncio loop (the craft's thread)."""

    def __init__(self, robot_id: int, cfg: Any, *, fly: Callable[[str, Any], None],
                 stop: Callable[[str], None], record: Path | None = None) -> None:
        self.robot_id = robot_id
        self.cfg = cfg
        self.fly = fly
        self.stop_flying = stop
        self.ros = RosThread(f"robot{robot_id}_stack", namespace=cfg.namespace,
                             domain_id=cfg.domain_id, localhost_only=cfg.localhost_only)
        self.health = Health.OK
        self.function = ""
        self.goal: tuple[float, float, float] | None = None
        self.record_path = record
        self._loop: asyncio.AbstractEventLoop | None = None
        self._pub: Any = None

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import String

        self._loop = loop
        cfg = self.cfg

        def setup(node: Any) -> None:
            self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS, 10)
            node.create_subscription(PoseStamped, cfg.goal_topic, self._on_goal, latched_qos())
            node.create_subscription(String, cfg.function_topic, self._on_function,
                                     latched_qos())
            node.create_subscription(String, cfg.release_topic, self._on_release,
                                     latched_qos())
            node.create_timer(HEALTH_PERIOD, self._publish_health)

        self.ros.start(setup)
        self.ros.call(lambda _node: self._publish_health())

    def set_health(self, health: Health) -> None:
        """At least `health` from now on (the `unhealthy` fault, a failed rotor)."""
        if health > self.health:
            self.health = health
            self.ros.call(lambda _node: self._publish_health())

    def _publish_health(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

        msg = DiagnosticArray()
        msg.header.stamp = self.ros.node.get_clock().now().to_msg()
        msg.status.append(DiagnosticStatus(
            level=bytes([LEVEL[self.health]]), name=f"robot{self.robot_id}/flight",
            hardware_id=f"robot{self.robot_id}", message=self.health.name.lower()))
        self._pub.publish(msg)

    def _record(self, kind: str, **fields: Any) -> None:
        if self.record_path is not None:
            with self.record_path.open("a") as f:
                f.write(json.dumps({"w": time.time(), "robot": self.robot_id, "kind": kind,
                                    **fields}) + "\n")

    def _to_loop(self, fn: Callable[..., None], *args: Any) -> None:
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(fn, *args)

    def _on_goal(self, msg: Any) -> None:
        p = msg.pose.position
        goal = (p.x, p.y, p.z)
        if goal == self.goal:
            return  # the link re-publishes while the function is held
        self.goal = goal
        self._record("goal", position=list(goal), frame=msg.header.frame_id)
        if self.function:
            self._to_loop(self.fly, self.function, goal)

    def _on_function(self, msg: Any) -> None:
        name = str(msg.data)
        self._record("function", name=name)
        if name == self.function:
            return
        old, self.function = self.function, name
        if name:
            self._to_loop(self.fly, name, self.goal)
        elif old:
            self.goal = None

    def _on_release(self, msg: Any) -> None:
        self._record("release", action=str(msg.data))
        if msg.data:  # "": an assign cleared it (docs/ros2.md), nothing to stop
            self._to_loop(self.stop_flying, str(msg.data))

    def stop(self) -> None:
        self.ros.stop()


class SimRos2Link:
    """The robot process's `RobotLink` for `--link ros2` (module docstring)."""

    def __init__(self, cfg: Any, quad: RobotLink | None) -> None:
        from swarmd.link.ros2 import Ros2Link

        self.cfg = cfg
        self.link = Ros2Link(cfg.link)
        self.quad = quad
        self._flying: str | None = None
        record = Path(cfg.source).parent.parent / "ros2" / f"robot{cfg.robot}.jsonl"
        record.parent.mkdir(parents=True, exist_ok=True)
        self.stack = RobotStack(cfg.robot, cfg.link, fly=self._fly, stop=self._land,
                                record=record)

    def watch(self, snapshot: Callable[[], Any], cfg: Any) -> Callable[[Event], None]:
        return self.link.watch(snapshot, cfg)

    def _fly(self, function: str, goal: Any) -> None:
        if self.quad is None or goal is None:
            return  # a bare robot (--no-physics), or a function with no place
        self._flying = function
        self.quad.assign(function, 0, {"kind": "slot", "position": list(goal)})

    def _land(self, action: str) -> None:
        if self.quad is not None and self._flying is not None:
            self.quad.release(self._flying)  # the craft lands at home either way
            self._flying = None

    async def start(self, on_health: HealthCallback) -> None:
        loop = asyncio.get_running_loop()
        if self.quad is not None:
            await self.quad.start(self.stack.set_health)  # the craft's health, via ROS
        await asyncio.to_thread(self.stack.start, loop)
        await self.link.start(on_health)

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        self.link.assign(function, epoch, params)

    def release(self, function: str) -> None:
        self.link.release(function)

    def set_health(self, health: Health) -> None:
        self.stack.set_health(health)

    def fail_motor(self, index: int = 0) -> None:
        fail = getattr(self.quad, "fail_motor", None)
        if fail is not None:
            fail(index)

    async def close(self) -> None:
        await self.link.close()
        await asyncio.to_thread(self.stack.stop)
        if self.quad is not None:
            await self.quad.close()


class DomainLease:
    """A ROS 2 domain id held for one run, so runs and tests never hear each other's
    topics: a Unix socket bound to the abstract name `swarmd-ros2-domain-<id>` (Linux),
    which the kernel hands to one socket at a time and frees by itself when the socket
    closes, by `release()` or with the process, however it ends: nothing is left in
    /tmp (a lock file per id was, for good). Ids 1..100 (0 is everyone's default; above
    101 Fast DDS runs out of ports for several participants)."""

    FIRST, LAST = 1, 100

    def __init__(self, domain_id: int | None = None) -> None:
        """Lease a free id; or, given `domain_id`, use that one (the user's: nothing is
        leased, and other runs in it hear this one, as the user asked)."""
        import random
        import socket

        self._sock: socket.socket | None = None
        self.leased = domain_id is None
        if domain_id is not None:
            self.domain_id = domain_id
            return
        ids = list(range(self.FIRST, self.LAST + 1))
        random.shuffle(ids)
        for domain in ids:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            try:
                sock.bind(f"\0swarmd-ros2-domain-{domain}")
            except OSError:  # EADDRINUSE: another run holds it
                sock.close()
                continue
            self.domain_id = domain
            self._sock = sock
            return
        raise RuntimeError(f"no free ROS 2 domain id in {self.FIRST}..{self.LAST}")

    def link_doc(self, robot: int) -> dict[str, Any]:
        """The robot file's link section for `robot` in this run."""
        # The link no longer counts health_timeout before the stack's first status (it
        # waits for it: DDS discovery between the stack and the link took over 6 s with
        # two suites at once on two cores). Once heard, the simulated stack never falls
        # silent on its own (its faults are explicit: ERROR, or the whole process), so
        # a long timeout costs nothing and keeps a starved executor thread on a loaded
        # machine from looking like a dead stack.
        return {"kind": "ros2", "domain_id": self.domain_id,
                "health_timeout": SIM_HEALTH_TIMEOUT}

    @classmethod
    def for_run(cls) -> DomainLease:
        """$ROS_DOMAIN_ID when it is set (the user watches that domain), else a leased
        one; `SimOptions` already refused a value that is not a domain id."""
        env = os.environ.get("ROS_DOMAIN_ID", "").strip()
        return cls(int(env)) if env else cls()

    def announce(self) -> str:
        """The line that tells the user where the swarm is and how to watch it."""
        how = "from ROS_DOMAIN_ID" if not self.leased else \
            "leased for this run: set ROS_DOMAIN_ID to choose one"
        return (f"ROS 2 domain {self.domain_id} ({how}); watch the swarm with "
                f"`ROS_DOMAIN_ID={self.domain_id} ros2 topic echo /diagnostics` or "
                f"`ROS_DOMAIN_ID={self.domain_id} ros2 run rqt_robot_monitor "
                f"rqt_robot_monitor`")

    def release(self) -> None:
        """Give the id back; idempotent."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
