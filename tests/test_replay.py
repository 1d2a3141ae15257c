"""Anti-replay window (swarmd.core.replay): order, duplicates, reordering, restarts."""

from __future__ import annotations

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
