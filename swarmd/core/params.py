"""Timing and quorum parameters of the protocol, one frozen dataclass with presets.

Every field carries its unit and the rule it comes from (memberlist's config.go is the
model). Two presets: `udp()` for loopback / Wi-Fi multicast, where frames
are cheap and latency is milliseconds, and `radio()` for XBee / SiK radios, where the
air is shared at 250 kbps and a frame costs milliseconds of airtime.

The takeover bound follows from the fields (`Params.takeover_bound`): a watcher fires
after the patience its belief of the link gives (`belief.py`): `t_max` after the last
heartbeat it heard on a clean link (paper Fig. 7), more on a link that fades in bursts,
never more than `t_max_bursty`. A crash is taken over within `patience + vote_window +
claim_hold` when nothing is lost (two more vote windows under loss).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

from swarmd.core.belief import LEVEL_MAX
from swarmd.core.errors import ParamsError as ParamsError


@dataclass(frozen=True, slots=True)
class Params:
    heartbeat_interval: float
    """s. Period of an ACTIVE robot's HEARTBEAT (the paper's health signal)."""

    standby_heartbeat_interval: float
    """s. Period of a STANDBY robot's HEARTBEAT; lower rate, it only proves the standby is
    alive so watchers know whether anyone is left to take over (DESIGN rule 6, 8)."""

    t_max: float
    """s. Silence after which a watcher suspects a neighbour (paper Fig. 7 T_max).
    Must be >= 2 * heartbeat_interval so one lost frame never raises a suspicion."""

    warn_interval: float
    """s. While a suspicion lasts, the watcher repeats WARN at this period (Fig. 7 keeps
    warning until the substitute answers); repetition beats loss."""

    vote_window: float
    """s. A standby counts warnings from distinct witnesses seen within this window
    (Fig. 9 time window). >= 2 * warn_interval so two watchers' warnings overlap."""

    quorum: int
    """Distinct witnesses needed to claim (paper: two; DESIGN rule 3)."""

    claim_hold: float
    """s. Time spent in CLAIMING (the paper's wait state) listening for a lower-id
    claimant or a refutation before taking over. A few channel latencies."""

    startup_grace: float
    """s. A watched slot never heard from is suspected after this (DESIGN rule 5); a
    link heard for less than this many seconds' worth of heartbeats is not measured yet
    and its watchers' patience is `t_max_bursty` (DESIGN "Detection")."""

    standby_timeout: float
    """s. A standby not heard for this long is taken for dead (DESIGN rule 6)."""

    alert_after: float
    """s. A suspicion with no CLAIM heard for this long raises an `alert`
    (DESIGN rule 8: the paper's "inform a base station")."""

    rejoin_hold: float
    """s. A robot restarted with a function in its persisted state listens this long
    before it resumes, so it learns of a takeover made while it was down (rule 2)."""

    patience_cap: float
    """Times `t_max`. The most patience a watcher's belief may give a link that loses
    heartbeats in bursts (DESIGN "Detection"): its silence is suspected after between
    `t_max` (a clean link, Fig. 7 as configured) and `t_max_bursty` = this x `t_max`,
    which the takeover bound on a lossy link uses. A multiple, so that a file that
    overrides `t_max` alone keeps the same proportion. At least 1 (1: Fig. 7 as is)."""

    suspect_level: float
    """Suspicion level (-log10 of how often a live neighbour is silent that long on the
    link as measured, `belief.py`) at which a watcher suspects it, and that a standby
    needs from each witness and from its own ears before it claims. 2: a silence a live
    robot on that link produces once in a hundred heartbeats. Above 3.7 a link not
    measured yet is given more than `t_max` (`belief.PRIOR_BURSTS`)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "quorum":
                if not isinstance(value, int) or value < 1:
                    raise ParamsError(f"quorum must be an integer >= 1, got {value!r}")
            elif f.name == "suspect_level":
                if not isinstance(value, (int, float)) or not 0 < value <= LEVEL_MAX:
                    raise ParamsError(f"suspect_level must be a number in (0, {LEVEL_MAX}], "
                                      f"got {value!r}")
            elif f.name == "patience_cap":
                if not isinstance(value, (int, float)) or not value >= 1:
                    raise ParamsError(f"patience_cap must be a number >= 1 (times t_max), "
                                      f"got {value!r}")
            elif not isinstance(value, (int, float)) or value <= 0:
                raise ParamsError(f"{f.name} must be a positive number of seconds, got {value!r}")
        if self.t_max < 2 * self.heartbeat_interval:
            raise ParamsError(
                f"t_max ({self.t_max} s) is shorter than two heartbeat intervals "
                f"(2 x {self.heartbeat_interval} s): a single lost heartbeat would raise a "
                "suspicion"
            )
        if self.vote_window < 2 * self.warn_interval:
            raise ParamsError(
                f"vote_window ({self.vote_window} s) must be >= 2 x warn_interval "
                f"({self.warn_interval} s) so warnings of two watchers can meet in it"
            )
        if self.standby_timeout < 2 * self.standby_heartbeat_interval:
            raise ParamsError(
                f"standby_timeout ({self.standby_timeout} s) must be >= 2 x "
                f"standby_heartbeat_interval ({self.standby_heartbeat_interval} s)"
            )

    def with_overrides(self, **overrides: Any) -> Params:
        """A copy with some fields changed, validated again."""
        return replace(self, **overrides)

    def takeover_bound(self, *, lossy: bool = False, patience: float | None = None) -> float:
        """s from a holder's crash to its takeover, at most: every watcher suspects within
        `patience` of the last heartbeat it heard (its belief of the link, `belief.py`,
        kept within [`t_max`, `t_max_bursty`]); the quorum's warnings meet within
        `vote_window` (DESIGN rule 3); then the claim hold (the wait state). On a clean
        link the patience is `t_max` (paper Fig. 7): the bound users configure. On a
        `lossy` channel the links may fade in bursts, so the patience is at most
        `t_max_bursty` (the default there), and the warnings, repeated every
        `warn_interval`, may need two more vote windows. A link not measured yet (heard
        for less than a start-up grace's worth of heartbeats: the run's first seconds, a
        new holder's, a watcher's restart) gets `t_max_bursty` on any channel, so a crash
        then is taken over within `takeover_bound(patience=t_max_bursty)`. The one
        formula `swarmd check` prints and the invariant checker holds runs to."""
        if patience is None:
            patience = self.t_max_bursty if lossy else self.t_max
        wait = min(max(patience, self.t_max), self.t_max_bursty)
        bound = wait + self.vote_window + self.claim_hold
        return bound + 2 * self.vote_window if lossy else bound

    @property
    def t_max_bursty(self) -> float:
        """s. The most patience any link gets (`patience_cap` x `t_max`)."""
        return self.patience_cap * self.t_max

    @property
    def claim_horizon(self) -> float:
        """s a CLAIM silences the slot's watchers, from the first time it is heard (DESIGN
        rule 10): the claim hold, then one `t_max` for the new holder's first heartbeat.
        A claimant not heard heartbeating by then is suspected again."""
        return self.claim_hold + self.t_max

    def as_dict(self) -> dict[str, float | int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


SUSPECT_LEVEL = 2.2
"""The presets' `suspect_level`. Measured on the paper swarm at `udp()` (DESIGN
"Detection"): with 30 % loss in bursts of 8 heartbeats a watcher waits ~1.7 s, so a crash
is still taken over within 2 s, and a live robot is suspected by a quorum and its standby
at once too rarely to be replaced."""


def udp() -> Params:
    """Loopback / Wi-Fi multicast: frames cost nothing, delivery takes milliseconds."""
    return Params(
        heartbeat_interval=0.1,  # 10 Hz: detection in half a second at ~22 B a frame
        standby_heartbeat_interval=0.5,  # standbys only prove liveness
        t_max=0.5,  # five missed heartbeats: a false suspicion needs 5 losses in a row
        warn_interval=0.1,  # one warning per heartbeat period
        vote_window=1.0,  # two watchers' warnings meet in it even at 20% loss
        quorum=2,  # the paper
        claim_hold=0.2,  # 2 heartbeat periods: a live suspect refutes, a rival claims
        startup_grace=2.0,  # processes of one swarm start within a second or two
        standby_timeout=2.0,  # four standby heartbeats
        alert_after=2.0,  # no claim within 4 x t_max: nobody is coming
        rejoin_hold=0.7,  # > t_max + heartbeat: a holder's heartbeat is heard by then
        patience_cap=4.0,  # at most 2 s: 30 % loss in bursts of 8 gets ~1.5 s
        suspect_level=SUSPECT_LEVEL,
    )


def radio() -> Params:
    """XBee / SiK radios at 250 kbps: heartbeats are rationed (see `swarmd check`).

    Tuned on the channel budget (swarmd/services/budget.py): a signed heartbeat costs 2.4 ms of
    802.15.4 airtime, so 30% of the channel carries about 123 heartbeats a second.
    Actives at 1/0.6 s and standbys at 1/8 s fit 107 robots of the paper's shape (2/3
    active), and a 100-robot grid of 60 actives and 40 standbys (configs/grid100-radio.yaml)
    stays below 30% during a failover too."""
    return Params(
        heartbeat_interval=0.6,
        standby_heartbeat_interval=8.0,  # liveness only (rules 6, 8): 16x rarer than actives
        t_max=2.0,  # three missed heartbeats with 0.2 s to spare for CSMA back-off
        warn_interval=0.5,
        vote_window=4.0,
        quorum=2,
        claim_hold=0.8,  # two claims (one per warn_interval) and a heartbeat of a live
        # suspect fall in it; a refutation takes one radio round trip (< 0.1 s)
        startup_grace=10.0,  # radios join a network in seconds
        standby_timeout=24.0,  # three standby heartbeats: a lost one is no dead standby
        alert_after=8.0,
        rejoin_hold=3.0,  # > t_max + heartbeat_interval
        patience_cap=4.0,  # at most 8 s, as at udp 4 x t_max
        suspect_level=SUSPECT_LEVEL,
    )


PRESETS = {"udp": udp, "radio": radio}

UNITLESS = frozenset({"quorum", "patience_cap", "suspect_level"})
"""The fields that are not seconds."""
