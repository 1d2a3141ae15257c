"""Anti-replay window (swarmd.core.replay): order, duplicates, reordering, restarts."""

from __future__ import annotations

import random

from swarmd.core import wire
from swarmd.core.replay import WINDOW, ReplayFilter


def test_in_order_accepted() -> None:
    f = ReplayFilter()
    assert all(f.accept(7, s) for s in range(100, 200))


def test_duplicate_dropped() -> None:
    f = ReplayFilter()
    assert f.accept(7, 10)
    assert not f.accept(7, 10)
    assert f.accept(7, 11)
    assert not f.accept(7, 11)
    assert not f.accept(7, 10)


def test_reordered_within_window_accepted_once() -> None:
    f = ReplayFilter()
    assert f.accept(7, 100)
    assert f.accept(7, 105)
    assert f.accept(7, 103)  # late but new
    assert not f.accept(7, 103)  # the same late frame again
    assert f.accept(7, 101)
    assert f.accept(7, 105 - WINDOW + 1)  # oldest position the window still holds
    assert not f.accept(7, 105 - WINDOW + 1)


def test_older_than_window_dropped() -> None:
    f = ReplayFilter()
    assert all(f.accept(7, s) for s in range(1000, 1000 + WINDOW + 1))
    assert not f.accept(7, 1000)
    assert not f.accept(7, 1)


def test_a_sender_heard_first_has_no_floor_until_a_window_is_heard() -> None:
    """The first frame heard of a sender may be a forgery far ahead of it: until WINDOW
    of its frames are heard, any not seen yet counts (replay.UNKNOWN)."""
    f = ReplayFilter()
    assert f.accept(7, 10**9)
    assert f.accept(7, 1000) and f.accept(7, 999) and not f.accept(7, 1000)


def test_big_jump_forgets_the_window() -> None:
    f = ReplayFilter()
    assert f.accept(7, 10)
    assert f.accept(7, 10 + 10 * WINDOW)
    assert not f.accept(7, 10)


def test_senders_are_independent() -> None:
    f = ReplayFilter()
    assert f.accept(1, 50)
    assert f.accept(2, 50)
    assert not f.accept(1, 50)


def test_restarted_sender_seeded_higher_is_accepted() -> None:
    f = ReplayFilter()
    t = 1_700_000_000.0
    first = wire.seq_seed(t)
    for i in range(1000):  # an hour of frames at a few Hz, as the old process sent
        assert f.accept(3, first + i)
    restarted = wire.seq_seed(t + 5.0)  # the new process seeds from its own clock
    assert restarted > first + 1000
    assert f.accept(3, restarted)
    assert f.accept(3, restarted + 1)
    assert not f.accept(3, first + 999)  # the old process's frames replayed


def _largest_cluster_top(seqs: set[int], floor: int) -> int:
    """`_Seen.established` by its definition, from scratch: the top of the largest
    cluster (neighbours at most WINDOW apart; a tie goes to the higher), else the floor."""
    clusters: list[list[int]] = []
    for s in sorted(seqs):
        if clusters and s - clusters[-1][-1] <= WINDOW:
            clusters[-1].append(s)
        else:
            clusters.append([s])
    if not clusters:
        return floor
    return max(clusters, key=lambda c: (len(c), c[-1]))[-1]


def test_top_kept_between_frames_is_the_one_a_sort_gives() -> None:
    """`top` after every frame of runs mixing in-order frames, reordering, repeats, lone
    frames far ahead (forgeries), gaps around a window and restarts, against the
    definition worked out anew: the top `add` keeps without sorting must never differ
    from it."""
    rng = random.Random(20261127)
    for _ in range(200):
        f, seq = ReplayFilter(), rng.randrange(1, 10**6)
        for _ in range(rng.randrange(1, 400)):
            roll = rng.random()
            if roll < 0.75:
                seq += rng.choice((1, 1, 1, 2, 3))
                got = seq
            elif roll < 0.85:
                got = seq - rng.randrange(0, 2 * WINDOW)  # late or repeated
            elif roll < 0.9:
                got = seq + rng.randrange(WINDOW + 1, 10**5)  # a lone frame far ahead
            elif roll < 0.95:
                seq += rng.randrange(WINDOW - 1, 2 * WINDOW)  # lost frames, about a window
                got = seq
            else:
                seq += rng.randrange(10**3, 10**5)  # a restart, seeded higher
                got = seq
            f.accept(7, got)
            known = f.state[7]
            latest = max([known.main, *known.holes], key=lambda h: h.stamp)
            assert f.top(7) == _largest_cluster_top(latest.seqs, latest.floor)
