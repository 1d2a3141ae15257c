"""What a robot believes of one neighbour's link: its suspicion level for a silence
(DESIGN section 2, "Detection: a belief per link"; the paper's future work).

Fig. 7 suspects a neighbour after one fixed T_max of silence. A radio loses frames in
bursts (a fade, a collision run), and on such a link one number cannot be right: short
enough to catch a crash quickly, it suspects a live robot at every long fade. So every
robot keeps, per neighbour it hears heartbeating a slot, what it measured of that
link and turns the current silence into a suspicion level, as phi-accrual detectors do
(Hayashibara et al.; Akka, Cassandra), with the loss model of a fading radio in place of
their normal or exponential gaps:

- the link is a two-state (Gilbert-Elliott) channel: after a heartbeat that got through,
  the next one is lost with probability `p_enter`; once one is lost, the next one is
  lost too with probability `q` (a burst lasts 1 / (1 - q) heartbeats on average);
- both are estimated from the gaps between heartbeats heard: a gap of k + 1 periods is
  a burst of k lost heartbeats (k - 1 of them continued it, then it ended). A gap longer
  than the patience cap is an outage, not a burst: it is counted only up to the cap
  (a censored sample), so one fault does not teach the link to wait forever;
- the counts decay with a half-life of `HALF_LIFE` heartbeat periods, so memory per link
  is six numbers, whatever the run's length, and a link that heals earns its speed back;
- a silence of x + 1 periods (x heartbeats missed) is as likely as `p_enter * q^(x-1)`
  for a live neighbour: the suspicion level is minus its log10 (2 means one silence in a
  hundred this long, on this link, from a live robot), rising linearly with silence.

The watcher suspects when the level reaches the swarm's `suspect_level`, but never
sooner than `t_max` (a clean link stays exactly as fast as Fig. 7 makes it) nor later
than `t_max_bursty` (the takeover stays bounded; `Params.takeover_bound`). A link not
measured yet is believed a clean one (`PRIOR_*`), but that belief is not acted on until
the link has been heard for a start-up grace's worth of heartbeats (`samples`; the
watcher's `Ears` gives it the cap until then, DESIGN "Detection").

Pure, on whatever clock `now` comes from (virtual time in the simulator).
"""

from __future__ import annotations

import math

HALF_LIFE = 1024.0
"""Heartbeat periods (102 s at `udp()`, 10 min at `radio()`) after which a measured gap
weighs half: long enough for a 30 % bursty link to show a few dozen bursts, so one
unlucky minute does not swing the patience; short enough that a link that heals is fast
again within minutes."""

PRIOR_RECEIVED = 5.0
PRIOR_BURSTS = 0.001
PRIOR_CONT = 1.5
PRIOR_ENDED = 0.5
"""What a link not measured yet is believed to be, worth five heartbeats of evidence: a
clean one (one heartbeat in 5,000 lost: level 3.7 for one loss, so `t_max` for any
`suspect_level` up to that), whose bursts, if any, would last four heartbeats (1.5 lost
heartbeats went on, 0.5 bursts ended). Only measured bursts earn patience, so the
takeover bound users configure holds on any link until it has faded; light, so that a
bursty link earns its patience with its first burst or two (about 1.2 s of patience
after one burst of 7 lost heartbeats in its first 20)."""

LEVEL_MAX = 25.5
"""The highest level a warning carries (one byte in tenths, `wire.Warn.belief`): a
silence that a live robot on this link produces less than once in 10^25 tries."""


