"""Seeded random chaos at scale, in virtual time (docs/sim.md).

Each seed draws a random valid swarm (3-60 robots: a ring of active slots, each watched
by its two ring neighbours plus random extra watchers, so every slot has at least the
quorum of witnesses, DESIGN rule 3; 1-5 standbys with random subs, rule 6), a random
schedule of every fault kind (several at once, overlapping, on adjacent robots, several
robots in one spec, collisions), link faults that lose frames one way (fades, deafness,
one-way partitions) and a loss of 0-30 %, independent or in bursts (Gilbert-Elliott),
runs it on sim.virtual in the mode users run (signed per robot; `--auth` for the others)
and judges it with sim.shared.invariants, convergence included (invariant 8). It prints
the fault kinds drawn and the violations by kind, each with the command that replays it:

    python bench/bench_chaos.py --seeds 1000              # violations by kind
    python bench/bench_chaos.py --seeds 1000 --dense      # 4-8 faults within 1.5 s
    python bench/bench_chaos.py --seeds 1000 --auth none  # unsigned (also: shared)
    python bench/bench_chaos.py --seed 1234 --verbose     # replay one seed
    python bench/bench_chaos.py --seeds 600 --wide        # compound link faults too
    python bench/bench_chaos.py --seeds 500 --first 40000 --wide   # fresh seeds
    python bench/bench_chaos.py --seeds 500 --wider       # and groups cut both ways
    python bench/bench_chaos.py --seeds 500 --widest      # and flapping links, handovers
                                                          # and pauses inside cuts
    python bench/bench_chaos.py --seeds 500 --wiped       # a robot back without its
                                                          # state file in every case
    python bench/bench_chaos.py --seeds 500 --wiped-all   # or a standby wiped around
                                                          # its claim or its new hold
    python bench/bench_chaos.py --seeds 500 --wide --preset radio   # at radio() timing
    python bench/bench_chaos.py --seeds 500 --wide --rough          # delays, reordering,
                                                                    # duplicates
    python bench/bench_chaos.py --seeds 500 --wide --insider        # a forging insider
    python bench/bench_chaos.py --ring8                   # the correlated-failure figure

`--rough`: every case's channel also delays each delivery 2-30 ms, with a jitter of 2-120
ms on top (frames a heartbeat period apart at udp swap places) and duplicates 0-20 % of
deliveries (drawn per seed apart from the rest: the seed's swarm and faults stay the
same).

`--insider`: every case also holds a `forge:R@T:ATTACK` (sim/shared/forge.py) from a
robot R drawn per seed, within 1 s before to 3 s after the first fault; per robot, ATTACK
is any of `ATTACKS` (an insider with R's own key speaks in R's name only: DESIGN's
threat table); with a shared key and unsigned, where an insider can forge any frame in
any name and no invariant holds against it, `replay` and `ahead`: frames anyone can
make or record (a recorder of the channel, heartbeats far ahead of R's counter), which
those modes promise to withstand as well.

`--preset radio`: every case runs at `radio()` timing (t_max 2 s, standbys heartbeating
every 8 s), its fault times and length stretched by radio's t_max over udp's (x4), so a
fault lasts as long against the timing as the udp draw made it.

`--ring8`: configs/ring8.yaml (eight actives in a ring, three standbys covering all
eight); every two adjacent robots crash at the same instant, at 20 phases of the
heartbeat grid; prints the takeover latency p50 / p99 / max of both slots and how many
were never taken over; then the same for a watcher failing with the standby of the
slot it watches (the goal: every slot taken over, p99 <= 1.5 s at 0 % loss).
"""

from __future__ import annotations

import argparse
import collections
import random
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.shared.faults import ATTACKS, Fault, FaultKind  # noqa: E402
from sim.shared.invariants import Violation  # noqa: E402
from sim.virtual.simulator import Channel, VirtualResult, run_virtual  # noqa: E402
from swarmd.config import load_swarm  # noqa: E402
from swarmd.core.params import Params, radio, udp  # noqa: E402
from swarmd.core.plan import RobotPlan, SwarmPlan  # noqa: E402

KINDS = ("crash", "restart", "pause", "partition", "liar", "leave", "unhealthy", "collide",
         "fade", "deaf", "oneway")
"""What a schedule draws from; `oneway` is a one-way partition (`partition:A>B`)."""
AUTH = "per-robot"
"""The authentication mode of every run (`--auth`): the shipped default unless told."""
PRESETS: dict[str, Callable[[], Params]] = {"udp": udp, "radio": radio}
"""The timing presets a case may run at (`--preset`); the draw is made for `udp`."""


def _stretch(preset: str) -> float:
    """How much longer the draw's times are at `preset` than at udp, the timing it is
    made for: the ratio of their t_max."""
    return PRESETS[preset]().t_max / udp().t_max


