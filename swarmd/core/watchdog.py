"""Per-slot watchdog (paper Fig. 7, with DESIGN rules 1, 5 and 8).

One `SlotWatch` per slot the robot's own slot watches. It follows whoever holds the slot
(rule 1): the node resets it with every heartbeat of the current holder.

    WAITING   never heard the slot's holder; fires after `startup_grace` (rule 5)
    RUNNING   heard; fires `t_max` after the last heartbeat (Fig. 7 T_max)
    DOUBT     silent for `t_max`, but on a link whose belief (`belief.py`) gives it more
              patience than that: warns every `warn_interval` with its (weak) level, so
              the holder hears it and answers (rule 4: ask before accusing), which no
              standby counts; suspects `patience` after the last heartbeat (DESIGN
              "Detection"). On a clean link patience is t_max and this state is skipped
    SUSPECT   patience ran out: warns every `warn_interval` until the holder is heard
              (refuted) or a CLAIM is heard (Fig. 7: "till it receives a message from the
              substitute"); raises an alert once after `alert_after` (rule 8)
    HANDOVER  a CLAIM or LEAVE was heard: silent for `claim_hold + t_max`, waiting for
              the new holder's heartbeat; if none comes, back to SUSPECT, logged as a
              new suspicion; once per episode, so repeated or further claims cannot
              keep the watchers silent (DESIGN rule 10)

The class is pure: the node calls `heard`, `claim_heard` and `fire` with `now` and turns
the returned `Fired` into frames and events; the patience comes from the node's belief
of the holder's link with every heartbeat (`heard`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from swarmd.core.params import Params


class WatchState(Enum):
    WAITING = "waiting"
    RUNNING = "running"
    DOUBT = "doubt"
    SUSPECT = "suspect"
    HANDOVER = "handover"


@dataclass(frozen=True, slots=True)
class Fired:
    """What a deadline produced: `first` is True on the first warning of an episode,
    `alert` when the alert time has just passed; `doubt` for a warning sent in doubt
    (no suspicion yet: nothing to log, a weak level on the wire)."""

    first: bool
    alert: bool
    doubt: bool = False


class SlotWatch:
    __slots__ = ("alerted", "deadline", "function", "handed_over", "last_heard", "params",
                 "patience", "since", "state")

    def __init__(self, function: str, params: Params, now: float,
                 last_heard: float | None = None, patience: float | None = None) -> None:
        self.function = function
        self.params = params
        self.patience = params.t_max if patience is None else patience
        """s of silence after which the holder is suspected (its link's belief)."""
        self.since: float | None = None  # start of the current suspicion episode
        self.handed_over = False  # a CLAIM or LEAVE silenced this episode once already
        self.alerted = False
        self.last_heard = last_heard
        if last_heard is not None:
            # Fig. 7: T_max from the last heartbeat heard, also when that was before this
            # watch began (a standby that takes a slot over has heard its new neighbours
            # as a standby): a neighbour already silent for T_max is suspected at once,
            # not after a start-up grace meant for robots never heard.
            self.state = WatchState.RUNNING
            self.deadline = max(now, last_heard + params.t_max)
        else:
            # Rule 5: a slot not heard yet gets a grace time instead of Fig. 7's
            # endless *waiting* state.
            self.state = WatchState.WAITING
            self.deadline = now + params.startup_grace

    @property
    def suspecting(self) -> bool:
        return self.state in (WatchState.SUSPECT, WatchState.HANDOVER)

    def heard(self, now: float, patience: float | None = None) -> bool:
        """The slot's holder heartbeated; `patience` is what the link's belief allows its
        next silence (default `t_max`, Fig. 7). Returns True if that ends a suspicion."""
        was_suspect = self.suspecting
        self.state = WatchState.RUNNING
        self.last_heard = now
        self.patience = self.params.t_max if patience is None else patience
        self.deadline = now + self.params.t_max  # T_max: the first doubt, or suspicion
        self.since = None
        self.alerted = False
        self.handed_over = False
        return was_suspect

    def claim_heard(self, now: float) -> None:
        """A substitute claimed (or the holder left): stop warning (paper, wait state)
        and give the new holder time to heartbeat."""
        if self.state is WatchState.HANDOVER or self.handed_over:
            # Rule 10: one handover per suspicion episode. Repeated claims never extend
            # the silence; once a claim went unfulfilled, later ones do not silence the
            # warnings either (a claiming standby ignores them; others may race it).
            return
        self.handed_over = True
        if self.since is None:
            self.since = now
        self.state = WatchState.HANDOVER
        self.deadline = now + self.params.claim_hold + self.params.t_max

    def fire(self, now: float) -> Fired:
        """Deadline reached. Call only when `now >= deadline`."""
        p = self.params
        if self.state in (WatchState.RUNNING, WatchState.DOUBT) \
                and self.last_heard is not None and now < self.last_heard + self.patience:
            # Silent for T_max, not yet for the link's patience: ask, do not accuse.
            self.state = WatchState.DOUBT
            self.deadline = min(now + p.warn_interval, self.last_heard + self.patience)
            return Fired(first=False, alert=False, doubt=True)
        # A handover that brought no new holder (rule 10) is a new suspicion, logged
        # again, unless the episode already raised its alert.
        first = self.state in (WatchState.WAITING, WatchState.RUNNING, WatchState.DOUBT) or (
            self.state is WatchState.HANDOVER and not self.alerted)
        if self.since is None:
            self.since = now
        self.state = WatchState.SUSPECT
        alert = False
        if not self.alerted and now - self.since >= p.alert_after:
            self.alerted = alert = True
        # After the alert nobody is coming soon: keep warning, slower, so a standby
        # that appears later can still count (rule 8 without flooding the channel).
        period = p.standby_heartbeat_interval if self.alerted else p.warn_interval
        self.deadline = now + period
        return Fired(first=first, alert=alert)

    def mark_alerted(self) -> None:
        """An alert was raised at once (no live standby): don't raise it again."""
        self.alerted = True

    def refresh(self, now: float) -> None:
        """The node itself stalled (paused process): don't blame the neighbours for
        our own silence (Lifeguard's idea); restart the timer from now."""
        if self.state in (WatchState.RUNNING, WatchState.DOUBT):
            self.state = WatchState.RUNNING
            self.last_heard = now
            self.deadline = now + self.params.t_max
        elif self.state is WatchState.WAITING:
            self.deadline = max(self.deadline, now + self.params.t_max)
