"""The real-time run's fault schedule: the injected faults on the wall clock.

The orchestrator supervises the robot processes; this schedule only says when each
fault acts. Armed once, at the run's origin t0 (a Unix time the robots share), each
fault is handed to the orchestrator's `apply` at t0 + its `at`; a fault after the run's
end is never armed, and `cancel` drops the ones still pending when the run ends early.
Partitions act in the robots' receive filters instead (`sim/realtime/netfilter.py`):
`partitions` lists their windows for the robot processes, set at spawn.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence

from sim.realtime.netfilter import PartitionWindow, link_windows
from sim.shared.faults import Fault


class FaultSchedule:
    """`faults` in time order, applied within `duration` s of the run's origin."""

    def __init__(self, faults: Sequence[Fault], duration: float) -> None:
        self.faults = sorted(faults, key=lambda f: f.at)
        self.duration = duration
        self.partitions: tuple[PartitionWindow, ...] = link_windows(
            [part for f in self.faults for part in f.split()])
        self._handles: list[asyncio.TimerHandle] = []

    @property
    def armed(self) -> int:
        """Faults armed by `arm` and not cancelled (applied already or still to come)."""
        return sum(1 for h in self._handles if not h.cancelled())

    def arm(self, t0: float, apply: Callable[[Fault], None],
            clock: Callable[[], float] = time.time) -> None:
        """Apply each fault at wall time `t0 + at` (`clock`: Unix time, s); a fault
        whose time has passed acts at once."""
        loop = asyncio.get_running_loop()
        for fault in self.faults:
            if fault.at <= self.duration:
                delay = t0 + fault.at - clock()
                self._handles.append(loop.call_later(max(0.0, delay), apply, fault))

    def cancel(self) -> None:
        """Drop every fault not applied yet (the run ended)."""
        for handle in self._handles:
            handle.cancel()
        self._handles.clear()


__all__ = ["FaultSchedule"]
