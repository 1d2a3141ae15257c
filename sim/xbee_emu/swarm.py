"""A whole swarm of protocol nodes in one asyncio loop, each on its own radio transport.

The smallest real-time driver of `swarmd.core.Node` (aioquic's pattern, DESIGN
section 2): after every input the node's actions are executed (Broadcast -> the robot's
transport, Event -> the event list) and one `call_at` is re-armed at `next_deadline()`.
Used by the radio tests and `bench/bench_radio.py` to run the paper swarm over emulated
XBee or serial radios with the real transports in between; `swarmd start` uses the full
runtime instead.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sim.shared.faults import FaultKind
from swarmd.core import wire
from swarmd.core.actions import Action, Broadcast
from swarmd.core.auth import Identity
from swarmd.core.events import Event, Fault
from swarmd.core.node import Node
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.transport.base import ChannelEvent, Transport

Record = dict[str, Any]


@dataclass(frozen=True, slots=True)
class ChannelRecord:
    """A channel condition one robot's transport reported, at `t` s of the run."""

    t: float
    robot: int
    event: ChannelEvent


class _Robot:
    def __init__(self, swarm: RadioSwarm, robot_id: int, node: Node, transport: Transport):
        self.swarm = swarm
        self.robot_id = robot_id
        self.node = node
        self.transport = transport
        self.timer: asyncio.TimerHandle | None = None
        self.alive = True

    def execute(self, actions: list[Action]) -> None:
        for action in actions:
            match action:
                case Broadcast(frame):
                    self.transport.send(frame)
                case Event() as event:
                    self.swarm.record(event.record(self.swarm.elapsed(), self.robot_id))
                case _:
                    pass  # Assign / Release go to a robot link; none here
        self.rearm()

    def rearm(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        deadline = self.node.next_deadline()
        if self.alive and deadline is not None:
            self.timer = self.swarm.loop.call_at(deadline, self.tick)

    def tick(self) -> None:
        self.timer = None
        if self.alive:
            self.execute(self.node.tick(self.swarm.loop.time()))

    def on_frame(self, data: bytes) -> None:
        if self.alive:
            self.execute(self.node.receive(data, self.swarm.loop.time()))

    def on_event(self, event: ChannelEvent) -> None:
        self.swarm.channel.append(ChannelRecord(self.swarm.elapsed(), self.robot_id, event))


class RadioSwarm:
    """Nodes of `plan` wired to `transports` (robot id -> transport), in this loop."""

    def __init__(
        self,
        plan: SwarmPlan,
        params: Params,
        transports: Mapping[int, Transport],
        *,
        keys: Sequence[bytes] = (),
        identities: Mapping[int, Identity] | None = None,
    ) -> None:
        self.plan = plan
        self.params = params
        self.transports = dict(transports)
        self.keys = tuple(keys)
        self.identities = dict(identities or {})
        """Per-robot mode: each robot's own signer (DESIGN section 2, "Who may say what")."""
        self.events: list[Record] = []
        """The nodes' event-log records (and injected faults), in order."""
        self.channel: list[ChannelRecord] = []
        """The transports' channel conditions (send errors, radio up), in order."""
        self.robots: dict[int, _Robot] = {}
        self._changed = asyncio.Event()
        self._t0 = 0.0
        self.loop = asyncio.get_running_loop()

    def elapsed(self) -> float:
        return round(self.loop.time() - self._t0, 6)

    def record(self, rec: Record) -> None:
        self.events.append(rec)
        self._changed.set()

    async def start(self) -> None:
        """Open every transport, then start every node (first tick at once)."""
        self._t0 = self.loop.time()
        seq = wire.seq_seed(time.time())
        for rid, transport in self.transports.items():
            node = Node(rid, self.plan, self.params, self.loop.time(), keys=self.keys,
                        identity=self.identities.get(rid), seq_start=seq)
            robot = _Robot(self, rid, node, transport)
            self.robots[rid] = robot
            await transport.start(robot.on_frame, robot.on_event)
        for robot in self.robots.values():
            robot.tick()

    async def kill(self, robot_id: int) -> None:
        """Crash a robot: its node stops at once and its radio goes silent."""
        robot = self.robots[robot_id]
        robot.alive = False
        if robot.timer is not None:
            robot.timer.cancel()
        self.record(Fault(FaultKind.CRASH.value).record(self.elapsed(), robot_id))
        await robot.transport.close()

    async def wait_for(self, match: Callable[[Record], bool], timeout: float) -> Record | None:
        """The first event (past or future) matching, or None after `timeout` s."""
        deadline = self.loop.time() + timeout
        seen = 0
        while True:
            for rec in self.events[seen:]:
                if match(rec):
                    return rec
            seen = len(self.events)
            remaining = deadline - self.loop.time()
            if remaining <= 0:
                return None
            self._changed.clear()
            try:
                await asyncio.wait_for(self._changed.wait(), remaining)
            except TimeoutError:
                return None

    async def close(self) -> None:
        for robot in self.robots.values():
            if robot.alive:
                robot.alive = False
                if robot.timer is not None:
                    robot.timer.cancel()
                await robot.transport.close()


def paper_plan(swarm_id: int = 0x607) -> SwarmPlan:
    """The paper's appendix swarm: robots 1-4 active on f1-f4 in a ring (each watches
    its two ring neighbours), 5 covers f1 and f4, 6 covers f2 and f3."""
    from swarmd.core.plan import RobotPlan

    functions = ("f1", "f2", "f3", "f4")
    robots = {r: RobotPlan(r, f"f{r}") for r in range(1, 5)}
    robots[5] = RobotPlan(5, None, ("f1", "f4"))
    robots[6] = RobotPlan(6, None, ("f2", "f3"))
    watches = {"f1": ("f4", "f2"), "f2": ("f1", "f3"), "f3": ("f2", "f4"), "f4": ("f3", "f1")}
    return SwarmPlan(swarm_id, functions, robots, watches)
