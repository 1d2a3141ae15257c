"""How many signatures a daemon checks a second (DESIGN section 2, "Who can still do
what"): an Ed25519 check costs 0.1-0.5 ms of CPU (`bench/bench_verify_flood.py`), so a
forger sending thousands of signed frames a second, each with a fresh sequence number
so the cheap checks before it (swarm, sender, size, relevance, the replay filter) pass,
would otherwise take the whole CPU and make the daemon's own heartbeats late: its
watchers suspect it, a standby takes its function over and it is fenced.

A token bucket per claimed sender and one for all together. A check the budget does
not cover is not made: the frame counts as unverified (`auth`), as a forged one does.
Honest traffic is far below it: a robot's anchors (about one a second), its warnings,
claims, leaves and refutes of a failover and the certificates relayed with them (a few
dozen within a second), so a flood in one robot's name costs only that robot's signed
frames for as long as it lasts (its chain-linked heartbeats need no signature), and a
flood in every name costs each robot its share of `TOTAL_RATE`, a delay of the signed
frames of a failover, not the heartbeats.
"""

from __future__ import annotations

import time
from collections.abc import Callable

PER_ROBOT_RATE = 40.0
"""Signature checks a second for frames in one robot's name: its anchors (about one a
second), its warnings (one each warn interval while it suspects), and the certificates
relayed with claims, in which its warnings travel again (a few dozen a second at most)."""
PER_ROBOT_BURST = 80.0
TOTAL_RATE = 150.0
"""Signature checks a second in all: 3-15% of one core at 0.2-1 ms a check
(`bench/bench_verify_flood.py` measures the check on the machine it runs on)."""
TOTAL_BURST = 150.0
SIGNED_MIN = 11 + 64
"""bytes: the shortest frame that carries an Ed25519 signature (header and signature;
a frame tagged with the swarm key carries 8 bytes, and every such frame is shorter)."""


class _Bucket:
    __slots__ = ("at", "burst", "level", "rate")

    def __init__(self, rate: float, burst: float, now: float) -> None:
        self.rate, self.burst, self.level, self.at = rate, burst, burst, now

    def fill(self, now: float) -> float:
        self.level = min(self.burst, self.level + (now - self.at) * self.rate)
        self.at = now
        return self.level


class VerifyBudget:
    """Whether one more signature check may be made now (module docstring)."""

    def __init__(self, *, per_robot: float = PER_ROBOT_RATE, per_robot_burst: float =
                 PER_ROBOT_BURST, total: float = TOTAL_RATE, total_burst: float =
                 TOTAL_BURST, clock: Callable[[], float] = time.monotonic,
                 own: int | None = None) -> None:
        """`own`: this daemon's robot id. Frames in its name are mostly the echoes of
        what it sent (a multicast group loops them back), which the node drops unchecked
        (`Node.receive`), so `allows` takes no credit for them: a credit never spent
        would stay, and let a later flood forged in our name past the budget. One that
        is checked (not an echo: a forgery) spends the budget at its check."""
        self._own = own
        self._clock = clock
        self._per = (per_robot, per_robot_burst)
        self._total = _Bucket(total, total_burst, clock())
        self._robots: dict[int, _Bucket] = {}
        self._credits: dict[int, int] = {}
        """Checks `allows` took from the budget for frames still on their way."""
        self.refused = 0
        """Checks not made (counted once each)."""

    def allows(self, data: bytes) -> bool:
        """The daemon's receive filter (`Runtime(receive_filter=)`), before the frame is
        queued and decoded: False for a frame that carries a signature to check (its
        signed bit set, and long enough for a 64-byte signature: an anchor, a WARN,
        CLAIM, LEAVE, REFUTE or CERT) in the name of a robot whose budget is spent, so a
        flood past the budget costs no decoding either (counted in `refused`). A frame it
        lets through takes its check from the budget now, as a credit the check then
        spends (`take`): frames queued together cannot overdraw it. Credits are capped,
        so played-back frames (dropped before any check) spend nothing more."""
        if len(data) < SIGNED_MIN or not data[0] & 0x08:
            return True
        robot = int.from_bytes(data[3:5], "big")
        if robot == self._own or self._credits.get(robot, 0) >= self._per[1]:
            return True
        if not self._spend(robot):
            return False
        self._credits[robot] = self._credits.get(robot, 0) + 1
        return True

    def take(self, robot: int) -> bool:
        """One signature check of a frame in `robot`'s name: a credit `allows` took, or
        the budget now."""
        credit = self._credits.get(robot, 0)
        if credit > 0:
            self._credits[robot] = credit - 1
            return True
        return self._spend(robot)

    def _spend(self, robot: int) -> bool:
        now = self._clock()
        mine = self._robots.get(robot)
        if mine is None:
            mine = self._robots[robot] = _Bucket(*self._per, now)
        if mine.fill(now) < 1.0 or self._total.fill(now) < 1.0:
            self.refused += 1
            return False
        mine.level -= 1.0
        self._total.level -= 1.0
        return True
