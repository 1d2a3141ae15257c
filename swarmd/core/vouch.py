"""Vouching for a suspect heard alive: a robot that heard a suspicion of a slot's holder,
then hears that holder heartbeat, relays that heartbeat once (DESIGN "Detection", "A
heartbeat heard is vouched for"; rule 4 through a third robot's ears).

Per robot, a holder answers a warning about itself with a signed REFUTE that anyone can
relay, so a standby whose own link to the holder is faded still learns it is alive. With a
shared key or unsigned there is no such proof, but nothing is needed: the holder's own
heartbeat is as good a word as any frame of those modes, and re-broadcast verbatim it is
the same frame (sender, seq and, with a key, its tag). Its seq makes it a duplicate where
it was heard first-hand (`replay.py`), and a first hearing where the holder's link had
faded: at the standby, which so hears the suspect (rule 4: its claim ends, its votes
clear), and at a witness, which stops warning. A live robot is then taken over only if
every robot that heard a suspicion of it is also cut off from it, not merely its two
witnesses and its standby.

Only where a takeover may be near: a robot relays a holder's heartbeat only within
`hold` (the vote window) after it heard a strong warning or a claim about that holder
at that epoch (a standby may be counting it), or when its own watch suspected it; and
once per suspicion heard, so each frame it relays answers one warning and the channel
carries at most as many relays as it carried warnings. A clean channel warns about
nobody, so it relays nothing. Pure.
"""

from __future__ import annotations

from swarmd.core.records import Holder


class Vouches:
    """Per slot, the suspicion of its holder heard last and until when it calls for a
    relay of the holder's next heartbeat."""

    __slots__ = ("_armed", "_hold")

    def __init__(self, hold: float) -> None:
        self._hold = hold
        """s a suspicion heard calls for a relay (the vote window: as long as a standby
        counts the warning)."""
        self._armed: dict[str, tuple[Holder, float]] = {}
        """slot -> (the suspected entry, until when)."""

    def suspected(self, f: str, holder: Holder, now: float) -> None:
        """A strong warning or a claim about `holder` of f was heard at `now`."""
        self._armed[f] = (holder, now + self._hold)

    def due(self, f: str, holder: Holder, now: float, *, own: bool = False) -> bool:
        """`holder` of f heartbeated at `now`: relay that heartbeat? Yes after a suspicion
        of that very entry heard within `hold`, or `own` (our own watch suspected it);
        either way the suspicion is answered, and the next relay waits for the next."""
        armed = self._armed.pop(f, None)
        if own:
            return True
        if armed is None:
            return False
        entry, until = armed
        return entry == holder and now <= until

    def clear(self) -> None:
        self._armed.clear()


__all__ = ["Vouches"]
