"""The explorer: every interleaving of a small swarm's frames, on the real protocol core.

`sim.virtual.simulator` runs one seeded schedule; chaos (bench/bench_chaos.py) samples
many. This one enumerates, for one configuration (a small swarm, its auth mode and up
to two scripted faults: crashes, leaves, restarts, one-way cuts), every way the channel
may treat the frames near the faults: at each step of a window around them, either
every frame due is delivered, or one of them is dropped, duplicated or held back a step
(reordered), up to `budget` such perturbations a run. Each run is stepped to the
horizon (quiet for `Bounds.settle` after the last fault) and judged at its final state
by `sim.shared.invariants` (takeover within the bound or an alert, no dual execution
beyond the bound after the last heal, every warning answered), invariant 8 (one view of
each slot, executed by the robot it names) and, at every step, that no robot's view of
a slot moves backwards (DESIGN rule 2's order: epoch, then the lower id).

The search is a depth-first walk over `World` states (`sim.virtual.explore_world`),
copied at each choice point, with states de-duplicated by `World.key()`: a frame whose
loss changes nothing merges with the run that delivered it at the next step. It is
bounded (steps, window, budget) and the key leaves some node state out, so it proves
nothing beyond what it walked; what it walked it walked exhaustively.

    from sim.virtual.explore import explore, scripts
    for script in scripts("four"):
        print(explore(script, auth="none").summary())
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field

from sim.shared.fakeid import fake_identities
from sim.shared.faults import Fault, FaultKind
from sim.shared.invariants import Bounds, Violation
from sim.virtual.explore_world import PERTURB, Choice, NodeFactory, Script, World
from swarmd.core.auth import Identity
from swarmd.core.node import Node
from swarmd.core.params import Params, udp
from swarmd.core.plan import RobotPlan, SwarmPlan

AUTH_MODES = ("per-robot", "shared", "none")


@dataclass(slots=True)
class Found:
    """A violation and the shortest schedule found that leads to it."""

    violation: Violation
    choices: tuple[Choice, ...]


@dataclass(slots=True)
class Result:
    script: Script
    auth: str
    states: int = 0
    """States stepped through (one per step of every run walked)."""
    branches: int = 1
    """Interleavings tried: the run that delivers everything, and one more for every
    perturbed delivery tried from a state."""
    runs: int = 0
    """Interleavings walked to their final state (the others merged into one walked)."""
    merged: int = 0
    """Runs cut short because their state was reached before (de-duplication)."""
    found: dict[str, Found] = field(default_factory=dict)
    """violation kind -> the shortest interleaving that shows it."""
    violating_runs: int = 0
    wall: float = 0.0

    def summary(self) -> str:
        kinds = ", ".join(f"{k}" for k in sorted(self.found)) or "none"
        return (f"{self.script.name} [{self.auth}]: {self.branches} interleavings, "
                f"{self.states} states, {self.runs} walked to the end, {self.violating_runs} "
                f"violating ({kinds}), {self.wall:.1f} s")

    def schedule(self, kind: str) -> str:
        """The shortest interleaving that shows `kind`, as a readable schedule."""
        f = self.found[kind]
        lines = [f"{self.script.name} [{self.auth}], {kind}:",
                 "  faults: " + " ".join(x.spec() for x in self.script.faults)]
        lines += [f"  {c.describe()}" for c in f.choices] or ["  (every frame delivered)"]
        v = f.violation
        lines.append(f"  => t={v.t:.2f} {v.kind} robot {v.robot}: {v.detail}")
        return "\n".join(lines)


def explore(script: Script, *, auth: str = "none", budget: int = 1,
            factory: NodeFactory = Node, identities: dict[int, Identity] | None = None,
            max_runs: int = 100_000) -> Result:
    """Walk every interleaving of `script` with at most `budget` perturbed deliveries.
    Per robot, each robot signs with `identities` (default: `sim.shared.fakeid`'s
    stand-ins); `factory` builds the nodes (a test's mutant, say)."""
    if auth not in AUTH_MODES:
        raise ValueError(f"auth must be one of {', '.join(AUTH_MODES)}, not {auth!r}")
    keys = (bytes(range(32)),) if auth != "none" else ()
    ids: dict[int, Identity] = {}
    if auth == "per-robot":
        ids = identities if identities is not None else fake_identities(script.plan.robots)
    result = Result(script, auth)
    t0 = time.perf_counter()
    root = World.start(script, keys=keys, identities=ids, factory=factory)
    seen: dict[tuple[int, str], int] = {}
    stack: list[tuple[bytes, Choice] | World] = [root]
    while stack and result.runs < max_runs:
        item = stack.pop()
        if isinstance(item, World):
            world = item
        else:  # a choice not tried yet: its state, copied when its turn comes
            world = root.thaw(item[0])
            world.advance(item[1])
        _walk(world, budget, seen, stack, result)
    result.wall = time.perf_counter() - t0
    return result


def _walk(world: World, budget: int, seen: dict[tuple[int, str], int],
          stack: list[tuple[bytes, Choice] | World], result: Result) -> None:
    """Step `world` to its end, pushing a copy for every other choice on the way (the
    run that delivers everything is walked first, so perturbed runs merge into it)."""
    while world.step <= world.last_step:
        left = budget - len(world.choices)
        key = (world.step, world.key())
        if seen.get(key, -1) >= left:
            result.merged += 1
            return
        seen[key] = left
        result.states += 1
        if left > 0 and world.choosable() and world.due():
            blob = world.freeze()
            result.branches += len(world.due()) * len(PERTURB)
            stack += [(blob, Choice(world.step, i, what))
                      for i in range(len(world.due())) for what in PERTURB]
        world.advance(None)
    result.runs += 1
    bad = world.finish()
    if bad:
        result.violating_runs += 1
    for v in bad:
        old = result.found.get(v.kind)
        if old is None or len(world.choices) < len(old.choices):
            result.found[v.kind] = Found(v, tuple(world.choices))


# ---------------------------------------------------------------------- configurations
def swarm(name: str) -> tuple[SwarmPlan, Params]:
    """The small swarms the explorer walks (`SWARMS`)."""
    p = udp()
    if name == "three":  # two actives watching each other, one standby: quorum 1
        robots = {1: RobotPlan(1, "f1"), 2: RobotPlan(2, "f2"), 3: RobotPlan(3, None, ("f1",))}
        return SwarmPlan(31, ("f1", "f2"), robots, {"f1": ("f2",), "f2": ("f1",)}), \
            p.with_overrides(quorum=1)
    ring = {"f1": ("f2", "f3"), "f2": ("f1", "f3"), "f3": ("f1", "f2")}
    if name == "four":  # the paper's shape, small: three actives, one standby of f1
        robots = {1: RobotPlan(1, "f1"), 2: RobotPlan(2, "f2"), 3: RobotPlan(3, "f3"),
                  4: RobotPlan(4, None, ("f1",))}
        return SwarmPlan(41, ("f1", "f2", "f3"), robots, ring), p
    if name == "five":  # two standbys covering f1 (rule 6) and f2
        robots = {1: RobotPlan(1, "f1"), 2: RobotPlan(2, "f2"), 3: RobotPlan(3, "f3"),
                  4: RobotPlan(4, None, ("f1", "f2")), 5: RobotPlan(5, None, ("f1",))}
        return SwarmPlan(51, ("f1", "f2", "f3"), robots, ring), p
    raise ValueError(f"no swarm {name!r}: one of {', '.join(SWARMS)}")


SWARMS = ("three", "four", "five")
AT = 3.0
"""When the first scripted fault strikes: after every robot has heard every other for a
start-up grace (`udp()`'s 2 s) and more, so the links are measured and judged by `t_max`
(DESIGN "Detection", "A link not measured yet"), and a cut lasting past the clean
takeover bound is taken over under it."""


def fault_sets(plan: SwarmPlan, params: Params) -> Iterator[tuple[str, tuple[Fault, ...]]]:
    """Up to two faults around robot 1 (f1's holder), f1's first standby and its first
    watcher: what the explorer scripts for each swarm. Each begins at `AT`; a fade or
    cut lasts past the takeover bound, so the slot is taken over under it."""
    sb = next(r for r in plan.covered_by("f1") if plan.robots[r].function is None)
    watchers = [r for r, p in sorted(plan.robots.items()) if p.function in
                plan.watched_by("f1")]
    tb = params.takeover_bound()
    rest = tuple(r for r in sorted(plan.robots) if r != 1)
    yield "crash", (Fault(FaultKind.CRASH, AT, (1,)),)
    yield "leave", (Fault(FaultKind.LEAVE, AT, (1,)),)
    yield "restart", (Fault(FaultKind.RESTART, AT, (1,)),)
    yield "crash-restart", (Fault(FaultKind.CRASH, AT, (1,)),
                            Fault(FaultKind.RESTART, AT + tb + 0.5, (1,)))
    # Back without its state file (`restart:1@T:wiped`), as the plan's holder of f1,
    # after its slot was taken over: on its crash's warnings, or on its own LEAVE.
    yield "crash-wiped", (Fault(FaultKind.CRASH, AT, (1,)),
                          Fault(FaultKind.RESTART, AT + tb + 0.5, (1,), wiped=True))
    yield "leave-wiped", (Fault(FaultKind.LEAVE, AT, (1,)),
                          Fault(FaultKind.RESTART, AT + tb + 0.5, (1,), wiped=True))
    yield "no-standby-left", (Fault(FaultKind.CRASH, AT, (1, sb)),)  # rule 8: an alert
    yield "fade", (Fault(FaultKind.FADE, AT, (1,), tb + 0.5),)
    yield "oneway", (Fault(FaultKind.PARTITION, AT, (1, *rest), tb + 0.5, ((1,), rest),
                           oneway=True),)
    yield "cut-off", (Fault(FaultKind.PARTITION, AT, (1, *rest), tb + 0.5, ((1,), rest)),)
    yield "deaf-standby-crash", (Fault(FaultKind.DEAF, AT, (sb,), 1.0, (tuple(watchers),)),
                                 Fault(FaultKind.CRASH, AT, (1,)))
    yield "fade-restart", (Fault(FaultKind.FADE, AT, (1,), tb + 0.5),
                           Fault(FaultKind.RESTART, AT + 0.5, (1,)))
    yield "deaf-watcher-crash", (Fault(FaultKind.DEAF, AT, (watchers[0],), 1.5, ((sb,),)),
                                 Fault(FaultKind.CRASH, AT, (1,)))
    yield "muted-standby-crash", (Fault(FaultKind.FADE, AT, (sb,), 1.0),
                                  Fault(FaultKind.CRASH, AT, (1,)))
    yield "two-cuts", (Fault(FaultKind.PARTITION, AT, (1, sb), tb + 0.5, ((1,), (sb,)),
                             oneway=True),
                       Fault(FaultKind.PARTITION, AT + 0.5, (sb, 1), 1.0, ((sb,), (1,)),
                             oneway=True))


def scripts(name: str, *, window: float = 0.6) -> Iterator[Script]:
    """Every configuration of swarm `name`: choice points from the first fault for
    `window` seconds and again for `window` after the last heal; the horizon leaves
    `Bounds.settle` of quiet after the last fault."""
    plan, params = swarm(name)
    settle = Bounds.of(params, 0.01).settle
    for label, faults in fault_sets(plan, params):
        last = max((f.end if f.end is not None else f.at) for f in faults)
        windows = ((AT, AT + window),) if last == AT else \
            ((AT, AT + window), (last, last + window))
        yield Script(f"{name}/{label}", plan, params, faults,
                     horizon=round(last + settle + 0.5, 1), windows=windows)


__all__ = ["AUTH_MODES", "SWARMS", "Found", "Result", "explore", "fault_sets", "scripts",
           "swarm"]
