"""This robot's own heartbeat schedule (paper Fig. 4's health signal; DESIGN rules 4, 7).

Active robots heartbeat every `heartbeat_interval`, standbys every
`standby_heartbeat_interval`, with no drift (the next one is due one period after the
previous *deadline*). Extra heartbeats out of schedule (refutation, answering a stale
holder) are limited to four per heartbeat period, so a flood of warnings cannot make a
robot amplify it. Pure: the node asks when, and tells when it sent.
"""

from __future__ import annotations

from swarmd.core.params import Params
from swarmd.core.roles import Role


class HeartbeatClock:
    __slots__ = ("_last", "_params", "next")

    def __init__(self, params: Params, now: float) -> None:
        self._params = params
        self.next = now
        """When the next scheduled heartbeat is due."""
        self._last = -1e18

    def period(self, role: Role) -> float:
        p = self._params
        return p.heartbeat_interval if role == Role.ACTIVE else p.standby_heartbeat_interval

    def sent(self, now: float) -> None:
        self._last = now

    def scheduled(self, now: float, role: Role) -> None:
        """The heartbeat due at `next` went out at `now`: the next one, no drift."""
        period = self.period(role)
        self.next += period
        if self.next <= now:
            self.next = now + period

    def restart(self, now: float) -> None:
        """Became ACTIVE: the next one a heartbeat period from now (the standby period
        would let the new neighbours' T_max run out)."""
        self.next = now + self._params.heartbeat_interval

    def extra_allowed(self, now: float) -> bool:
        return now - self._last >= self._params.heartbeat_interval / 4


__all__ = ["HeartbeatClock"]