@dataclass(frozen=True)
class Case:
    seed: int
    plan: SwarmPlan
    faults: tuple[Fault, ...]
    loss: float
    duration: float
    loss_model: str = "bernoulli"
    burst_len: float = 4.0
    compound: tuple[str, ...] = ()
    """`--wide` (`--wider`, `--widest`): the compound link faults (`WIDE_KINDS`,
    `WIDER_KINDS`, `WIDEST_KINDS`) drawn on top of the classic draw."""
    preset: str = "udp"
    """The timing it runs at (`PRESETS`); its times are the udp draw's, stretched."""
    delay: float = 0.002
    jitter: float = 0.002
    duplicate: float = 0.0
    """The channel's latency, jitter (reordering) and duplication (`Channel`; `--rough`)."""
    insider: bool = False
    """`--insider`: a forge fault drawn in (`with_insider`); which attacks depends on the
    mode the case runs in, so the fault is drawn when it runs (`run_case`)."""

    def describe(self) -> str:
        model = f" in bursts of {self.burst_len:g}" if self.loss_model == "burst" else ""
        lines = [f"seed {self.seed}: {len(self.plan.robots)} robots, loss {self.loss:.0%}"
                 f"{model}, {self.duration:g} s at {self.preset}(), delay "
                 f"{self.delay * 1000:.0f} ms + jitter {self.jitter * 1000:.0f} ms, "
                 f"duplicates {self.duplicate:.0%}"]
        for r, p in sorted(self.plan.robots.items()):
            lines.append(f"  robot {r}: " + (f"active {p.function}, watched by "
                         f"{', '.join(self.plan.watched_by(p.function))}" if p.function
                         else f"standby, subs {', '.join(p.subs)}"))
        lines.append("  faults: " + " ".join(f.spec() for f in self.faults))
        if self.compound:
            lines.append("  compound (--wide/--wider/--widest): " + ", ".join(self.compound))
        return "\n".join(lines)


def draw_swarm(rng: random.Random, max_robots: int = 60) -> SwarmPlan:
    standbys = rng.randint(1, 5)
    n = rng.randint(3, max(3, max_robots - standbys))
    fs = tuple(f"f{i + 1}" for i in range(n))
    watches: dict[str, set[str]] = {f: {fs[i - 1], fs[(i + 1) % n]} - {f}
                                    for i, f in enumerate(fs)}
    for _ in range(rng.randint(0, n)):
        a, b = rng.choice(fs), rng.choice(fs)
        if a != b:
            watches[a].add(b)
    robots = {i + 1: RobotPlan(i + 1, f) for i, f in enumerate(fs)}
    for j in range(standbys):
        rid = n + 1 + j
        subs = rng.sample(fs, rng.randint(1, n))
        robots[rid] = RobotPlan(rid, None, tuple(sorted(subs, key=fs.index)))
    return SwarmPlan(2000 + n, fs, robots,
                     {f: tuple(sorted(w, key=fs.index)) for f, w in watches.items()})


def draw_case(seed: int, max_robots: int = 60, dense: bool = False,
              wide: int = 0, preset: str = "udp", rough: bool = False,
              insider: bool = False) -> Case:
    """`_draw` at `preset` timing: each fault's time and length, and the run's length,
    stretched by the preset's t_max over udp's (the draw's timing), so that a fault is as
    long against the timing (shorter or longer than a suspicion, a vote, a claim) as the
    udp draw made it. `rough`: a channel that delays, reorders and duplicates, drawn
    apart from the rest (the same swarm and faults). `insider`: a forge fault as well,
    drawn for the mode the case runs in (`with_insider`)."""
    case = replace(_draw(seed, max_robots, dense, wide), insider=insider)
    if rough:
        rng = random.Random(f"rough-{seed}")
        case = replace(case, delay=round(rng.uniform(0.002, 0.03), 4),
                       jitter=round(rng.uniform(0.002, 0.12), 4),
                       duplicate=round(rng.uniform(0.0, 0.2), 3))
    if preset == "udp":
        return case
    k = _stretch(preset)
    faults = tuple(replace(f, at=round(f.at * k, 3), duration=None if f.duration is None
                           else round(f.duration * k, 3)) for f in case.faults)
    return replace(case, faults=faults, duration=round(case.duration * k, 3), preset=preset)


def _draw(seed: int, max_robots: int, dense: bool, wide: int) -> Case:
    """The swarm and schedule of one seed. `dense`: 4-8 faults within 1.5 s, mostly on
    neighbours (clustered failures). `wide` (1, or True): the same draw, then one or two
    compound link faults (`WIDE_KINDS`, `_draw_compound`) on top; 2 (`--wider`): drawn
    from `WIDER_KINDS`; 3 (`--widest`): from `WIDEST_KINDS`; 4 (`--wiped`): a wiped
    restart (`WIPED_KIND`) and up to one of `WIDEST_KINDS`; 5 (`--wiped-all`): one of
    `WIPED_KINDS` and up to one of `WIDEST_KINDS`. A seed drawn without it replays
    exactly as it always did, and a wide (wider, widest, wiped) seed as it did before
    the wider (widest, wiped, wiped-all) draw existed."""
    case = _draw_classic(seed, max_robots, dense)
    if not wide:
        return case
    kinds = (WIDE_KINDS, WIDER_KINDS, WIDEST_KINDS)[min(wide, 3) - 1]
    rng = random.Random(f"wide-{seed}")
    always = rng.choice(WIPED_KINDS) if wide >= 5 else WIPED_KIND if wide == 4 else None
    return _widen(case, rng, kinds, always)


def _draw_classic(seed: int, max_robots: int, dense: bool) -> Case:
    rng = random.Random(seed)
    plan = draw_swarm(rng, max_robots)
    ids = sorted(plan.robots)
    params = udp()
    t = params.t_max
    faults: list[Fault] = []
    base = round(rng.uniform(2.5, 4.0), 3)
    partitioned = False
    for _ in range(rng.randint(4, 8) if dense else rng.randint(1, 4)):
        # one two-way partition a run: the virtual medium holds one at a time (one-way
        # link faults may overlap anything)
        kind = rng.choice([k for k in KINDS if k != "partition" or not partitioned])
        partitioned = partitioned or kind == "partition"
        # overlapping: at the same instant, or T_max/2 .. 2 T_max after another fault
        spread = rng.uniform(0, 1.5) if dense else rng.uniform(0, 3)
        at = round(base + rng.choice((0.0, 0.0, t / 2, t, 2 * t, spread)), 3)
        faults.append(_draw_fault(rng, plan, ids, kind, at, dense))
    loss = rng.choice((0.0, 0.0, round(rng.uniform(0.0, 0.3), 2)))
    model, burst = "bernoulli", 4.0
    if loss and rng.random() < 0.4:
        model, burst = "burst", round(rng.uniform(2.0, 8.0), 1)
    last = max((f.end or f.at) for f in faults)
    return Case(seed, plan, tuple(faults), loss, round(last + 8.0, 3), model, burst)


