"""bench/bench_chaos.py in CI: a sample of random swarms (up to 12 robots, so that it is
fast) and schedules of every fault kind, judged by sim.shared.invariants. The sample
keeps the suite within its time; the bench runs the thousands (docs/testing.md).

No kind of violation may occur, `no_takeover_correlated` included (a slot not taken
over while a neighbour failed with it: DESIGN rule 9 covers it)."""

from __future__ import annotations

import importlib.util
import itertools
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from sim.shared.faults import ATTACKS, parse_fault
from sim.shared.invariants import Violation
from swarmd.core.params import radio, udp

ROOT = Path(__file__).resolve().parent.parent
SEEDS = 50


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_chaos", ROOT / "bench" / "bench_chaos.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_chaos"] = mod
    spec.loader.exec_module(mod)
    return mod


def assert_clean(found: Mapping[str, Sequence[tuple[int, Violation]]]) -> None:
    """No violation of any kind: the first three of each kind, seed and detail, if any."""
    hits = {k: [(s, v.detail) for s, v in h[:3]] for k, h in found.items()}
    assert hits == {}, hits


def test_drawn_cases_are_valid_and_replayable() -> None:
    bench = _bench()
    for seed in range(50):
        case = bench.draw_case(seed, max_robots=60)
        assert case == bench.draw_case(seed, max_robots=60)  # a seed replays
        plan = case.plan
        assert 3 <= len(plan.robots) <= 60
        assert 1 <= sum(1 for p in plan.robots.values() if p.function is None) <= 5
        assert all(len(plan.watched_by(f)) >= 2 for f in plan.functions)  # the quorum
        assert 0.0 <= case.loss <= 0.3
        for f in case.faults:
            assert parse_fault(f.spec()) == f
            assert set(f.robots) <= set(plan.robots)


def test_random_chaos_breaks_no_invariant_the_protocol_promises() -> None:
    bench = _bench()
    found = bench.chaos(range(SEEDS), max_robots=12, verbose=False)
    assert_clean(found)


DENSE_FOUND = (543, 1104, 1669, 1672, 1867)
"""Dense seeds that broke convergence before (README, "Random chaos"): views that
disagreed after a new holder died before a cut-off robot heard it, or after a holder cut
off through its takeover executed on."""


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_dense_chaos_converges_in_every_auth_mode(auth: str) -> None:
    """`--dense` (4-8 faults within 1.5 s, mostly on neighbours) in each mode: a rule
    proven unsigned is not proven signed, nor the other way round."""
    bench = _bench()
    seeds = [*range(25), *DENSE_FOUND]
    found = bench.chaos(seeds, max_robots=12, verbose=False, dense=True, auth=auth)
    assert_clean(found)


CLASSIC_FINGERPRINT = "bbd90d62597ea7cc"
"""A digest of the classic draw (seeds 0-99, plain and `--dense`) as it was before
`--wide` existed: old seeds must replay exactly."""


def _draw_digest(max_robots: int, wide: int = 0) -> str:
    """A digest of the draws of seeds 0-99, plain and `--dense` (`wide`: with the
    compound kinds drawn, `bench_chaos.draw_case`)."""
    import hashlib

    bench = _bench()
    h = hashlib.blake2b(digest_size=8)
    for seed in range(100):
        for dense in (False, True):
            c = bench.draw_case(seed, max_robots, dense, wide)
            h.update(repr((c.loss, c.loss_model, c.burst_len, c.duration,
                           *((c.compound,) if wide else ()),
                           [f.spec() for f in c.faults],
                           sorted((r, p.function, p.subs) for r, p in c.plan.robots.items())
                           )).encode())
    return h.hexdigest()


def test_the_classic_draw_is_unchanged_so_old_seeds_replay() -> None:
    assert _draw_digest(60) == CLASSIC_FINGERPRINT


WIDE_FINGERPRINTS = {1: "23e2479c8b33b945", 2: "73818875aab18f0d", 3: "54584970f6e9d071",
                     4: "b667ba492153dd6a"}
