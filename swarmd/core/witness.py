"""Who may speak about a slot, and what this robot heard itself (DESIGN rules 3, 6, 8, 9).

- Rule 3: the witnesses of slot f are the holders of the slots that watch f; never the
  suspect itself (`witnesses`).
- Rules 6 and 8: is anyone left who may take a slot over (`Ears.live_standby`)?
- Rule 9: the standby's own ears stand in for watchers lost with the suspect
  (`Ears.own_ears`), and rule 4 from its own ears: a suspect heard lately is alive
  (`Ears.alive_to_me`).

`Ears` keeps, per slot, the last heartbeat heard *for that slot* (a robot that stopped
heartbeating but still sends other frames, a faulty liar, must not look alive to the
standby that would replace it), per robot its last standby heartbeat, and per robot
heard heartbeating a slot the belief of its link (`belief.py`): how long a silence of
that robot is still no news (DESIGN "Detection"). Pure.
"""

from __future__ import annotations

from collections.abc import Mapping

from swarmd.core.belief import LEVEL_MAX, LinkBelief
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.records import Holder, SlotBeat


def witnesses(plan: SwarmPlan, known: Mapping[str, Holder], f: str) -> set[int]:
    """Rule 3: the robots whose warnings about f's holder count — the holders of the
    slots that watch f, as this robot knows them."""
    return {known[g].robot for g in plan.watched_by(f)}


