"""The slot table's merge (swarmd/core/slots.py; DESIGN section 2, "Convergence"): a
join, so views that merged the same entries agree whatever the order, and no merge
ever lowers an entry."""

from __future__ import annotations

import random
from functools import reduce

from hypothesis import given
from hypothesis import strategies as st

from swarmd.core.records import Holder
from swarmd.core.slots import NOBODY, SlotTable, greater, join, rank

entries = st.builds(Holder, st.integers(0, 6), st.integers(0, 4))
slots = st.sampled_from(("f1", "f2", "f3"))
updates = st.lists(st.tuples(slots, entries), max_size=12)


def table(items: list[tuple[str, Holder]]) -> dict[str, Holder]:
    t = SlotTable()
    for f, e in items:
        t.merge(f, e)
    return dict(t)


@given(entries, entries)
def test_join_is_commutative(a: Holder, b: Holder) -> None:
    assert join(a, b) == join(b, a)


@given(entries, entries, entries)
def test_join_is_associative(a: Holder, b: Holder, c: Holder) -> None:
    assert join(join(a, b), c) == join(a, join(b, c))


@given(entries)
def test_join_is_idempotent(a: Holder) -> None:
    assert join(a, a) == a


@given(updates, st.randoms(use_true_random=False))
def test_the_order_of_merges_does_not_matter(items: list[tuple[str, Holder]],
                                             rnd: random.Random) -> None:
    shuffled = list(items)
    rnd.shuffle(shuffled)
    assert table(items) == table(shuffled)


@given(updates, updates)
def test_merging_two_tables_is_their_join(a: list[tuple[str, Holder]],
                                          b: list[tuple[str, Holder]]) -> None:
    left = SlotTable(a)
    left.merge_all(SlotTable(b))
    assert dict(left) == table(a + b)


@given(updates)
def test_no_merge_lowers_an_entry(items: list[tuple[str, Holder]]) -> None:
    t = SlotTable()
    for f, e in items:
        before = t.get(f)
        rose = t.merge(f, e)
        after = t[f]
        if before is not None:
            assert rank(after) >= rank(before)
            assert rose == greater(e, before)
        assert rank(after) >= rank(e)
    assert dict(t) == {f: reduce(join, [e for g, e in items if g == f])
                       for f in {g for g, _ in items}}


def test_the_order_is_epoch_then_somebody_then_the_lower_id() -> None:
    assert greater(Holder(9, 1), Holder(1, 0))       # a takeover outranks any older hold
    assert greater(Holder(1, 0), Holder(NOBODY, 0))  # a holder outranks nobody
    assert greater(Holder(2, 3), Holder(5, 3))       # the paper's race: the lowest id wins
    assert not greater(Holder(5, 3), Holder(5, 3))


def test_a_broken_merge_that_keeps_the_last_entry_fails_these_laws() -> None:
    """The laws above can fail: "keep the last entry heard" is not commutative."""
    def last(a: Holder, b: Holder) -> Holder:
        return b

    a, b = Holder(1, 2), Holder(3, 1)
    assert last(a, b) != last(b, a)
    assert join(a, b) == join(b, a) == a