"""Digests of the `--wide`, `--wider`, `--widest` and `--wiped` draws (seeds 0-99 of up
to 12 robots, plain and `--dense`): the wide and wider ones as they were before
`--widest` existed, the widest and wiped ones as docs/sim.md's figures were measured. A
seed run once replays."""


@pytest.mark.parametrize("wide", sorted(WIDE_FINGERPRINTS))
def test_the_wide_draws_are_unchanged_so_their_seeds_replay(wide: int) -> None:
    assert _draw_digest(12, wide) == WIDE_FINGERPRINTS[wide]


def _wide_case(bench: ModuleType, seed: int, wide: int) -> Any:
    """The case `seed` draws at `wide` level (up to 12 robots), with what every wide draw
    promises: it replays, each compound kind it names has the shape `wide_kinds`
    recognises, and each fault reads back from its SPEC and names robots of the swarm."""
    case = bench.draw_case(seed, 12, wide=wide)
    assert case == bench.draw_case(seed, 12, wide=wide)  # a wide seed replays
    assert set(case.compound) <= set(bench.wide_kinds(case)), case.describe()
    for f in case.faults:
        assert parse_fault(f.spec()) == f and set(f.robots) <= set(case.plan.robots)
    return case


def test_the_wide_draw_draws_every_compound_link_fault() -> None:
    """`--wide` adds overlapping one-way cuts, a robot muted while a group is cut, fades
    during restarts, deafness during a takeover and bursty loss up to 40 %, on top of
    the classic draw of the same seed; each kind drawn has the shape it names."""
    bench = _bench()
    drawn: set[str] = set()
    for seed in range(60):
        case = _wide_case(bench, seed, 1)
        assert case == bench.draw_case(seed, 12, wide=True)  # `True` is level 1
        classic = bench.draw_case(seed, 12)
        assert case.faults[:len(classic.faults)] == classic.faults
        assert 1 <= len(case.compound) <= 2 and 0.0 <= case.loss <= 0.4
        assert sum(f.kind == "partition" and not f.oneway for f in case.faults) <= 1
        drawn.update(case.compound)
    assert drawn == set(bench.WIDE_KINDS)


def test_the_wider_draw_splits_the_swarm_in_groups_cut_both_ways() -> None:
    """`--wider` draws from the wide kinds and `split-groups`: three or four groups, every
    pair cut both ways (a one-way cut each way, same start and length), the pairs
    starting and healing at their own times. A `--wide` seed draws what it always drew."""
    bench = _bench()
    drawn: set[str] = set()
    alone = 0
    for seed in range(60):
        case = _wide_case(bench, seed, 2)
        assert bench.draw_case(seed, 12, wide=1) == bench.draw_case(seed, 12, wide=True)
        drawn.update(case.compound)
        if case.compound != ("split-groups",):
            continue  # alone, so that its cuts are the only one-way cuts added
        alone += 1
        classic = bench.draw_case(seed, 12)
        cuts = [f for f in case.faults[len(classic.faults):] if f.oneway]
        pairs = {frozenset(f.groups) for f in cuts}
        groups = {g for pair in pairs for g in pair}
        assert len(groups) in (3, 4) and len(pairs) == len(groups) * (len(groups) - 1) // 2
        assert sorted(r for g in groups for r in g) == sorted(case.plan.robots)
        for f in cuts:
            if frozenset(f.groups) in pairs:
                assert any(g.groups == f.groups[::-1] and (g.at, g.end) == (f.at, f.end)
                           for g in cuts)
        assert len({(f.at, f.end) for f in cuts}) > 1  # the pairs heal at their own times
    assert drawn == set(bench.WIDER_KINDS) and alone >= 3