def _draw_fault(rng: random.Random, plan: SwarmPlan, ids: list[int], kind: str, at: float,
                dense: bool) -> Fault:
    first = rng.choice(ids)
    targets = [first]
    near = _neighbours(plan, first)
    if kind == "collide" or (kind in ("crash", "pause", "leave", "unhealthy")
                             and rng.random() < (0.6 if dense else 0.3)):
        pool = near or [r for r in ids if r != first]
        targets.append(rng.choice(pool))  # an adjacent robot, when there is one
    if kind in ("partition", "oneway"):
        group = tuple(sorted(rng.sample(ids, rng.randint(1, len(ids) - 1))))
        rest = tuple(r for r in ids if r not in group)
        return Fault(FaultKind.PARTITION, at, (*group, *rest), round(rng.uniform(0.5, 3.0), 2),
                     (group, rest), oneway=kind == "oneway")
    if kind == "fade":
        return Fault(FaultKind(kind), at, (first,), round(rng.uniform(0.2, 3.0), 2))
    if kind == "deaf":
        heard = near or [r for r in ids if r != first]
        senders = tuple(sorted(rng.sample(heard, rng.randint(1, min(2, len(heard))))))
        return Fault(FaultKind(kind), at, (first,), round(rng.uniform(0.2, 3.0), 2), (senders,))
    if kind == "pause":
        return Fault(FaultKind(kind), at, tuple(targets), round(rng.uniform(0.3, 4.0), 2))
    return Fault(FaultKind(kind), at, tuple(targets))


# ------------------------------------------------------------------ the wide draw
WIDE_KINDS = ("overlapping-cuts", "muted-while-cut", "fade-restart", "deaf-takeover",
              "burst-40")
"""Compound link faults `--wide` adds (docs/sim.md, "Random chaos"):
- `overlapping-cuts`: two or three one-way partitions (`partition:A>B`) in force at once;
- `muted-while-cut`: a robot muted entirely (`fade`, or `partition:R>rest`) while a group
  is cut off (a two-way partition);
- `fade-restart`: a robot whose transmissions fade while it restarts (crash, then back);
- `deaf-takeover`: a holder crashes while its standby, or one of its watchers, is deaf
  to the robots it needs to hear (the watchers, or the standby);
- `burst-40`: bursty loss (Gilbert-Elliott) of 20 to 40 %."""

WIDER_KINDS = (*WIDE_KINDS, "split-groups")
"""`--wider`: the wide kinds, and
- `split-groups`: the swarm split in three or four groups, each pair of groups cut both
  ways from a start and for a length of its own, so that the cuts overlap and heal one
  pair at a time (a group hears a second one again while a third is still cut off)."""

WIDEST_KINDS = (*WIDER_KINDS, "flapping", "handover-while-cut", "pause-while-cut",
                "pause-claimant", "restart-new-holder")
"""`--widest`: the wider kinds, and
- `flapping`: a robot's link comes and goes, three to six times within a few seconds:
  its transmissions fade, or its neighbours are cut from hearing it, for 0.1-0.6 s each,
  with 0.1-0.6 s between (a marginal radio link, shorter than a suspicion or not);
- `handover-while-cut`: a holder and some robots around it cut off from the rest both
  ways, and while the cut lasts the holder leaves or turns unhealthy (rule 7: its LEAVE
  reaches only its own side);
- `pause-while-cut`: a holder paused (its process stopped) for 0.5-4 s, and while it is
  paused some of its neighbours go unheard by it one way for a while (back from the
  pause, it may not hear the robot that took its slot over);
- `pause-claimant`: a holder crashes, and the standby that covers its slot is paused
  around the time it would claim (its own stall, noticed when it wakes: DESIGN
  "Sequence numbers" and the claim's wait state);
- `restart-new-holder`: a holder crashes or is paused for 2-4 s, and once its standby
  has taken the slot over, that new holder restarts (it resumes its hold from its state
  file, its certificate and its claim signed again, while the old one may come back)."""


WIPED_KIND = "wiped-restart"
"""`--wiped`: every case holds one, with up to one of the widest kinds beside it:
- `wiped-restart`: a robot (a holder, seven times in ten) crashes, leaves, turns
  unhealthy or is paused, and comes back 0.2-6 s later without its state file
  (`restart:R@T:wiped`: a wiped or replaced companion computer, as at a first start);
  three times in ten it is restarted wiped once more 0.2-2 s after that."""

WIPED_KINDS = (WIPED_KIND, "wiped-claimant", "wiped-new-holder")
"""`--wiped-all`: every case holds one of these, with up to one of the widest kinds:
- `wiped-restart` as `--wiped` draws it;
- `wiped-claimant`: a holder crashes, and the first standby covering its slot is
  restarted without its state file 0.3-1.4 s later: while it votes, claims or holds its
  claim (a standby's claim lives in memory only, DESIGN "Persistence");
- `wiped-new-holder`: a holder crashes or is paused for 2-4 s, and once that standby has
  taken the slot over it crashes and comes back 0.2-3 s later without its state file (a
  standby by the plan, at a first start, while the swarm knows it as the holder), or is
  restarted so at once."""


