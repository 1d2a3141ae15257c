"""sim.realtime.netfilter: per-process receive filter (loss, partitions), on an injected clock."""

from __future__ import annotations

import pytest

from sim.realtime.netfilter import ReceiveFilter, partition_windows
from swarmd.core import wire


def frame(sender: int, seq: int = 1) -> bytes:
    return wire.encode(wire.Frame(1543, sender, seq, wire.Heartbeat(1, 0, 1, 0)))


def test_filter_without_loss_or_partition_keeps_everything() -> None:
    f = ReceiveFilter(3)
    assert all(f(frame(s), 0.0) for s in range(1, 7))
    assert f.stats.passed == 6


def test_filter_partition_drops_other_group_only_inside_the_window() -> None:
    clock = [0.0]
    windows = partition_windows([(1.0, 2.0, [[1, 2], [3, 4]])])
    f = ReceiveFilter(1, partitions=windows, clock=lambda: clock[0])
    assert f(frame(3), 0.0)
    clock[0] = 1.5
    assert not f(frame(3), 0.0) and not f(frame(4), 0.0)
    assert f(frame(2), 0.0)
    assert f(frame(5), 0.0)  # named nowhere: the first group, like robot 1
    clock[0] = 3.01
    assert f(frame(3), 0.0)
    assert f.stats.partitioned == 2


def test_filter_unnamed_robots_are_in_the_first_group() -> None:
    clock = [1.5]
    windows = partition_windows([(1.0, 2.0, [[1, 2], [3, 4]])])
    f5 = ReceiveFilter(5, partitions=windows, clock=lambda: clock[0])
    assert f5(frame(1), 0.0)
    assert not f5(frame(3), 0.0)


def test_filter_short_garbage_passes_to_be_counted_by_the_daemon() -> None:
    windows = partition_windows([(0.0, 9.0, [[1], [2]])])
    f = ReceiveFilter(1, partitions=windows, clock=lambda: 1.0)
    assert f(b"\x01\x02", 0.0)


def test_filter_loss_is_seeded_per_robot_and_near_the_rate() -> None:
    a1 = ReceiveFilter(1, loss=0.3, seed=7)
    a2 = ReceiveFilter(1, loss=0.3, seed=7)
    b = ReceiveFilter(2, loss=0.3, seed=7)
    data = frame(4)
    pa1 = [a1(data, 0.0) for _ in range(2000)]
    pa2 = [a2(data, 0.0) for _ in range(2000)]
    pb = [b(data, 0.0) for _ in range(2000)]
    assert pa1 == pa2  # same seed, same robot: same pattern in any process
    assert pa1 != pb  # independent per receiver, as on a broadcast radio
    assert 0.25 < a1.stats.lost / 2000 < 0.35


def test_filter_rejects_impossible_loss() -> None:
    with pytest.raises(ValueError, match="loss"):
        ReceiveFilter(1, loss=1.0)