def test_the_widest_draw_flaps_links_and_fails_holders_inside_cuts() -> None:
    """`--widest` draws from the wider kinds and five more: a robot's link flapping
    (three to six short fades, or cuts from it to its neighbours, one after the other), a
    holder leaving or turning unhealthy inside a two-way cut around it, a holder paused
    while some neighbours are unheard by it, a crashed holder's standby paused around
    its claim, a new holder restarting after its takeover. Each has the shape it names
    (that a `--wider` seed draws what it always drew:
    `test_the_wide_draws_are_unchanged_so_their_seeds_replay`)."""
    bench = _bench()
    drawn: set[str] = set()
    alone: set[str] = set()
    for seed in range(120):
        case = _wide_case(bench, seed, 3)
        drawn.update(case.compound)
        if len(case.compound) != 1 or case.compound[0] in bench.WIDER_KINDS:
            continue
        added = case.faults[len(bench.draw_case(seed, 12).faults):]
        kind = case.compound[0]
        alone.add(kind)
        if kind == "flapping":
            assert 3 <= len(added) <= 6 and len({f.robots[0] for f in added}) == 1
            for one, then in itertools.pairwise(added):  # one after the other
                assert one.end is not None and one.end < then.at
        elif kind == "handover-while-cut":
            *cut, act = added
            holder = act.robots[0]
            assert act.kind in ("leave", "unhealthy")
            assert case.plan.robots[holder].function is not None
            assert len(cut) == 2 and cut[0].groups == cut[1].groups[::-1]
            assert holder in cut[0].groups[0] and cut[0].at <= act.at <= (cut[0].end or 0)
        elif kind == "pause-while-cut":
            pause, cut = added
            assert pause.kind == "pause" and cut.oneway and cut.groups[1] == pause.robots
            assert pause.at <= cut.at <= (pause.end or 0)
        else:  # the standby of a holder that failed: paused, or restarted
            fail, then = added
            holder, standby = fail.robots[0], then.robots[0]
            g = case.plan.robots[holder].function
            assert g is not None and standby != holder and standby in case.plan.covered_by(g)
            if kind == "pause-claimant":
                assert (fail.kind, then.kind) == ("crash", "pause")
                assert 0.3 <= then.at - fail.at <= 1.2
            else:
                assert fail.kind in ("crash", "pause") and then.kind == "restart"
                assert then.at - fail.at >= udp().takeover_bound()
    assert drawn == set(bench.WIDEST_KINDS)
    assert alone == set(bench.WIDEST_KINDS) - set(bench.WIDER_KINDS)  # each shape checked


def test_the_wiped_draw_restarts_a_robot_without_its_state_file() -> None:
    """`--wiped`: every case holds a robot that crashes, leaves, turns faulty or is paused
    and comes back without its state file (`restart:R@T:wiped`), at times twice, beside
    up to one of the widest kinds; the classic draw of the seed stays under it."""
    bench = _bench()
    hows: set[str] = set()
    twice = 0
    for seed in range(80):
        case = _wide_case(bench, seed, 4)
        assert case.compound[0] == bench.WIPED_KIND and len(case.compound) <= 2
        classic = bench.draw_case(seed, 12)
        assert case.faults[:len(classic.faults)] == classic.faults
        wiped = [f for f in case.faults if f.wiped]
        assert wiped and all(f.kind == "restart" for f in wiped)
        robot = wiped[0].robots[0]
        assert all(f.robots == (robot,) for f in wiped)
        fail = next(f for f in case.faults[len(classic.faults):] if f.robots == (robot,))
        assert fail.kind in ("crash", "leave", "unhealthy", "pause") and fail.at < wiped[0].at
        hows.add(fail.kind)
        twice += len(wiped) == 2
    assert hows == {"crash", "leave", "unhealthy", "pause"} and twice >= 10