def _widen(case: Case, rng: random.Random, kinds: tuple[str, ...] = WIDE_KINDS,
           always: str | None = None) -> Case:
    """`case` with one or two compound faults of `kinds` drawn by `rng` on top (with
    `always`: that kind, and none or one of `kinds` beside it)."""
    plan, ids = case.plan, sorted(case.plan.robots)
    faults = list(case.faults)
    loss, model, burst = case.loss, case.loss_model, case.burst_len
    base = min(f.at for f in faults)
    drawn = tuple(rng.sample(kinds, rng.randint(1, 2))) if always is None else \
        (always, *rng.sample(kinds, rng.randint(0, 1)))
    for kind in drawn:
        at = round(base + rng.uniform(0.0, 2.0), 3)
        if kind == "burst-40":
            loss, model, burst = round(rng.uniform(0.2, 0.4), 2), "burst", \
                round(rng.uniform(2.0, 8.0), 1)
        else:
            faults += _draw_compound(rng, plan, ids, kind, at)
    last = max((f.end or f.at) for f in faults)
    return Case(case.seed, plan, tuple(faults), loss, round(last + 8.0, 3), model, burst,
                drawn)


def _draw_compound(rng: random.Random, plan: SwarmPlan, ids: list[int], kind: str,
                   at: float) -> list[Fault]:
    """The faults of one compound kind (`WIDEST_KINDS`, all but the loss) from `at`."""
    def length() -> float:
        return round(rng.uniform(0.5, 3.0), 2)

    if kind == "overlapping-cuts":
        out, t = [], at
        for _ in range(rng.randint(2, 3)):
            a = rng.choice(ids)
            near = _neighbours(plan, a) or [r for r in ids if r != a]
            b = tuple(sorted(rng.sample(near, rng.randint(1, min(2, len(near))))))
            out.append(Fault(FaultKind.PARTITION, t, (a, *b), length(), ((a,), b), oneway=True))
            # Within 0.8 s of the one before: mostly while it lasts (it lasts 0.5-3 s);
            # `wide_kinds` names the case by the overlap it finds.
            t = round(t + rng.uniform(0.0, 0.8), 3)
        return out
    if kind == "muted-while-cut":
        group = tuple(sorted(rng.sample(ids, rng.randint(1, len(ids) - 1))))
        rest = tuple(r for r in ids if r not in group)
        muted = rng.choice(ids)
        others = tuple(r for r in ids if r != muted)
        mute = Fault(FaultKind.FADE, at, (muted,), length()) if rng.random() < 0.5 else \
            Fault(FaultKind.PARTITION, at, (muted, *others), length(), ((muted,), others),
                  oneway=True)
        cut_at, cut_for = round(at + rng.uniform(0.0, 0.5), 3), length()
        return [mute, *_two_way_cut(cut_at, group, rest, cut_for)]
    if kind == "split-groups":
        return _split_groups(rng, ids, at, length)
    if kind == "flapping":
        return _flapping(rng, plan, ids, at)
    if kind in ("handover-while-cut", "pause-while-cut"):
        return _holder_inside_a_cut(rng, plan, ids, kind, at, length)
    if kind in ("pause-claimant", "restart-new-holder", "wiped-claimant",
                "wiped-new-holder"):
        return _standby_after_a_failure(rng, plan, ids, kind, at)
    if kind == WIPED_KIND:
        return _wiped_restart(rng, plan, ids, at)
    if kind == "fade-restart":
        r = rng.choice(ids)
        back = round(at + rng.uniform(0.1, 1.5), 3)
        crash = [Fault(FaultKind.CRASH, at, (r,))] if rng.random() < 0.5 else []
        fade_for = round(back - at + 0.2 + rng.uniform(0.3, 2.0), 2)  # past the restart
        return [Fault(FaultKind.FADE, round(at - 0.2, 3), (r,), fade_for), *crash,
                Fault(FaultKind.RESTART, back, (r,))]
    return _deaf_takeover(rng, plan, ids, at, length())


def _two_way_cut(at: float, a: tuple[int, ...], b: tuple[int, ...],
                 span: float) -> list[Fault]:
    """Groups `a` and `b` cut both ways from `at` for `span` s, as one one-way partition
    each way: the virtual medium holds one two-way partition at a time, one-way cuts
    overlap anything (`_cut_both_ways` tells such a pair)."""
    return [Fault(FaultKind.PARTITION, at, (*a, *b), span, (a, b), oneway=True),
            Fault(FaultKind.PARTITION, at, (*b, *a), span, (b, a), oneway=True)]


def _split_groups(rng: random.Random, ids: list[int], at: float,
                  length: Callable[[], float]) -> list[Fault]:
    """Three or four groups (as many as there are robots, at most), each pair cut both
    ways (`_two_way_cut`) from its own start within 0.6 s of `at`, for its own length."""
    order = list(ids)
    rng.shuffle(order)
    k = min(len(order), rng.randint(3, 4))
    groups = [tuple(sorted(order[i::k])) for i in range(k)]
    out = []
    for i, a in enumerate(groups):
        for b in groups[i + 1:]:
            start, span = round(at + rng.uniform(0.0, 0.6), 3), length()
            out += _two_way_cut(start, a, b, span)
    return out


def _flapping(rng: random.Random, plan: SwarmPlan, ids: list[int], at: float) -> list[Fault]:
    """One robot's link going and coming back three to six times from `at`: each time its
    transmissions fade, or (the same way every time) its neighbours cannot hear it."""
    r = rng.choice(ids)
    near = tuple(_neighbours(plan, r) or [x for x in ids if x != r])
    fade = rng.random() < 0.5
    out, t = [], at
    for _ in range(rng.randint(3, 6)):
        span = round(rng.uniform(0.1, 0.6), 2)
        out.append(Fault(FaultKind.FADE, t, (r,), span) if fade else
                   Fault(FaultKind.PARTITION, t, (r, *near), span, ((r,), near), oneway=True))
        t = round(t + span + rng.uniform(0.1, 0.6), 3)
    return out