class LinkBelief:
    """One neighbour's heartbeats as one robot heard them: the burst model's counts
    (decayed), and when and what it last heartbeated."""

    __slots__ = ("_bursts", "_continued", "_ended", "_key", "_period", "_received",
                 "last", "samples")

    def __init__(self, period: float) -> None:
        self._period = period
        """s. The neighbour's heartbeat period (an ACTIVE robot's, `heartbeat_interval`)."""
        self._received = PRIOR_RECEIVED
        """Heartbeats heard whose successor's fate is known (the chances to lose one)."""
        self._bursts = PRIOR_BURSTS
        """Of those, how many the next heartbeat after was lost (a burst began)."""
        self._continued = PRIOR_CONT
        """Lost heartbeats that followed a lost one (a burst went on)."""
        self._ended = PRIOR_ENDED
        """Bursts seen to end (the next heartbeat got through)."""
        self._key: object = None
        self.samples = 0
        """Gaps learnt so far, not decayed: how much of this link has been measured."""
        self.last: float | None = None
        """When its last heartbeat was heard (None: since a restart of the count)."""

    # ------------------------------------------------------------------ learning
    def beat(self, now: float, key: object, cap: float) -> None:
        """A heartbeat heard at `now`, about `key` (its slot and epoch). The gap since
        the previous one is a sample only if both were about the same thing: a robot
        that changed slot or role was not silent on its link, it had nothing to say.
        Gaps are counted only up to `cap` (s), the patience cap."""
        last, self.last = self.last, now
        same, self._key = key == self._key, key
        if last is None or not same or now < last:
            return
        self._learn(now - last, cap)

    def forget_gap(self) -> None:
        """The next gap is not the link's doing (this robot itself stalled: DESIGN rule
        on own stalls, Lifeguard's local health): do not learn from it."""
        self.last = None

    def _learn(self, gap: float, cap: float) -> None:
        missed = max(0, round(gap / self._period) - 1)
        most = max(1, round(cap / self._period) - 1)
        decay = 0.5 ** ((min(missed, most) + 1) / HALF_LIFE)
        self.samples += 1
        self._received = self._received * decay + 1.0
        self._bursts *= decay
        self._continued *= decay
        self._ended *= decay
        if not missed:
            return
        self._bursts += 1.0
        if missed > most:  # an outage: known to have lasted `most` at least
            self._continued += most - 1
        else:
            self._continued += missed - 1
            self._ended += 1.0

    # ------------------------------------------------------------------ judging
    def _slopes(self) -> tuple[float, float]:
        """(-log10 p_enter, -log10 q): the level one lost heartbeat is worth, and each
        further one."""
        enter = min(1.0, self._bursts / self._received)
        stay = self._continued / (self._continued + self._ended)
        first = -math.log10(enter) if enter > 0 else math.inf
        further = -math.log10(stay) if stay > 0 else math.inf
        return first, further

    def level(self, silence: float) -> float:
        """Suspicion level (0 .. LEVEL_MAX) after `silence` seconds without a heartbeat:
        -log10 of how often a live neighbour on this link is silent that long.
        Non-decreasing in `silence`."""
        missed = silence / self._period - 1.0
        if missed <= 0.0:
            return 0.0
        first, further = self._slopes()
        # The first lost heartbeat costs `first`, each one after it `further`.
        value = missed * first if missed <= 1.0 else first + (missed - 1.0) * further
        return min(LEVEL_MAX, value)

    def patience(self, threshold: float, floor: float, cap: float) -> float:
        """Seconds of silence after which the level reaches `threshold`, kept within
        [floor, cap] (the configured `t_max` and `t_max_bursty`)."""
        first, further = self._slopes()
        if first >= threshold:
            missed = threshold / first
        elif math.isinf(further):
            missed = 1.0  # no burst ever went on: a second lost heartbeat is news
        elif further <= 0.0:
            return cap  # every burst went on (outages only): wait as long as allowed
        else:
            missed = 1.0 + (threshold - first) / further
        return min(cap, max(floor, self._period * (1.0 + missed)))

    def stats(self) -> tuple[float, float]:
        """(p_enter, mean burst length in heartbeats) as measured, for logs and tests."""
        first, further = self._slopes()
        enter = 10.0 ** -first
        stay = 10.0 ** -further
        return enter, 1.0 / (1.0 - stay) if stay < 1.0 else math.inf


def level_byte(level: float) -> int:
    """A level as a warning carries it: tenths, 0..255."""
    return max(0, min(255, math.floor(level * 10.0)))


def byte_level(value: int) -> float:
    """The level a warning's byte stands for."""
    return value / 10.0


__all__ = ["HALF_LIFE", "LEVEL_MAX", "LinkBelief", "byte_level", "level_byte"]