def test_the_wiped_all_draw_also_wipes_a_standby_around_its_claim_or_its_new_hold() -> None:
    """`--wiped-all`: every case holds one of the wiped kinds; a wiped claimant is the
    first standby covering a crashed holder's slot, back without its state file within
    1.4 s of the crash (around its claim); a wiped new holder is that standby, crashed
    or restarted once the takeover bound has passed, back wiped; a `--wiped` seed
    replays as before."""
    bench = _bench()
    drawn: set[str] = set()
    for seed in range(120):
        case = _wide_case(bench, seed, 5)
        kind = case.compound[0]
        assert kind in bench.WIPED_KINDS and len(case.compound) <= 2
        drawn.add(kind)
        assert _wide_case(bench, seed, 4) == bench.draw_case(seed, 12, wide=4)
        if kind == bench.WIPED_KIND:
            continue
        n = len(bench.draw_case(seed, 12).faults)
        fail, first = case.faults[n:n + 2]
        then = case.faults[n + 1:n + (3 if first.kind == "crash" else 2)]
        back, standby = then[-1], first.robots[0]
        g = case.plan.robots[fail.robots[0]].function
        assert g is not None and standby in case.plan.covered_by(g)
        assert back.kind == "restart" and back.wiped
        assert all(f.robots == (standby,) for f in then)
        if kind == "wiped-claimant":
            assert fail.kind == "crash" and 0.3 <= back.at - fail.at <= 1.4
        else:
            assert fail.kind in ("crash", "pause")
            assert then[0].at - fail.at >= udp().takeover_bound()
            assert then[0].kind in ("crash", "restart")
    assert drawn == set(bench.WIPED_KINDS)


WIDE_FIXED: tuple[int, ...] = (21,)
"""Wide seeds (`python bench/bench_chaos.py --seed N --wide --verbose`, 3-60 robots) that
broke an invariant on the core before the slot table (swarmd/core/slots.py) and run
clean since, in every mode (`test_wide_seeds_fixed_run_clean_in_every_mode`).
- 21, per robot (clean unsigned and with a shared key): robot 21 restarts through a fade
  and takes its slot back; it drops its neighbour 22's heartbeats as `unanchored` for
  longer than T_max, warns about 22 (alive, holding f22 at epoch 1, no standby covers
  f22), then hears it again without logging an answer: `warning_unresolved`."""

WIDE_SMALL: tuple[int, ...] = (5, 50, 84, 99, 136, 144, 147, 172, 182, 195, 279, 321, 365,
                                383, 1713, 73506, 94471, 97376, 101757, 104525)