def _holder_inside_a_cut(rng: random.Random, plan: SwarmPlan, ids: list[int], kind: str,
                         at: float, length: Callable[[], float]) -> list[Fault]:
    """`handover-while-cut`: a holder and some of its neighbours cut off from the rest
    both ways from `at`, the holder leaving or unhealthy while the cut lasts.
    `pause-while-cut`: a holder paused from `at`, and while it is paused some of its
    neighbours unheard by it (a one-way cut) for a while."""
    actives = [r for r in ids if plan.robots[r].function is not None]
    holder = rng.choice(actives)
    near = _neighbours(plan, holder) or [r for r in ids if r != holder]
    # Drawn for both kinds (only a handover's cut uses it), so that each replays as
    # the figures in docs/sim.md were measured.
    side = tuple(sorted(rng.sample(near, rng.randint(0, min(2, len(near) - 1)))))
    if kind == "handover-while-cut":
        group = tuple(sorted((holder, *side)))
        rest = tuple(r for r in ids if r not in group)
        span = length()
        act = FaultKind.LEAVE if rng.random() < 0.5 else FaultKind.UNHEALTHY
        when = round(at + rng.uniform(0.0, span), 3)
        return [*_two_way_cut(at, group, rest, span), Fault(act, when, (holder,))]
    pause = round(rng.uniform(0.5, 4.0), 2)
    unheard = tuple(sorted(rng.sample(near, rng.randint(1, min(2, len(near))))))
    start = round(at + rng.uniform(0.0, pause), 3)
    return [Fault(FaultKind.PAUSE, at, (holder,), pause),
            Fault(FaultKind.PARTITION, start, (*unheard, holder), length(),
                  (unheard, (holder,)), oneway=True)]


def _standby_after_a_failure(rng: random.Random, plan: SwarmPlan, ids: list[int], kind: str,
                             at: float) -> list[Fault]:
    """A holder that a standby covers fails at `at` (`pause-claimant`, `wiped-claimant`:
    it crashes; `restart-new-holder`, `wiped-new-holder`: it crashes or is paused for
    2-4 s), and the first standby covering its slot is paused 0.3-1.2 s later for 0.3-2 s
    (around its claim) or restarted wiped 0.3-1.4 s later, or restarts 0-1.5 s after
    the takeover bound (once it holds the slot): from its state file, or wiped (crashed
    first, half the time, and back 0.2-3 s later)."""
    # A holder whose slot a standby covers (every drawn swarm has one: each standby
    # covers at least one slot).
    covered = {r: by for r in ids if (g := plan.robots[r].function) is not None
               and (by := [s for s in plan.covered_by(g) if s != r])}
    holder = rng.choice(sorted(covered))
    standby = covered[holder][0]
    if kind == "pause-claimant":
        return [Fault(FaultKind.CRASH, at, (holder,)),
                Fault(FaultKind.PAUSE, round(at + rng.uniform(0.3, 1.2), 3), (standby,),
                      round(rng.uniform(0.3, 2.0), 2))]
    if kind == "wiped-claimant":
        return [Fault(FaultKind.CRASH, at, (holder,)),
                Fault(FaultKind.RESTART, round(at + rng.uniform(0.3, 1.4), 3), (standby,),
                      wiped=True)]
    fail = Fault(FaultKind.CRASH, at, (holder,)) if rng.random() < 0.5 else \
        Fault(FaultKind.PAUSE, at, (holder,), round(rng.uniform(2.0, 4.0), 2))
    back = round(at + udp().takeover_bound() + rng.uniform(0.0, 1.5), 3)
    if kind == "restart-new-holder":
        return [fail, Fault(FaultKind.RESTART, back, (standby,))]
    if rng.random() < 0.5:
        return [fail, Fault(FaultKind.RESTART, back, (standby,), wiped=True)]
    return [fail, Fault(FaultKind.CRASH, back, (standby,)),
            Fault(FaultKind.RESTART, round(back + rng.uniform(0.2, 3.0), 3), (standby,),
                  wiped=True)]


def _wiped_restart(rng: random.Random, plan: SwarmPlan, ids: list[int],
                   at: float) -> list[Fault]:
    """`wiped-restart` (`WIPED_KIND`) from `at`."""
    actives = [r for r in ids if plan.robots[r].function is not None]
    r = rng.choice(actives) if rng.random() < 0.7 else rng.choice(ids)
    how = rng.choice((FaultKind.CRASH, FaultKind.LEAVE, FaultKind.UNHEALTHY,
                      FaultKind.PAUSE))
    fail = Fault(how, at, (r,), round(rng.uniform(0.5, 4.0), 2)) \
        if how is FaultKind.PAUSE else Fault(how, at, (r,))
    back = round(at + rng.uniform(0.2, 6.0), 3)
    out = [fail, Fault(FaultKind.RESTART, back, (r,), wiped=True)]
    if rng.random() < 0.3:
        out.append(Fault(FaultKind.RESTART, round(back + rng.uniform(0.2, 2.0), 3), (r,),
                         wiped=True))
    return out


