"""Per-process receive filter: packet loss and partitions for the real-time `swarmd sim`.

Every robot process of `swarmd sim` hears the whole loopback multicast group; a lossy
radio channel and a partitioned swarm are emulated on the *receive* side, inside each
robot process, before a frame reaches the daemon's queue (the daemon's
`receive_filter(data, now) -> bool` hook, False = drop). Doing it on receive, per
receiver, gives independent losses per link as on a real broadcast radio, where one
transmission reaches some neighbours and not others.

- loss: each frame is dropped with probability `loss`, from a `random.Random` seeded by
  the run's `--seed` and the robot id, so a run's loss pattern does not depend on which
  process happened to start first.
- partition (`partition:1,2|3,4@T+D`): during [T, T+D] a robot drops frames whose
  sender is in a different group than its own. The one-way link faults (`fade:R@T+D`,
  `deaf:R:S@T+D`, `partition:1,2>3,4@T+D`) are windows too: a robot in the window's
  receivers drops frames from its senders (`sim.shared.faults.Fault.cut`).
- burst loss (`--loss-model burst`): Gilbert-Elliott per sender, seeded as the loss is
  (sim/shared/channel.py). A robot named in no group is in the first
  group (sim/shared/faults.py). The sender id is read from the header without verifying the
  frame (`wire.HEADER`): fine for an emulated link; a frame too short to carry a header
  passes, so the daemon still counts it as garbage.

Time is the run's clock (seconds since t0), injected as a callable so that the filter is
testable without sleeping.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from sim.shared.channel import GilbertElliott
from sim.shared.faults import Fault, FaultKind
from swarmd.core.wire import HEADER, HEADER_LEN


@dataclass(frozen=True, slots=True)
class PartitionWindow:
    """Groups that cannot hear each other during [start, end] (run seconds)."""

    start: float
    end: float
    groups: tuple[frozenset[int], ...]
    cut: tuple[frozenset[int] | None, frozenset[int] | None] | None = None
    """A one-way window instead: (senders, receivers), None = every robot."""

    def drops(self, sender: int, receiver: int, t: float) -> bool:
        """Does this window lose a frame from `sender` at `receiver` at run time `t`?"""
        if not self.start <= t <= self.end or sender == receiver:
            return False
        if self.cut is not None:
            senders, receivers = self.cut
            return (senders is None or sender in senders) \
                and (receivers is None or receiver in receivers)
        return self.group_of(sender) != self.group_of(receiver)

    def group_of(self, robot: int) -> int:
        """Index of the robot's group; robots named nowhere are in the first group."""
        for i, g in enumerate(self.groups):
            if robot in g:
                return i
        return 0


@dataclass(slots=True)
class FilterStats:
    """What the filter dropped (reported by the robot process at exit)."""

    passed: int = 0
    lost: int = 0
    partitioned: int = 0


@dataclass(slots=True)
class ReceiveFilter:
    """`receive_filter(data, now) -> bool` for `run_daemon`: True keeps the frame."""

    robot_id: int
    loss: float = 0.0
    seed: int = 0
    partitions: Sequence[PartitionWindow] = ()
    clock: Callable[[], float] = time.time
    loss_model: str = "bernoulli"
    burst_len: float = 4.0
    """Seconds since the run's start; the robot process passes `time.time() - t0`."""
    stats: FilterStats = field(default_factory=FilterStats)
    _rng: random.Random = field(init=False)
    _burst: GilbertElliott | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"loss must be in [0, 1), got {self.loss}")
        # A string seed is hashed with SHA-512 by random.seed: stable across processes
        # and Python runs (unlike hash()), distinct per robot.
        self._rng = random.Random(f"swarmd-loss:{self.seed}:{self.robot_id}")
        self._burst = GilbertElliott(self.loss, self.burst_len, self._rng) \
            if self.loss_model == "burst" else None

    def __call__(self, data: bytes, now: float) -> bool:
        sender = HEADER.unpack_from(data)[2] if len(data) >= HEADER_LEN else None
        if self.partitions and sender is not None:
            t = self.clock()
            if any(w.drops(sender, self.robot_id, t) for w in self.partitions):
                self.stats.partitioned += 1
                return False
        if self._burst is not None:
            lost = sender is not None and self._burst.lost(sender, self.robot_id)
        else:
            lost = self.loss > 0.0 and self._rng.random() < self.loss
        if lost:
            self.stats.lost += 1
            return False
        self.stats.passed += 1
        return True


def partition_windows(
    faults: Sequence[tuple[float, float, Sequence[Sequence[int]]]],
) -> tuple[PartitionWindow, ...]:
    """Windows from (at, duration, groups) triples (the partition faults of a run)."""
    return tuple(
        PartitionWindow(at, at + duration, tuple(frozenset(g) for g in groups))
        for at, duration, groups in faults
    )


def link_windows(faults: Sequence[Fault]) -> tuple[PartitionWindow, ...]:
    """The windows of a run's link faults: two-way partitions by groups, the one-way
    ones (fade, deaf, `partition:A>B`) by their cut."""
    out = []
    for f in faults:
        cut = f.cut()
        end = f.at + (f.duration or 0.0)
        if cut is not None:
            out.append(PartitionWindow(f.at, end, (), cut))
        elif f.kind is FaultKind.PARTITION:
            out.append(PartitionWindow(f.at, end, tuple(frozenset(g) for g in f.groups)))
    return tuple(out)