"""Wide seeds on swarms of up to 12 robots (`python bench/bench_chaos.py --seed N --wide
--max-robots 12 --verbose`) that broke an invariant per robot on the slot-table core as
first merged, each a shape the table's proofs had to cover; clean in every mode since
(`test_wide_small_seeds_run_clean_in_every_mode`):
- 5, 99, 147: two robots executed one slot for about 10 s, views split at the end: a
  refuted takeover judged by whichever warnings each robot held (now one signed frame
  decides it, the holder's REFUTE of the claim), and a reassertion that never reached a
  robot whose view had moved on to a rival at its epoch;
- 279, 321, 365, 383: a restarted standby kept its state file's view of a takeover that
  was since refuted (its proof, relayed, did not certify the entry it already held);
- 84, 50, 144, 172, 182, 195: fenced at a reassertion's epoch before the holder logged it
  (the checker now knows the reassertion);
- 136: a suspicion of a takeover the reassertion outranked was never answered;
- 1713: a robot that took a slot over unheard (a fade), left it faulty and restarted kept
  its state file's entry naming itself: an entry nobody could be shown a proof of, and
  views split for good (a restarted robot now keeps its own entry only for the slot it
  held);
- 73506: a robot restarted within its start-up grace cannot judge the LEAVE behind the
  slot's current entry yet, so it warns about the holder its stale view names, which a
  greater entry had already fenced; it merges the entry once the grace ends. The checker
  counted that warning unresolved: a warning about a fenced holder is now resolved by
  the entry that fenced it, as one about a replaced holder is by the takeover;
- 94471 (with a shared key and unsigned): a holder restarted on its state file resumed
  its slot, cut off from the robot that had taken it over meanwhile; past the cut it
  heard the new holder's heartbeat within its start-up grace, held it (it could not
  judge it yet) and released the slot at once, fenced at the grace's end. The log shows
  only the fence, and the checker counted both robots executing until then: it now
  reads what the robot link is told (`Release`, `Assign`) as the virtual simulator
  hands it over;
- 97376: a holder restarted as a standby took its own slot over (its watchers warned of
  its silence), crashed unheard, and restarted on that entry; two watchers that missed
  the takeover suspected it at its old epoch and, once it resumed, heard it at the new
  one, which ended their suspicion without a word in the log (a newer epoch was taken
  for another robot's takeover): the suspect itself heard at any epoch is now refuted.
- 101757 (with a shared key and unsigned, once they took the per-robot proof path): a
  holder stopped for 4 s, whose slot its standby took over meanwhile, missed the new
  holder's proof (lost in a 40 % burst) and, once its stall was T_max behind it,
  refuted the warnings in it instead of fencing itself: two executors for 1.31 s
  (bound 1.20 s). A holder now shows its proof to any stale holder of its slot every
  other heartbeat period, not only to a rival at its own epoch.
- 104525: a standby that took a slot over restarted and resumed it; the old holder, back
  from a partition, dropped the CLAIM in the new holder's proof as `outdated` (older than
  its standby heartbeats during the rejoin) and executed on beside it: the CLAIM
  relayed back to the new holder from before its restart had replaced the one it signed
  again on resuming. A robot now keeps the latest CLAIM its claimant signed.
(Classic seed 25, run per robot here and in tests/test_attacks.py: a standby's own refuted claim,
relayed back as part of a reassertion's proof, never certified at it.)"""


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wide_seeds_fixed_run_clean_in_every_mode(auth: str) -> None:
    bench = _bench()
    found = bench.chaos(WIDE_FIXED, max_robots=60, verbose=False, auth=auth, wide=True)
    assert_clean(found)


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wide_small_seeds_run_clean_in_every_mode(auth: str) -> None:
    bench = _bench()
    found = bench.chaos(WIDE_SMALL, max_robots=12, verbose=False, auth=auth, wide=True)
    assert_clean(found)


WIPED: tuple[int, ...] = (810005, 810087, 810135, 810373, 810463, 830146, 831779,
                          832952)
"""Seeds of the `--wiped` draw (`python bench/bench_chaos.py --seed N --wiped --max-robots
12 --verbose`) that broke an invariant per robot on the core before it, one a shape of
a robot back without its state file as the plan's holder of a slot taken over meanwhile;
clean in every mode since (`test_wiped_seeds_run_clean_in_every_mode`):
- 810005: its REFUTE of its own recorded `LEAVE` made the others move to its reassertion
  before it learnt it; it heartbeat its hold below that entry, its watchers heard no
  heartbeat at the entry, suspected it T_max later and a claim fenced it with nobody to
  take over (`fenced_without_takeover`). The heartbeat of the robot an entry names now
  feeds its watchdog at whatever epoch it names;
- 810087, 810373: the slot was handed over twice while it was gone, and the new holder's
  proof rests on the `LEAVE` of a robot it never heard, which it refused for its whole
  start-up grace: two executors for 2.1 s and 2.0 s (bounds 1.2 s and 1.7 s). Within the
  grace such a `LEAVE` now counts once a robot's own word holds the slot above it;
- 810135, 810463: it refuted the takeover's claim, which voided it where robots held
  only the warnings behind it, while robots that also held its old `LEAVE` judged the
  takeover by the `LEAVE` alone (not refuted): two executors to the end of the run (8 s,
  9.2 s). The REFUTE of the claim now voids it whatever else backs it;
- 830146: the takeover rested on its `LEAVE` and on warnings, and only one warning
  reached it; its own `LEAVE` is no evidence at itself, so the claim did not verify
  there, and it refuted only the `LEAVE`, which voids the takeover only where a robot's
  certificate holds that `LEAVE`: two executors for 2.18 s (bound 1.71 s). A claim that
  replaces a live hold is refuted whether or not it verifies at the holder;
- 831779: others had moved to its reassertion before it learnt it, so it heartbeat below
  the entry naming it; a standby's own ears did not count that as the holder heard, and
  one liar's warning with the standby's own ears (rule 9) made a quorum that fenced it,
  the claimant then giving the claim up (`fenced_without_takeover`). The heartbeat of the
  robot an entry names, at whatever epoch, is heard by a standby's ears as by a
  watchdog;
- 832952 (a robot wiped twice, 39 % loss in bursts; on the core that keeps a robot's own
  REFUTE from before its start, `WIPED_ALL_40`): the standby's first claim at epoch 1
  was refuted by the live holder and ended; its second claim, at the same epoch, was not
  refuted again (a holder refutes a claimant once an epoch), and it took the slot over
  although the REFUTE it held voids any takeover of it at that epoch: two executors for
  1.59 s (bound 1.20 s). A claimant that holds such a REFUTE does not take over; its
  view moves to the holder's reassertion."""


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wiped_seeds_run_clean_in_every_mode(auth: str) -> None:
    bench = _bench()
    found = bench.chaos(WIPED, max_robots=12, verbose=False, auth=auth, wide=4)
    assert_clean(found)