def _deaf_takeover(rng: random.Random, plan: SwarmPlan, ids: list[int], at: float,
                   length: float) -> list[Fault]:
    """A holder crashes at `at`; from just before, its standby is deaf to its watchers,
    or one of its watchers is deaf to the standby (the claim and the new heartbeats)."""
    actives = [r for r in ids if plan.robots[r].function is not None]
    holder = rng.choice(actives)
    f = plan.robots[holder].function
    assert f is not None
    standbys = [r for r in plan.covered_by(f) if r != holder] or [rng.choice(ids)]
    standby = standbys[0]
    watchers = [r for r in actives if plan.robots[r].function in plan.watched_by(f)
                and r not in (holder, standby)] or [r for r in ids if r != holder]
    start = round(at - rng.uniform(0.0, 0.5), 3)
    if rng.random() < 0.5:  # a deaf standby: the warnings do not reach it
        heard = tuple(sorted(rng.sample(watchers, min(len(watchers), rng.randint(1, 2)))))
        deaf = Fault(FaultKind.DEAF, start, (standby,), length, (heard,))
    else:  # a deaf watcher: it misses the claim and the new holder
        deaf = Fault(FaultKind.DEAF, start, (rng.choice(watchers),), length, ((standby,),))
    return [deaf, Fault(FaultKind.CRASH, at, (holder,))]


def wide_kinds(case: Case) -> list[str]:
    """The compound kinds a wide case holds, recognised from its faults."""
    out = []
    if case.loss_model == "burst" and case.loss >= 0.2 and "burst-40" in case.compound:
        out.append("burst-40")
    oneways = [f for f in case.faults if f.oneway]
    if any(a is not b and a.at <= b.at < (a.end or a.at) for a in oneways for b in oneways):
        out.append("overlapping-cuts")
    mutes = [f for f in case.faults if f.kind is FaultKind.FADE or (
        f.oneway and len(f.groups[0]) == 1 and len(f.groups[1]) == len(case.plan.robots) - 1)]
    cuts = [f for f in case.faults if f.kind is FaultKind.PARTITION]
    if any(m is not c and _overlap(m, c) for m in mutes for c in cuts):
        out.append("muted-while-cut")
    fades = [f for f in case.faults if f.kind is FaultKind.FADE]
    if any(r.kind is FaultKind.RESTART and r.robots[0] in fd.robots and _overlap(fd, r)
           for fd in fades for r in case.faults):
        out.append("fade-restart")
    if len(_cut_both_ways(oneways)) >= 3:
        out.append("split-groups")
    deafs = [f for f in case.faults if f.kind is FaultKind.DEAF]
    if any(c.kind is FaultKind.CRASH and _overlap(d, c) for d in deafs for c in case.faults):
        out.append("deaf-takeover")
    if any(len([f for f in fades if f.robots == (r,)]) >= 3 for r in case.plan.robots) \
            or any(len([c for c in oneways if c.groups == o.groups]) >= 3 for o in oneways):
        out.append("flapping")
    handovers = [f for f in case.faults if f.kind in (FaultKind.LEAVE, FaultKind.UNHEALTHY)]
    if any(_overlap(h, c) and h.robots[0] in c.robots for h in handovers for c in cuts):
        out.append("handover-while-cut")
    pauses = [f for f in case.faults if f.kind is FaultKind.PAUSE]
    if any(_overlap(p, c) and set(p.robots) & set(c.robots) for p in pauses for c in cuts):
        out.append("pause-while-cut")
    # Each holder that crashed or was paused: the robots covering its slot, and when.
    failed = [(case.plan.covered_by(g), f.at) for f in case.faults
              if f.kind in (FaultKind.CRASH, FaultKind.PAUSE) and len(f.robots) == 1
              and (g := case.plan.robots[f.robots[0]].function) is not None]
    if any(p.robots[0] in by and 0 < p.at - t <= 1.2 for p in pauses for by, t in failed):
        out.append("pause-claimant")
    restarts = [f for f in case.faults if f.kind is FaultKind.RESTART]
    bound = udp().takeover_bound()
    if any(b.robots[0] in by and bound <= b.at - t <= bound + 1.5
           for b in restarts for by, t in failed):
        out.append("restart-new-holder")
    wiped = [b for b in restarts if b.wiped]
    if any(b.robots[0] in by and 0 < b.at - t <= 1.4 for b in wiped for by, t in failed):
        out.append("wiped-claimant")
    crashed = {f.robots[0]: f.at for f in case.faults
               if f.kind is FaultKind.CRASH and len(f.robots) == 1}
    if any(b.robots[0] in by and bound <= crashed.get(b.robots[0], b.at) - t <= bound + 1.5
           for b in wiped for by, t in failed):
        out.append("wiped-new-holder")
    if wiped:
        out.append(WIPED_KIND)
    return out


def _cut_both_ways(oneways: list[Fault]) -> set[frozenset[tuple[int, ...]]]:
    """The pairs of groups that one-way cuts in both directions, from the same instant
    for the same length, part: each a two-way cut."""
    return {frozenset(a.groups) for a in oneways for b in oneways
            if a.groups == b.groups[::-1] and (a.at, a.end) == (b.at, b.end)}


def _overlap(a: Fault, b: Fault) -> bool:
    return a.at <= (b.end or b.at) and b.at <= (a.end or a.at)


def _neighbours(plan: SwarmPlan, robot: int) -> list[int]:
    """Robots next to `robot` in the plan: holders of the slots it watches or that watch
    it, the standbys covering its slot (or, for a standby, the holders of its subs)."""
    p = plan.robots[robot]
    holders = {g: plan.initial_holder(g) for g in plan.functions}
    if p.function is None:
        return sorted({h for g in p.subs if (h := holders[g]) is not None})
    slots = {*plan.watched(p.function), *plan.watched_by(p.function)}
    out = {h for g in slots if (h := holders[g]) is not None}
    out.update(plan.covered_by(p.function))
    out.discard(robot)
    return sorted(out)


INSIDER_ATTACKS = {"per-robot": ATTACKS, "shared": ("replay", "ahead"),
                   "none": ("replay", "ahead")}
"""What `--insider` draws from in each mode (module docstring)."""


