"""Properties of a slot's view and its merge (`swarmd/core/slots.py`; DESIGN rule 2).

A robot's view of a slot is one entry (epoch, holder) that only moves forward: ordered
by epoch, then at one epoch the LOWER robot id wins (rule 2's tie-break), and merged by
taking the greater. Then every robot that holds the same entries holds the same view,
whatever order it heard them in: the merge is commutative, associative, idempotent and
never lowers a view.

The API this assumes of `swarmd.core.slots` (adjust `_entry`, `_merge`, `_table_*` below,
and only them, if the module names it otherwise): `Entry(epoch, holder)`;
`a.merge(b)` -> the greater entry; `SlotTable()` with `merge(function, entry)` and
`get(function)` -> the entry held. The whole file skips while the module does not exist.
"""

from __future__ import annotations

import itertools
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

slots = pytest.importorskip(
    "swarmd.core.slots",
    reason="swarmd/core/slots.py (the slot entry and its merge) is not in this tree yet")
Entry: Any = slots.Entry
SlotTable: Any = slots.SlotTable


def _entry(epoch: int, holder: int) -> Any:
    return Entry(epoch=epoch, holder=holder)


def _merge(a: Any, b: Any) -> Any:
    return a.merge(b)


def _table_merge(table: Any, function: str, entry: Any) -> None:
    table.merge(function, entry)


def _table_get(table: Any, function: str) -> Any:
    return table.get(function)


def _rank(e: Any) -> tuple[int, int]:
    """Rule 2's order: a higher epoch wins; at one epoch the lower robot id wins."""
    return (e.epoch, -e.holder)


entries = st.builds(_entry, st.integers(0, 0xFFFF), st.integers(1, 0xFFFF))
small = st.builds(_entry, st.integers(0, 3), st.integers(1, 4))
"""Few values, so that equal epochs and equal holders meet often."""


@given(small | entries, small | entries)
def test_merge_is_commutative(a: Any, b: Any) -> None:
    assert _merge(a, b) == _merge(b, a)


@given(small, small, small)
def test_merge_is_associative(a: Any, b: Any, c: Any) -> None:
    assert _merge(_merge(a, b), c) == _merge(a, _merge(b, c))


@given(small | entries)
def test_merge_is_idempotent(a: Any) -> None:
    assert _merge(a, a) == a


@given(small | entries, small | entries)
def test_merge_never_lowers_and_picks_the_winner(a: Any, b: Any) -> None:
    m = _merge(a, b)
    assert m in (a, b)
    assert _rank(m) >= _rank(a) and _rank(m) >= _rank(b)


@given(st.lists(small, min_size=1, max_size=5))
def test_a_table_ends_on_the_greatest_entry_in_any_order(heard: list[Any]) -> None:
    """Robots that hear the same entries in different orders hold the same view, the
    greatest, and no robot's view ever moved backwards on the way."""
    best = max(heard, key=_rank)
    for order in itertools.islice(itertools.permutations(heard), 24):
        table = SlotTable()
        seen: list[Any] = []
        for e in order:
            _table_merge(table, "f1", e)
            seen.append(_table_get(table, "f1"))
        assert seen[-1] == best
        assert all(_rank(x) <= _rank(y) for x, y in itertools.pairwise(seen))