WIPED_ALL_40: tuple[int, ...] = (870473,)
"""Seeds of `--wiped-all` on swarms of up to 40 robots (`python bench/bench_chaos.py --seed
N --wiped-all --max-robots 40 --verbose`) that broke an invariant, clean since, in every
mode:
- 870473, per robot (seven robots, 19 % loss): robot 4, its slot falsely taken over,
  reasserted it at epoch 2, turned faulty (its `LEAVE` lost in a fade), and was claimed
  at epoch 3; restarted without its state file it refuted that claim, and the others
  moved to its reassertion at epoch 4. Restarted so once more, it was shown the proof of
  that entry: the claim with its certificate, then its own REFUTE, which it dropped as
  its own frame relayed back. The claim fenced it at an epoch no takeover made
  (`fenced_without_takeover`), the slot idle for 1 s until its watchers, who knew it at
  epoch 4, had it taken over again. A robot keeps its own REFUTE from before its start as
  any peer's: it reasserts at epoch 4 and is never fenced."""


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wiped_all_seeds_run_clean_in_every_mode(auth: str) -> None:
    bench = _bench()
    found = bench.chaos(WIPED_ALL_40, max_robots=40, verbose=False, auth=auth, wide=5)
    assert_clean(found)


WIDE_DENSE: tuple[int, ...] = (200507, 201884)
"""Seeds of the wide draw made dense (`python bench/bench_chaos.py --seed N --wide --dense
--max-robots 16 --verbose`) that the checker judged wrongly, the core being right:
- 200507 (with a shared key and unsigned): a holder restarted on its state file resumed
  its slot, which a takeover had just given to its standby; a watcher that missed that
  takeover warned about it, and it crashed and came back a standby before it heard the
  new holder. No fence, no new takeover: the warning is answered by the takeover the
  watcher missed once the stale holder stops holding the slot;
- 201884 (per robot): two liars, both watchers of one slot, got its live holder replaced
  three times: two witnesses are a quorum (DESIGN's two-insider case), counted as false
  takeovers, not judged."""


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wide_dense_seeds_run_clean_in_every_mode(auth: str) -> None:
    bench = _bench()
    found = bench.chaos(WIDE_DENSE, max_robots=16, verbose=False, dense=True, auth=auth,
                        wide=True)
    assert_clean(found)


