"""The robot link interface (paper Fig. 4: one input, health; one output, the task).

The robot tells swarmd its health; swarmd tells the robot which function to execute.
Implementations: `none` (always healthy, for tests), `socket` (Unix socket, JSON
Lines), `exec` (run commands), and the simulator's MuJoCo quadrotor.

    link = SomeLink(cfg)
    await link.start(on_health)          # on_health(Health) called on the loop thread
    link.assign("f2", 3, {"kind": "slot", "position": [...]})
    link.release("f2")
    await link.close()

`assign`/`release` never block the loop and never raise into the runtime: a robot that
cannot be told is reported through the event log, and its health times out (rule 7).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

from swarmd.core.roles import Health

HealthCallback = Callable[[Health], None]


class RobotLink(Protocol):
    async def start(self, on_health: HealthCallback) -> None: ...

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None: ...

    def release(self, function: str) -> None: ...

    async def close(self) -> None: ...
