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


class CountedLog:
    """A warning that can come thousands of times a second (bad lines from a robot, bad
    MAVLink bytes) logged at most once a `period`, with how many there were: the first
    one at once, then one line a period for those that came meanwhile ("523 bad lines from
    the robot in the last 10 s"). A line per event would let a robot fill the journal
    (100 MB in 5 s) and stall the loop on logging.

    `hit` counts one; it returns True when it held the first line back, so an asyncio
    caller arms one `loop.call_at(due, tick)`; a thread calls `tick` from its own loop.
    `now` is any monotonic clock in seconds."""

    __slots__ = ("_due", "_last", "_log", "_pending", "message", "period", "total")

    def __init__(self, log: Any, message: str, *, period: float = 10.0) -> None:
        self._log = log
        self.message = message
        self.period = period
        self.total = 0
        self._pending = 0
        self._last = ""
        self._due = float("-inf")

    @property
    def due(self) -> float:
        """When the count held back may be logged (`tick`)."""
        return self._due

    def hit(self, reason: str, now: float, **extra: Any) -> bool:
        self.total += 1
        self._last = reason
        self._pending += 1
        if now >= self._due:
            self._emit(now, extra)
            return False
        return self._pending == 1

    def tick(self, now: float) -> None:
        """Log the count held back, if any and due."""
        if self._pending and now >= self._due:
            self._emit(now, {})

    def _emit(self, now: float, extra: Mapping[str, Any]) -> None:
        count, self._pending = self._pending, 0
        self._due = now + self.period
        self._log.warning("%s: %d in the last %g s (last: %s)", self.message, count,
                          self.period, self._last,
                          extra={**extra, "count": count, "period_s": self.period,
                                 "reason": self._last, "total": self.total})