class Ears:
    __slots__ = ("_links", "_params", "_plan", "_robot_id", "_settle", "_slot_heard",
                 "_standby_at", "_start")

    def __init__(self, robot_id: int, plan: SwarmPlan, params: Params, start: float) -> None:
        self._robot_id = robot_id
        self._plan = plan
        self._params = params
        self._start = start
        self._slot_heard: dict[str, SlotBeat] = {}
        self._standby_at: dict[int, float] = {}
        self._links: dict[int, LinkBelief] = {}
        """robot -> its link's belief; one per robot of the plan at most."""
        self._settle = max(1, round(params.startup_grace / params.heartbeat_interval))
        """Gaps a link must have been heard for before its belief is acted on: a start-up
        grace's worth of heartbeats (rule 5's time for a robot never heard, here for a
        link barely heard; DESIGN "Detection", "A link not measured yet")."""

    def slot_beat(self, f: str, holder: int, epoch: int, now: float) -> None:
        """A heartbeat of f's holder at `epoch` was accepted at `now`."""
        self._slot_heard[f] = SlotBeat(holder, epoch, now)
        link = self._links.get(holder)
        if link is None:
            link = self._links[holder] = LinkBelief(self._params.heartbeat_interval)
        link.beat(now, (f, epoch), self._params.t_max_bursty)

    # ------------------------------------------------------------------ beliefs
    def patience(self, robot: int) -> float:
        """s of silence of `robot`'s slot heartbeats after which this robot, watching
        it, suspects it: `t_max` on a link measured clean, up to `t_max_bursty` on a
        bursty one; and `t_max_bursty` on a link not measured yet (never heard, or heard
        for less than a start-up grace's worth of heartbeats): its first seconds are no
        evidence that it is clean, and a fade then would otherwise be judged by `t_max`
        alone."""
        link = self._links.get(robot)
        if link is None or link.samples < self._settle:
            return self._params.t_max_bursty
        return self._believed(link)

    def _ears_patience(self, robot: int) -> float:
        """The patience a standby's own ears judge `robot`'s silence by (rules 4 and 9):
        the link's belief, `t_max` until it has measured bursts, as on a clean link.
        Unlike a watcher's suspicion, these are a veto on a claim: a longer one on a
        link not measured yet would let a frame of the suspect's heard late (a replay
        that got through) hold a claim back longer than the T_max/2 `alive_to_me`
        promises."""
        link = self._links.get(robot)
        return self._params.t_max if link is None else self._believed(link)

    def _believed(self, link: LinkBelief) -> float:
        p = self._params
        return link.patience(p.suspect_level, p.t_max, p.t_max_bursty)

    def level(self, robot: int, silence: float) -> float:
        """How strongly a `silence` (s) of `robot` is suspected on its link (`belief.py`);
        a robot never heard heartbeating a slot is as suspect as can be."""
        link = self._links.get(robot)
        if link is None:
            return LEVEL_MAX
        if link.samples < self._settle:
            return self._unmeasured_level(silence)
        return link.level(silence)

    def _unmeasured_level(self, silence: float) -> float:
        """The level of a silence on a link not measured yet: rising with each heartbeat
        missed, to `suspect_level` at `t_max_bursty` (its patience), so the doubts sent
        before then stay doubts that no standby counts."""
        p = self._params
        missed = silence / p.heartbeat_interval - 1.0
        most = p.t_max_bursty / p.heartbeat_interval - 1.0
        if missed <= 0.0:
            return 0.0
        return min(LEVEL_MAX, p.suspect_level * missed / most)

    def forget_gaps(self) -> None:
        """This robot stalled: the silences it is about to see are its own."""
        for link in self._links.values():
            link.forget_gap()

    def standby_beat(self, robot: int, now: float) -> None:
        """A healthy standby (or claimant) heartbeat of `robot` was heard at `now`."""
        self._standby_at[robot] = now
        link = self._links.get(robot)
        if link is not None:
            # It heartbeats as a standby now (restarted, fenced, rejoining): its silence
            # on the slot it held was no fade of its link.
            link.forget_gap()

    def heard_lately(self, f: str, holder: int, epoch: int, now: float, within: float) -> bool:
        """Was f heard from `holder` at `epoch` less than `within` ago?"""
        heard = self._slot_heard.get(f)
        return heard is not None and (heard.holder, heard.epoch) == (holder, epoch) \
            and now - heard.at < within

    def alive_to_me(self, f: str, holder: int, epoch: int, now: float) -> bool:
        """Rule 4 from a standby's own ears: on a broadcast medium the standby hears the
        suspect too, so one heard within its own patience for the suspect's link, less
        T_max/2, is alive whatever the witnesses missed: a takeover needs the standby's
        silence to be nearly as unlikely from a live robot as each witness's (DESIGN
        "Detection": a live robot is replaced only if three independent links fade at
        once). On a clean link that is T_max/2, as before beliefs: after a real crash
        the witnesses warn T_max after the last heartbeat, which the standby heard at
        the same moment give or take the channel's jitter, so the first quorum claims;
        a frame of the suspect's heard later (a replay that got through, a refutation)
        holds the claim back for T_max/2, no more."""
        within = self._ears_patience(holder) - self._params.t_max / 2
        return self.heard_lately(f, holder, epoch, now, within)

    def own_ears(self, f: str, known: Mapping[str, Holder], now: float) -> bool:
        """Rule 9: is this standby a witness of f's holder's silence itself?

        Only when (a) it has heard no heartbeat for slot f for T_max — on a broadcast
        medium a live suspect is heard by the standby as well as by its watchers, so a
        liar's warning about a live robot finds the standby's ears against it — and
        (b) fewer than a quorum of f's watchers are alive by their own heartbeats (each
        judged by its own link's patience), so the quorum can no longer be met by
        watchers alone. Never during the start-up grace, when silence means nothing
        yet."""
        p = self._params
        if now - self._start < p.startup_grace:
            return False
        heard = self._slot_heard.get(f)
        if heard is not None and now - heard.at < self._ears_patience(heard.holder):
            return False
        live = len(self._plan.watched_by(f)) - len(self.silent_watchers(f, known, now))
        return live < p.quorum

    def silent_watchers(self, f: str, known: Mapping[str, Holder],
                        now: float) -> frozenset[tuple[str, int]]:
        """Rule 9's lost watchers: f's watcher slots, with their holders as we know
        them, whose heartbeats we have not heard within that holder's patience."""
        silent = set()
        for g in self._plan.watched_by(f):
            beat = self._slot_heard.get(g)
            if beat is None or beat.holder != known[g].robot \
                    or now - beat.at >= self._ears_patience(beat.holder):
                silent.add((g, known[g].robot))
        return frozenset(silent)

    def heard_again(self, watchers: frozenset[tuple[str, int]], since: float) -> bool:
        """Was any of these watchers (slot, holder) heard heartbeating its slot after
        `since`? A new holder of a watcher slot is not one of them."""
        for g, robot in watchers:
            beat = self._slot_heard.get(g)
            if beat is not None and beat.holder == robot and beat.at > since:
                return True
        return False

    def live_standby(self, f: str, subject: int, now: float) -> bool:
        """Is any robot that may take `f` over plausibly alive (rules 6, 8)? A standby
        never heard counts as alive during the start-up grace time only."""
        in_grace = now - self._start < self._params.startup_grace
        for r in self._plan.covered_by(f):
            if r in (subject, self._robot_id):
                continue
            seen = self._standby_at.get(r)
            if seen is None and in_grace:
                return True
            if seen is not None and now - seen <= self._params.standby_timeout:
                return True
        return False


__all__ = ["Ears", "witnesses"]