WIDER_DENSE: tuple[int, ...] = (500025, 500273)
"""Seeds of the wider draw made dense (`python bench/bench_chaos.py --seed N --wider
--dense --max-robots 16 --verbose`) that broke an invariant:
- 500025 (with a shared key and unsigned), the checker's fault: the channel (29 % loss)
  lost the last ten heartbeats of robot 5 to robot 10, and the run ended; invariant 7
  called 5 muted. Nothing of 5 reached 10 in that second, so nothing was dropped: the
  judge now calls a robot muted only when its frames reached the other and were refused;
- 500273 (per robot, 37 % loss in bursts): robot 1, heard by nobody for 2.3 s, was taken
  over by 7 and reasserted its slot; 1's proof of the reassertion was lost on the way
  to 7, and a REFUTE that 1 sent alone to a watcher held the next whole proof back for
  T_max: 7 executed beside 1 for 3.60 s against a bound of 3.58 s. The REFUTEs alone
  now have a clock of their own."""


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wider_dense_seeds_run_clean_in_every_mode(auth: str) -> None:
    bench = _bench()
    found = bench.chaos(WIDER_DENSE, max_robots=16, verbose=False, dense=True, auth=auth,
                        wide=2)
    assert_clean(found)


def test_a_few_wide_seeds_run_and_no_node_raises() -> None:
    """Wide runs complete, every compound kind is drawn, and no node raises on any
    input (invariant 5), whatever else they find."""
    bench = _bench()
    bench.DRAWN.clear()
    found = bench.chaos(range(12), max_robots=12, verbose=False, wide=True)
    assert "raised" not in found, found["raised"][:3]
    assert {f"wide {k}" for k in bench.WIDE_KINDS} <= set(bench.DRAWN)


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_the_virtual_medium_holds_overlapping_one_way_partitions(auth: str) -> None:
    """`partition:1>2@3+2` and `partition:1>3@4+2` overlap over [4, 5): each cut holds
    over its own window only. Robot 2 stops hearing 1 at 3 s and hears it again at
    5 s, robot 3 from 4 s to 6 s: each suspects 1 one `t_max` into its cut and hears it
    again (its `refute`) when its own cut heals, not when the other one does. The cuts
    come after the start-up grace: a link heard for less is not measured yet and waits
    `t_max_bursty` (DESIGN "Detection"). A watcher hears a holder's heartbeat
    first-hand only, in every mode: nobody repeats another robot's heartbeat."""
    from sim.virtual.explore import swarm
    from sim.virtual.simulator import run_virtual

    plan, params = swarm("four")
    res = run_virtual(plan, params, duration=8.0, auth=auth,
                      faults=[parse_fault("partition:1>2@3+2"),
                              parse_fault("partition:1>3@4+2")])
    heard = {(e["robot"], e["event"]): e["t"] for e in reversed(res.events)
             if e["event"] in ("suspect", "refute") and e.get("subject") == 1}
    assert set(heard) == {(2, "suspect"), (2, "refute"), (3, "suspect"), (3, "refute")}
    hb = params.heartbeat_interval  # a suspicion comes t_max after the last beat heard
    assert 3.0 + params.t_max - hb <= heard[(2, "suspect")] <= 3.0 + params.t_max + hb
    assert 5.0 <= heard[(2, "refute")] < 5.1
    assert 4.0 + params.t_max - hb <= heard[(3, "suspect")] <= 4.0 + params.t_max + hb
    assert 6.0 <= heard[(3, "refute")] < 6.1
    assert res.violations == []


def test_a_case_at_radio_timing_is_the_udp_draw_stretched_by_its_t_max() -> None:
    """`--preset radio`: the same swarm and faults as the udp draw, each time and length
    (and the run) stretched by radio's t_max over udp's, and the case runs at radio()."""
    bench = _bench()
    k = radio().t_max / udp().t_max
    for seed in range(20):
        fast, slow = bench.draw_case(seed, 12, wide=5), bench.draw_case(seed, 12, wide=5,
                                                                          preset="radio")
        assert slow.plan == fast.plan and slow.preset == "radio" and len(slow.faults) > 0
        assert slow.duration == pytest.approx(fast.duration * k, abs=1e-3)
        for a, b in zip(fast.faults, slow.faults, strict=True):
            assert (b.kind, b.robots, b.wiped) == (a.kind, a.robots, a.wiped)
            assert b.at == pytest.approx(a.at * k, abs=1e-3)
            assert (b.duration is None) == (a.duration is None)
            if a.duration is not None:
                assert b.duration == pytest.approx(a.duration * k, abs=1e-3)


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wiped_all_seeds_at_radio_timing_run_clean(auth: str) -> None:
    """A few `--wiped-all --preset radio` seeds, in every mode: the protocol holds at
    radio() timing (a standby heartbeating every 8 s, a 10 s start-up grace) as at udp."""
    bench = _bench()
    found = bench.chaos(range(880000, 880006), max_robots=12, verbose=False, auth=auth,
                        wide=5, preset="radio")
    assert dict(found) == {}