def with_insider(case: Case, auth: str) -> Case:
    """`case` with its insider's forge fault (`--insider`) for mode `auth`, drawn apart
    from the rest of the seed (the same swarm and faults), and drawn once (the case it
    returns has it among its faults); `case` itself without one. The fault's time is
    drawn at udp timing and stretched as the case's others."""
    if not case.insider:
        return case
    rng = random.Random(f"insider-{case.seed}")
    robot = rng.choice(sorted(case.plan.robots))
    attack = rng.choice(INSIDER_ATTACKS[auth])
    k = _stretch(case.preset)
    first = min(f.at for f in case.faults) / k
    at = round(max(0.5, first + rng.uniform(-1.0, 3.0)) * k, 3)
    return replace(case, insider=False,
                   faults=(*case.faults, Fault(FaultKind.FORGE, at, (robot,), attack=attack)))


def run_case(case: Case, auth: str | None = None) -> VirtualResult:
    case = with_insider(case, auth or AUTH)
    channel = Channel(loss=case.loss, delay=case.delay, jitter=case.jitter,
                      duplicate=case.duplicate, loss_model=case.loss_model,
                      burst_len=case.burst_len)
    return run_virtual(case.plan, PRESETS[case.preset](), duration=case.duration,
                       faults=case.faults, loss=case.loss, seed=case.seed,
                       auth=auth or AUTH, channel=channel)


WIDE_FLAGS = ("", " --wide", " --wider", " --widest", " --wiped", " --wiped-all")
"""The flag of each `wide` level, for the replay command a violation prints."""

DRAWN: collections.Counter[str] = collections.Counter()
"""Fault kinds drawn by `chaos` in this process (one-way partitions as `oneway`)."""


def chaos(seeds: Sequence[int], max_robots: int, verbose: bool, dense: bool = False,
          auth: str | None = None, wide: int = 0, preset: str = "udp", rough: bool = False,
          insider: bool = False) -> dict[str, list[tuple[int, Violation]]]:
    found: dict[str, list[tuple[int, Violation]]] = collections.defaultdict(list)
    for seed in seeds:
        case = with_insider(draw_case(seed, max_robots, dense, wide, preset, rough, insider),
                            auth or AUTH)
        DRAWN.update(f"forge {f.attack}" if f.kind is FaultKind.FORGE
                     else "oneway" if f.oneway else f.kind for f in case.faults)
        DRAWN.update(f"wide {k}" for k in case.compound)
        if case.loss_model == "burst":
            DRAWN["burst loss"] += 1
        res = run_case(case, auth)
        if verbose:
            print(case.describe())
            for e in res.events:
                if e["event"] in ("fault", "suspect", "claim", "takeover", "alert", "fenced"):
                    print("   ", e)
        for v in res.violations:
            found[v.kind].append((seed, v))
    return found


# -------------------------------------------------------------------- the ring of eight
def ring8() -> tuple[SwarmPlan, Params]:
    cfg = load_swarm(ROOT / "configs" / "ring8.yaml")
    return cfg.to_plan(), cfg.params()


def ring8_latencies(pairs: Sequence[tuple[int, ...]], phases: int = 20,
                    loss: float = 0.0, auth: str | None = None) -> tuple[list[float], int, int]:
    """Takeover latencies (s, fault -> takeover) of the slots of the crashed actives, the
    count of such slots never taken over, and the count of runs with a violation."""
    plan, params = ring8()
    lat: list[float] = []
    missed = bad = 0
    for robots in pairs:
        for k in range(phases):
            at = 3.0 + k * params.heartbeat_interval / phases
            res = run_virtual(plan, params, duration=at + 6.0, loss=loss, seed=k,
                              faults=[Fault(FaultKind.CRASH, at, robots)], auth=auth or AUTH)
            bad += bool(res.violations)
            for r in robots:
                f = plan.robots[r].function
                if f is None:
                    continue
                took = [e["t"] for e in res.events if e["event"] == "takeover"
                        and e["function"] == f and e["t"] >= at]
                if took:
                    lat.append(took[0] - at)
                else:
                    missed += 1
    return lat, missed, bad


def percentile(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q / 100 * len(s) + 0.5) - 1))]


def print_ring8(phases: int) -> None:
    adjacent = [(i, i % 8 + 1) for i in range(1, 9)]
    plan, _ = ring8()
    # a watcher and the first standby covering the slot it watches
    with_standby = [(i, next(r for r in plan.covered_by(f"f{i % 8 + 1}")
                             if plan.robots[r].function is None)) for i in range(1, 9)]
    for title, pairs in (("two adjacent robots crash at once", adjacent),
                         ("a watcher and the standby of its neighbour's slot", with_standby)):
        t0 = time.perf_counter()
        lat, missed, bad = ring8_latencies(pairs, phases)
        runs = len(pairs) * phases
        fig = (f"p50 {percentile(lat, 50):.3f} s, p99 {percentile(lat, 99):.3f} s, "
               f"max {max(lat):.3f} s" if lat else "no takeover at all")
        print(f"ring8, {title}: {runs} runs ({phases} phases), {len(lat)} slots taken "
              f"over ({fig}), {missed} never taken over, {bad} runs with a violation "
              f"[{time.perf_counter() - t0:.1f} s]")


def _chaos_chunk(args: tuple[int, int, int, bool, str, int, str, bool, bool]
                 ) -> tuple[dict[str, list[tuple[int, Violation]]], collections.Counter[str]]:
    first, last, max_robots, dense, auth, wide, preset, rough, insider = args
    DRAWN.clear()
    return (chaos(range(first, last), max_robots, False, dense, auth, wide, preset, rough,
                  insider), DRAWN.copy())


