"""A belief per watched link (swarmd/core/belief.py; DESIGN "Detection"), on virtual time:
what a watcher measures of a neighbour's heartbeats and the patience it earns."""

from __future__ import annotations

import random
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.core.belief import HALF_LIFE, LEVEL_MAX, LinkBelief, byte_level, level_byte
from swarmd.core.params import Params, radio, udp

P = udp()
H = P.heartbeat_interval
KEY = ("f2", 0)


def heard(gaps: list[float], period: float = H, cap: float = P.t_max_bursty,
          start: float = 0.0) -> LinkBelief:
    """A link whose heartbeats came after these gaps (s)."""
    b = LinkBelief(period)
    t = start
    b.beat(t, KEY, cap)
    for gap in gaps:
        t += gap
        b.beat(t, KEY, cap)
    return b


def patience(b: LinkBelief, p: Params = P) -> float:
    return b.patience(p.suspect_level, p.t_max, p.t_max_bursty)


def gilbert_elliott(loss: float, burst: float, beats: int, seed: int) -> list[float]:
    """Gaps between the heartbeats that got through a two-state bursty channel, as the
    simulator's `--loss-model burst` draws them (sim/shared/channel.py)."""
    rng = random.Random(seed)
    to_good, to_bad = 1 / burst, loss / (burst * (1 - loss))
    bad, gaps, gap = False, [], 0.0
    for _ in range(beats):
        gap += H
        bad = rng.random() >= to_good if bad else rng.random() < to_bad
        if not bad:
            gaps.append(gap)
            gap = 0.0
    return gaps


# ---------------------------------------------------------------------- clean links
@pytest.mark.parametrize("preset", [udp, radio])
def test_a_link_not_measured_yet_waits_t_max(preset: Callable[[], Params]) -> None:
    # Only measured bursts earn patience: the bound users configure holds until then.
    p = preset()
    b = LinkBelief(p.heartbeat_interval)
    assert patience(b, p) == p.t_max
    assert b.level(p.t_max) >= p.suspect_level


def test_a_clean_link_stays_at_t_max() -> None:
    b = heard([H] * 5000)
    assert patience(b) == P.t_max
    assert b.level(0.0) == 0.0 and b.level(H) == 0.0  # the next one is not even late


def test_independent_losses_earn_no_patience() -> None:
    # 20 % of heartbeats lost one at a time: bursts of 1, T_max (5 periods) is right.
    rng = random.Random(1)
    gaps, gap = [], 0.0
    for _ in range(5000):
        gap += H
        if rng.random() >= 0.2:
            gaps.append(gap)
            gap = 0.0
    assert patience(heard(gaps)) == P.t_max


# ---------------------------------------------------------------------- bursty links
@pytest.mark.parametrize(("loss", "burst", "low", "high"),
                         [(0.3, 8.0, 1.2, 2.0), (0.4, 4.0, 0.8, 1.8)])
def test_a_bursty_link_earns_patience(loss: float, burst: float, low: float,
                                      high: float) -> None:
    b = heard(gilbert_elliott(loss, burst, 6000, seed=3))
    enter, mean = b.stats()
    assert enter == pytest.approx(loss / (burst * (1 - loss)), rel=0.35)
    assert mean == pytest.approx(burst, rel=0.35)
    assert low < patience(b) <= high


def test_patience_never_passes_the_cap() -> None:
    # A link that only ever comes back after long outages: as patient as allowed.
    b = heard([3.0] * 200)
    assert patience(b) == P.t_max_bursty


def test_one_outage_does_not_teach_a_clean_link_to_wait() -> None:
    # A fade of 30 s after a minute of clean heartbeats: counted as an outage at the cap
    # (a censored burst), it does not make a clean link slow.
    b = heard([H] * 600 + [30.0] + [H] * 10)
    assert patience(b) == P.t_max


def test_a_link_that_heals_is_fast_again() -> None:
    b = heard(gilbert_elliott(0.3, 8.0, 3000, seed=4))
    assert patience(b) > P.t_max
    t = b.last or 0.0
    for _ in range(int(4 * HALF_LIFE)):
        t += H
        b.beat(t, KEY, P.t_max_bursty)
    assert patience(b) == P.t_max


def test_a_gap_across_a_change_of_slot_or_a_stall_is_no_sample() -> None:
    b = heard([H] * 100)
    t = b.last or 0.0
    b.beat(t + 20.0, ("f3", 1), P.t_max_bursty)  # it took another slot over
    b.forget_gap()  # ...and then we stalled
    b.beat(t + 40.0, ("f3", 1), P.t_max_bursty)
    assert b.stats() == heard([H] * 100).stats()


def test_level_and_its_byte() -> None:
    b = heard(gilbert_elliott(0.3, 8.0, 3000, seed=5))
    wait = patience(b)
    assert b.level(wait) == pytest.approx(P.suspect_level)
    assert b.level(wait - 0.01) < P.suspect_level
    assert byte_level(level_byte(b.level(wait))) <= b.level(wait)
    assert level_byte(LEVEL_MAX) == 255 and level_byte(1e9) == 255 and level_byte(-1) == 0


# ---------------------------------------------------------------------- properties
gap_lists = st.lists(st.one_of(st.just(H), st.floats(0.001, 5.0)), max_size=300)


@settings(max_examples=200, deadline=None)
@given(gap_lists, st.floats(0.0, 10.0), st.floats(0.0, 10.0))
def test_suspicion_is_monotone_in_silence(gaps: list[float], a: float, b: float) -> None:
    link = heard(gaps)
    low, high = sorted((a, b))
    assert 0.0 <= link.level(low) <= link.level(high) <= LEVEL_MAX


@settings(max_examples=200, deadline=None)
@given(gap_lists, st.floats(1.0, 6.0))
def test_patience_is_where_the_level_reaches_the_threshold(gaps: list[float],
                                                          threshold: float) -> None:
    link = heard(gaps)
    wait = link.patience(threshold, P.t_max, P.t_max_bursty)
    assert P.t_max <= wait <= P.t_max_bursty
    if P.t_max < wait < P.t_max_bursty:
        assert link.level(wait) >= threshold - 1e-9
        assert link.level(wait * 0.999) < threshold


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.001, 3.0), min_size=1, max_size=50), st.integers(1, 40))
def test_memory_per_link_is_bounded(gaps: list[float], rounds: int) -> None:
    # However long it listens, a link holds the same few numbers, and its counts stay
    # below what the half-life lets accumulate.
    link = heard(gaps * rounds)
    assert set(LinkBelief.__slots__) >= {"last"} and not hasattr(link, "__dict__")
    ceiling = 1.0 / (1.0 - 0.5 ** (1.0 / HALF_LIFE)) + 10.0
    enter, _ = link.stats()
    assert 0.0 <= enter <= 1.0
    assert all(getattr(link, n) <= ceiling for n in ("_received", "_bursts", "_continued",
                                                     "_ended"))
