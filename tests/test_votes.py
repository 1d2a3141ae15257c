"""Warning counter of a standby (paper Fig. 9, DESIGN rule 3), as a table."""

from __future__ import annotations

import pytest

from swarmd.core.votes import VoteCounter

# (witness, subject, epoch, now) steps and the count expected after each.
CASES = {
    "distinct witnesses": ([(1, 2, 0, 0.0), (3, 2, 0, 0.1)], [1, 2]),
    "same witness twice counts once": ([(1, 2, 0, 0.0), (1, 2, 0, 0.1)], [1, 1]),
    "window expiry": ([(1, 2, 0, 0.0), (3, 2, 0, 1.5)], [1, 1]),
    "refresh keeps a witness in the window": (
        [(1, 2, 0, 0.0), (1, 2, 0, 0.9), (3, 2, 0, 1.5)], [1, 1, 2]),
    "new subject resets": ([(1, 2, 0, 0.0), (3, 4, 0, 0.1)], [1, 1]),
    "new epoch resets": ([(1, 2, 0, 0.0), (3, 2, 1, 0.1)], [1, 1]),
    "edge of the window still counts": ([(1, 2, 0, 0.0), (3, 2, 0, 1.0)], [1, 2]),
}


@pytest.mark.parametrize(("steps", "counts"), CASES.values(), ids=CASES.keys())
def test_votes(steps: list[tuple[int, int, int, float]], counts: list[int]) -> None:
    v = VoteCounter(window=1.0)
    got = [v.add(w, s, e, t) for w, s, e, t in steps]
    assert got == counts


def test_count_ages_out_and_clear_resets() -> None:
    v = VoteCounter(window=1.0)
    v.add(1, 2, 0, 0.0)
    v.add(3, 2, 0, 0.5)
    assert v.count(1.2) == 1
    assert v.count(2.0) == 0
    v.add(1, 2, 0, 3.0)
    v.clear()
    assert (v.subject, v.epoch, v.witnesses) == (None, -1, {})
    assert v.add(3, 2, 0, 3.1) == 1


def test_a_witness_heard_with_its_warning_overdue_loses_its_vote() -> None:
    """A vote stands for a witness silent about the suspect now (`votes.py`): heard
    (a heartbeat) past its cadence with no warning, it stopped suspecting."""
    v = VoteCounter(window=1.0, cadence_floor=0.1)
    v.add(1, 2, 0, 0.0)
    v.add(1, 2, 0, 0.1)  # its cadence: 0.1 s
    assert not v.witness_heard(1, 0.14)  # its next warning may still be on its way
    assert v.witness_heard(1, 0.3)  # due at 0.2: it heard the suspect again
    assert v.add(3, 2, 0, 0.5) == 1  # the window alone would have counted 2


def test_a_vote_whose_cadence_is_unknown_or_slow_keeps_the_window() -> None:
    v = VoteCounter(window=1.0, cadence_floor=0.1)
    v.add(1, 2, 0, 0.0)
    assert not v.witness_heard(1, 0.5)  # one warning: its cadence is unknown
    v.add(1, 2, 0, 0.5)  # a witness that alerted warns slower (rule 8)
    assert not v.witness_heard(1, 1.1)
    assert v.add(3, 2, 0, 1.2) == 2
    # A new suspicion of the same witness (past the window) forgets the old cadence.
    v.add(4, 2, 0, 3.0)
    v.add(4, 2, 0, 3.1)
    v.add(4, 2, 0, 5.0)
    assert not v.witness_heard(4, 5.4)


def test_a_vote_with_no_cadence_is_given_the_slowest_a_witness_warns_at() -> None:
    """No suspecting witness warns slower than `cadence_ceiling` (after its alert, rule
    8): one warning, then its heartbeats past 1.5 of that with no warning, and its vote
    lapses; a gap longer than the ceiling is two suspicions, not a cadence."""
    v = VoteCounter(window=1.0, cadence_floor=0.1, cadence_ceiling=0.5)
    v.add(3, 2, 0, 10.443)
    v.add(3, 2, 0, 11.408)  # 0.965 s after: a new suspicion, no cadence of 0.965 s
    assert not v.witness_heard(3, 12.1)  # even its slowest next warning may be coming
    assert v.witness_heard(3, 12.2)
    assert v.add(1, 2, 0, 12.267) == 1  # the window alone would have counted 2