def _chaos_parallel(seeds: range, max_robots: int, jobs: int, dense: bool,
                    auth: str, wide: int = 0, preset: str = "udp", rough: bool = False,
                    insider: bool = False) -> dict[str, list[tuple[int, Violation]]]:
    from concurrent.futures import ProcessPoolExecutor

    step = 50
    chunks = [(s, min(s + step, seeds.stop), max_robots, dense, auth, wide, preset, rough,
               insider)
              for s in range(seeds.start, seeds.stop, step)]
    found: dict[str, list[tuple[int, Violation]]] = {}
    with ProcessPoolExecutor(jobs) as pool:
        for part, drawn in pool.map(_chaos_chunk, chunks):
            DRAWN.update(drawn)
            for kind, hits in part.items():
                found.setdefault(kind, []).extend(hits)
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=200,
                    help="how many seeds, from --first (default 200)")
    ap.add_argument("--first", type=int, default=0,
                    help="the first seed (default 0): fresh seeds for a tree tuned on others")
    ap.add_argument("--seed", type=int, default=None, help="replay this one seed")
    ap.add_argument("--max-robots", type=int, default=60)
    ap.add_argument("--verbose", action="store_true", help="print the swarm and its log")
    ap.add_argument("--ring8", action="store_true", help="the ring-of-eight figure only")
    ap.add_argument("--phases", type=int, default=20, help="--ring8: heartbeat phases")
    ap.add_argument("--jobs", type=int, default=1,
                    help="processes (seeds are independent: one per core)")
    ap.add_argument("--dense", action="store_true",
                    help="4-8 faults a run within 1.5 s, mostly on neighbours")
    ap.add_argument("--auth", choices=("per-robot", "shared", "none"), default="per-robot",
                    help="authentication mode (default per-robot, as shipped)")
    ap.add_argument("--wide", action="store_const", const=1, default=0,
                    help="add compound link faults: overlapping one-way cuts, a robot muted "
                         "while a group is cut, fades during restarts, deafness during a "
                         "takeover, bursty loss up to 40 %% (a seed without it replays as "
                         "before)")
    ap.add_argument("--wider", action="store_const", const=2, dest="wide",
                    help="--wide, and the swarm split in three or four groups cut both "
                         "ways, the cuts healing one pair at a time (a --wide seed "
                         "replays as before)")
    ap.add_argument("--widest", action="store_const", const=3, dest="wide",
                    help="--wider, and a robot's link flapping, a holder leaving or "
                         "turning unhealthy inside a cut, a holder paused while it cannot "
                         "hear some neighbours (a --wider seed replays as before)")
    ap.add_argument("--wiped", action="store_const", const=4, dest="wide",
                    help="a robot restarted without its state file in every case (after "
                         "a crash, a leave, a fault or a pause; at times twice), and up "
                         "to one of the --widest kinds beside it")
    ap.add_argument("--wiped-all", action="store_const", const=5, dest="wide",
                    help="--wiped, or a standby restarted without its state file around "
                         "its claim or once it holds the slot it took over (a --wiped "
                         "seed replays as before)")
    ap.add_argument("--rough", action="store_true",
                    help="a channel that delays (2-30 ms), reorders (jitter 2-120 ms) and "
                         "duplicates (0-20 %%), drawn per seed (its swarm and faults stay)")
    ap.add_argument("--insider", action="store_true",
                    help="a forge fault too, from a robot drawn per seed: any attack per "
                         "robot; with a shared key and unsigned, replay and ahead (what "
                         "anyone can record or make)")
    ap.add_argument("--preset", choices=tuple(PRESETS), default="udp",
                    help="the timing every case runs at (default udp); at radio the "
                         "fault times and lengths are stretched by its t_max over udp's")
    a = ap.parse_args()
    global AUTH
    AUTH = a.auth
    if a.ring8:
        print_ring8(a.phases)
        return
    seeds = range(a.seed, a.seed + 1) if a.seed is not None else range(a.first, a.first + a.seeds)
    t0 = time.perf_counter()
    if a.jobs > 1 and len(seeds) > 1:
        found = _chaos_parallel(seeds, a.max_robots, a.jobs, a.dense, a.auth, a.wide,
                                a.preset, a.rough, a.insider)
    else:
        found = chaos(seeds, a.max_robots, a.verbose, a.dense, a.auth, a.wide, a.preset,
                      a.rough, a.insider)
    wall = time.perf_counter() - t0
    total = sum(len(v) for v in found.values())
    wide = f" ({WIDE_FLAGS[a.wide][3:]})" if a.wide else ""
    print(f"{len(seeds)} seeds{' (dense)' if a.dense else ''}{wide}, "
          f"auth {a.auth}, {a.preset}(){', rough' if a.rough else ''}"
          f"{', insider' if a.insider else ''}, "
          f"{total} violation(s) in {wall:.1f} s")
    print("  drawn: " + ", ".join(f"{k} {n}" for k, n in sorted(DRAWN.items())))
    for kind, hits in sorted(found.items()):
        runs = sorted({s for s, _ in hits})
        print(f"  {kind}: {len(hits)} in {len(runs)} run(s)")
        for seed, v in hits[:5]:
            extra = ("" if a.max_robots == 60 else f" --max-robots {a.max_robots}") \
                + (" --dense" if a.dense else "") + WIDE_FLAGS[a.wide] \
                + ("" if a.auth == "per-robot" else f" --auth {a.auth}") \
                + ("" if a.preset == "udp" else f" --preset {a.preset}") \
                + (" --rough" if a.rough else "") + (" --insider" if a.insider else "")
            print(f"    t={v.t:.2f} robot {v.robot}: {v.detail}\n"
                  f"      python bench/bench_chaos.py --seed {seed}{extra} --verbose")
    sys.exit(1 if total else 0)


if __name__ == "__main__":
    main()
