"""The slot table: what one robot knows about who executes each function slot (DESIGN
section 2, "Convergence").

Each slot has one entry, a `Holder` (robot, epoch). Entries are totally ordered by
`rank`: a higher epoch is greater (a takeover, DESIGN rule 2); at one epoch a real
holder is greater than nobody, and a lower robot id greater than a higher one (the
paper's race: the lowest id wins). The table only moves forward: `merge` keeps the
greater of the entry held and the entry offered, so it is commutative, associative and
idempotent, and no sequence of merges lowers an entry. Two robots that have merged the
same entries hold the same table whatever the order they heard them in; that is why
views converge once the entries have spread (DESIGN, "Convergence").

Every act that changes who holds a slot produces a strictly greater entry: a takeover
or a handover after LEAVE is the next epoch (`epoch + 1`), and a holder that learns a
greater entry for its own slot stops executing it (it is fenced). Nothing here judges
whether an entry may be believed; that is the node's (a certificate).

Pure data, no rules beyond the order.
"""

from __future__ import annotations

from collections.abc import ItemsView, Iterable, Iterator, Mapping, ValuesView

from swarmd.core.records import Holder

NOBODY = 0
"""The robot id of "nobody holds this slot" (a slot the plan gives no initial holder)."""


def rank(entry: Holder) -> tuple[int, int, int]:
    """The order of entries: epoch first; then anybody over nobody; then the lower id."""
    return entry.epoch, int(entry.robot != NOBODY), -entry.robot


def greater(a: Holder, b: Holder) -> bool:
    """Is entry `a` strictly greater than entry `b`? (Equal entries, a holder heard
    again as we know it, rank alike: no rank worked out.)"""
    return a != b and rank(a) > rank(b)


def join(a: Holder, b: Holder) -> Holder:
    """The greater of two entries: the merge of one slot."""
    return a if rank(a) >= rank(b) else b


class SlotTable(Mapping[str, Holder]):
    """function -> its greatest known entry. A read-only mapping plus `merge`: there is no
    other way to change an entry, so no code path can lower one."""

    __slots__ = ("_entries",)

    def __init__(self, entries: Iterable[tuple[str, Holder]] = ()) -> None:
        self._entries: dict[str, Holder] = {}
        for f, entry in entries:
            self.merge(f, entry)

    def merge(self, f: str, entry: Holder) -> bool:
        """Keep the greater of f's entry and `entry`. True if f's entry rose."""
        old = self._entries.get(f)
        # `old == entry` first: every heartbeat heard merges the entry it shows, almost
        # always the one we know (equal entries rank alike).
        if old is not None and (old == entry or rank(old) >= rank(entry)):
            return False
        self._entries[f] = Holder(*entry)
        return True

    def merge_all(self, other: Mapping[str, Holder]) -> None:
        """Merge every entry of another table (the join of two tables)."""
        for f, entry in other.items():
            self.merge(f, entry)

    def __getitem__(self, f: str) -> Holder:
        return self._entries[f]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)

    # The dict's own read-only views: the same entries as Mapping's generic ones, without
    # a lookup per entry (a daemon reads the table every tick: `Node.standing`).
    def items(self) -> ItemsView[str, Holder]:
        return self._entries.items()

    def values(self) -> ValuesView[Holder]:
        return self._entries.values()

    def __contains__(self, f: object) -> bool:
        return f in self._entries

    def __repr__(self) -> str:
        return f"SlotTable({self._entries!r})"


__all__ = ["NOBODY", "SlotTable", "greater", "join", "rank"]
