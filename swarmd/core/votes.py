"""Warning counter of a standby for one slot (paper Fig. 9, DESIGN rule 3).

Counts *distinct* witnesses that warned about the same holder at the same epoch within
`window` seconds. A later warning from the same witness refreshes its time but never
counts twice. Warnings about another holder or epoch start a new count: the standby
follows the slot, not a robot id (rule 1).

A vote stands for a witness that is silent about the suspect *now*, not one that was
(DESIGN "Detection", "The standby combines"): a suspecting witness warns at a steady
cadence until it hears the suspect again, so a standby that keeps hearing the witness
(its heartbeats) after its next warning was due, and no warning, has heard it stop. Its
vote lapses then, rather than a whole window after its last warning, where it met the
next witness's suspicion of a live robot whose link had faded to each in turn. The
cadence is the one measured (the gap between the witness's last two warnings heard), so
a witness that warns slower after its alert (rule 8) keeps its vote between warnings.
No suspecting witness warns slower than that (`cadence_ceiling`, the swarm's
`standby_heartbeat_interval`, Fig. 7's repeated warning as rule 8 slows it): a vote whose
cadence is not measured yet (one warning of a new suspicion) is given that slowest one,
and a gap between two warnings longer than it is no cadence but two suspicions. A vote
resting on a silence that ended just after its one warning then lapses once the witness
is heard with even its slowest next warning overdue, rather than standing the whole
window and meeting the next witness's suspicion of a robot whose links faded each in
turn (DESIGN "Detection", "A vote stands for a witness silent now").
"""

from __future__ import annotations

import math

from swarmd.core.params import Params

LAPSE = 1.5
"""Times the witness's cadence: how overdue its next warning may be, once its
heartbeats show its link to us is up, before its vote lapses. Its warnings and
heartbeats go out on separate schedules, each within a frame's jitter: half a period of
slack lets the warning due arrive first whenever it was sent."""


class VoteCounter:
    __slots__ = ("_cadence", "_ceiling", "_floor", "_warned", "epoch", "subject", "window",
                 "witnesses")

    def __init__(self, window: float, cadence_floor: float = 0.0,
                 cadence_ceiling: float = math.inf) -> None:
        self.window = window
        self.subject: int | None = None
        self.epoch = -1
        self.witnesses: dict[int, float] = {}
        """witness -> when its last warning was heard, for the votes that count."""
        self._warned: dict[int, float] = {}
        """witness -> when its last warning was heard, lapsed or not (its cadence)."""
        self._cadence: dict[int, float] = {}
        """witness -> the gap between its last two warnings heard, at least
        `cadence_floor` (the swarm's `warn_interval`: no witness warns faster)."""
        self._floor = cadence_floor
        self._ceiling = cadence_ceiling
        """s. The slowest a suspecting witness warns (after its alert, rule 8): the
        cadence of a vote not measured yet, and the longest gap that is one."""

    @classmethod
    def of(cls, params: Params) -> VoteCounter:
        """A standby's counter for one slot at the swarm's timing: its vote window; no
        witness warns faster than `warn_interval` nor, suspecting, slower than
        `standby_heartbeat_interval` (after its alert, rule 8)."""
        return cls(params.vote_window, params.warn_interval,
                   params.standby_heartbeat_interval)

    def add(self, witness: int, subject: int, epoch: int, now: float) -> int:
        """Record a warning; return the number of distinct witnesses in the window."""
        if (subject, epoch) != (self.subject, self.epoch):
            self.clear()
            self.subject, self.epoch = subject, epoch
        before = self._warned.get(witness)
        if before is not None and now - before <= min(self.window, self._ceiling):
            self._cadence[witness] = max(self._floor, now - before)
        else:  # a new suspicion of this witness's: its old cadence says nothing
            self._cadence.pop(witness, None)
        self._warned[witness] = now
        self.witnesses[witness] = now
        return self.count(now)

    def witness_heard(self, witness: int, now: float) -> bool:
        """`witness` was heard at `now` (a heartbeat): its link to us is up. If its next
        warning is overdue by its cadence, it stopped suspecting (it heard the suspect):
        its vote lapses. True if it did. A vote whose cadence is not measured yet is
        given the slowest a suspecting witness warns at (it may be one that warns slowly
        after its alert): with no ceiling, it keeps the window."""
        last = self.witnesses.get(witness)
        cadence = self._cadence.get(witness, self._ceiling)
        if last is None or now - last <= LAPSE * cadence:
            return False
        del self.witnesses[witness]
        return True

    def count(self, now: float) -> int:
        horizon = now - self.window
        self.witnesses = {w: t for w, t in self.witnesses.items() if t >= horizon}
        return len(self.witnesses)

    def clear(self) -> None:
        self.subject, self.epoch, self.witnesses = None, -1, {}
        self._warned, self._cadence = {}, {}
