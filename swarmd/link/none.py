"""The `none` robot link: a robot that is always healthy and does what it is told.

For tests, benchmarks and bare daemons in `swarmd sim --no-physics`. It remembers what it
was told (`function`, `epoch`, `history`) so tests can check the daemon's one output
(paper Fig. 4), and `set_health()` lets a test or the simulator's `unhealthy` fault
play a robot that reports a fault.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback


class NoneLink:
    """Always healthy unless told otherwise; records assignments."""

    def __init__(self) -> None:
        self.function: str | None = None
        self.epoch: int | None = None
        self.params: Mapping[str, Any] = {}
        self.history: list[tuple[str, str, int | None]] = []
        """("assign", function, epoch) / ("release", function, None), in order."""
        self._on_health: HealthCallback | None = None

    async def start(self, on_health: HealthCallback) -> None:
        self._on_health = on_health
        on_health(Health.OK)

    def set_health(self, health: Health) -> None:
        """Report `health` to the daemon as the robot would."""
        if self._on_health is not None:
            self._on_health(health)

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        self.function, self.epoch, self.params = function, epoch, dict(params)
        self.history.append(("assign", function, epoch))

    def release(self, function: str) -> None:
        if self.function == function:
            self.function, self.epoch, self.params = None, None, {}
        self.history.append(("release", function, None))

    async def close(self) -> None:
        self._on_health = None