def test_a_rough_case_keeps_its_swarm_and_faults_and_draws_a_channel_that_reorders() -> None:
    """`--rough`: the seed's swarm, faults and loss stay; its channel delays 2-30 ms with
    2-120 ms of jitter and duplicates up to 20 % (drawn per seed, replayable), and the
    run carries it (more deliveries than a plain run of the same seed: the duplicates)."""
    bench = _bench()
    jitters = []
    for seed in range(30):
        plain, rough = bench.draw_case(seed, 12, wide=3), bench.draw_case(seed, 12, wide=3,
                                                                           rough=True)
        assert rough == bench.draw_case(seed, 12, wide=3, rough=True)
        assert (rough.plan, rough.faults, rough.loss) == (plain.plan, plain.faults, plain.loss)
        assert 0.002 <= rough.delay <= 0.03 and 0.002 <= rough.jitter <= 0.12
        assert 0.0 <= rough.duplicate <= 0.2
        jitters.append(rough.jitter)
    assert max(jitters) > 0.1  # frames a heartbeat period apart may swap places
    case = bench.draw_case(3, 12, wide=3, rough=True)
    assert case.duplicate > 0.02
    plain = bench.draw_case(3, 12, wide=3)
    assert bench.run_case(case).deliveries > bench.run_case(plain).deliveries


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_widest_seeds_on_a_rough_channel_run_clean(auth: str) -> None:
    """A few `--widest --rough` seeds, in every mode: delays, reordering and duplicates
    at scale (the explorer walks every one of them on small swarms) leave no violation."""
    bench = _bench()
    found = bench.chaos(range(920000, 920006), max_robots=12, verbose=False, auth=auth,
                        wide=3, rough=True)
    assert dict(found) == {}


def test_an_insider_case_adds_one_forge_fault_of_what_its_mode_must_withstand() -> None:
    """`--insider`: the seed's swarm and faults stay, and one `forge:R@T:ATTACK` joins
    them, drawn once: per robot any attack (an insider speaks in its own name only); with
    a shared key or unsigned only what anyone can record or make (`replay`, `ahead`)."""
    bench = _bench()
    seen: dict[str, set[str]] = {"per-robot": set(), "shared": set(), "none": set()}
    for seed in range(60):
        plain = bench.draw_case(seed, 12, wide=1)
        case = bench.draw_case(seed, 12, wide=1, insider=True)
        for auth, attacks in seen.items():
            full = bench.with_insider(case, auth)
            assert full == bench.with_insider(full, auth)  # drawn once
            assert full.faults[:-1] == plain.faults and full.plan == plain.plan
            forge = full.faults[-1]
            assert forge.kind == "forge" and forge.robots[0] in case.plan.robots
            assert forge.at >= 0.5
            attacks.add(forge.attack)
        assert bench.with_insider(plain, "per-robot") == plain
    assert seen["per-robot"] == set(ATTACKS)
    assert seen["shared"] == seen["none"] == {"replay", "ahead"}


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_wide_seeds_with_an_insider_run_clean(auth: str) -> None:
    """A few `--wide --insider` seeds, in every mode: an insider's forged frames beside
    the wide faults leave no violation (DESIGN's threat table: what each mode withstands)."""
    bench = _bench()
    found = bench.chaos(range(950000, 950008), max_robots=12, verbose=False, auth=auth,
                        wide=1, insider=True)
    assert dict(found) == {}
