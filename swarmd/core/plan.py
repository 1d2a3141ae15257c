"""The swarm plan as the core sees it: functions, robots, who watches which slot.

DESIGN rule 1: functions, not robot ids, are the unit. The config names, per robot, its
neighbours (robot ids, as the paper's launch file does) and the robots it may substitute;
here that is turned into relations between function *slots*:

- `watches[f]`: the slots whose holders the holder of `f` watches;
- `covers[f]`: the robots that may substitute `f` (standbys listing it in `subs`, plus
  the robot whose home slot it is, so a robot that was replaced and came back covers
  its own slot again).

Whoever holds `f` at any time inherits `watches[f]`, and the holders of the slots that
watch `f` follow the new holder: nothing is re-configured after a takeover.

The plan is built by the config layer: validation (pydantic) stays there, so the core
stays stdlib only (DESIGN section 2).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from swarmd.core.errors import PlanError as PlanError

MAX_FUNCTIONS = 0xFFFF
"""Slots 1..65535 (wire.py's slot field; 0 means "no function")."""



@dataclass(frozen=True, slots=True)
class Relevant:
    """What one robot must hear (DESIGN section 2, "What a robot hears"): frames about
    `slots` (wire indices) and the standby heartbeats of `standbys`. Everything else it
    would ignore anyway, so a receiver drops it before verifying the tag."""

    slots: frozenset[int]
    standbys: frozenset[int]


@dataclass(frozen=True, slots=True)
class Unheard:
    """The heartbeats one robot drops unread (`Node._irrelevant`), field by field of
    the wire header, for a driver that drops them before they reach the node (the udp
    transport's socket filter): of swarm `swarm_id`, from one of `senders` (every robot
    of the plan but this one), about a slot of `slots`, or without a slot (a standby's)
    from one of `standbys`."""

    swarm_id: int
    senders: frozenset[int]
    slots: frozenset[int]
    standbys: frozenset[int]


@dataclass(frozen=True, slots=True)
class RobotPlan:
    robot_id: int
    function: str | None
    """The slot this robot executes at start (ACTIVE), or None (STANDBY)."""
    subs: tuple[str, ...] = ()
    """Slots this robot may take over (the paper's `subs`, as functions)."""


@dataclass(frozen=True, slots=True)
class SwarmPlan:
    swarm_id: int
    functions: tuple[str, ...]
    """Slot names in wire order: slot index on the wire is position + 1."""
    robots: Mapping[int, RobotPlan]
    watches: Mapping[str, tuple[str, ...]]
    """function -> the functions whose holders its holder watches (neighbourhoods)."""
    _watchers: dict[str, tuple[str, ...]] = field(init=False, repr=False, compare=False)
    _covers: dict[str, tuple[int, ...]] = field(init=False, repr=False, compare=False)
    _covered: dict[int, tuple[str, ...]] = field(init=False, repr=False, compare=False)
    _index: dict[str, int] = field(init=False, repr=False, compare=False)
    _holders: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not 0 <= self.swarm_id <= 0xFFFF:
            raise PlanError(f"swarm id {self.swarm_id} does not fit 16 bits")
        if len(set(self.functions)) != len(self.functions):
            raise PlanError("duplicate function names")
        if not 1 <= len(self.functions) <= MAX_FUNCTIONS:
            raise PlanError(f"a swarm has 1 to {MAX_FUNCTIONS} functions (a 16-bit slot on "
                            "the wire)")
        index = {name: i + 1 for i, name in enumerate(self.functions)}
        holders = self._check_robots(index)
        for f, watched in self.watches.items():
            if f not in index or any(w not in index for w in watched):
                raise PlanError(f"watches names an unknown function: {f} -> {watched}")
        watchers: dict[str, list[str]] = {f: [] for f in self.functions}
        for f, watched in self.watches.items():
            for w in watched:
                if w != f and f not in watchers[w]:
                    watchers[w].append(f)
        covers: dict[str, list[int]] = {f: [] for f in self.functions}
        for rid in sorted(self.robots):
            robot = self.robots[rid]
            for f in (*robot.subs, *((robot.function,) if robot.function else ())):
                if rid not in covers[f]:
                    covers[f].append(rid)
        object.__setattr__(self, "_index", index)
        object.__setattr__(self, "_holders", holders)
        object.__setattr__(self, "_watchers", {f: tuple(v) for f, v in watchers.items()})
        object.__setattr__(self, "_covers", {f: tuple(sorted(v)) for f, v in covers.items()})
        covered: dict[int, list[str]] = {rid: [] for rid in self.robots}
        for f in self.functions:  # plan order: a standby's digest lists them so
            for rid in covers[f]:
                covered[rid].append(f)
        object.__setattr__(self, "_covered", {r: tuple(v) for r, v in covered.items()})

    def _check_robots(self, index: Mapping[str, int]) -> dict[str, int]:
        """Every robot's id, function and substitutes valid; function -> its holder."""
        holders: dict[str, int] = {}
        for rid, robot in self.robots.items():
            if rid != robot.robot_id or not 1 <= rid <= 0xFFFF:
                raise PlanError(f"robot id {rid} is not a 16-bit id matching its entry")
            if robot.function is not None:
                if robot.function not in index:
                    raise PlanError(f"robot {rid} holds unknown function {robot.function!r}")
                if robot.function in holders:
                    raise PlanError(
                        f"function {robot.function} held by robots {holders[robot.function]} "
                        f"and {rid}"
                    )
                holders[robot.function] = rid
            for f in robot.subs:
                if f not in index:
                    raise PlanError(f"robot {rid} substitutes unknown function {f!r}")
        return holders

    # -- queries -------------------------------------------------------------------------
    def slot(self, function: str) -> int:
        """Wire index (1..65535) of a function."""
        return self._index[function]

    def function_at(self, slot: int) -> str | None:
        """Function name of a wire index, or None if out of range."""
        if 1 <= slot <= len(self.functions):
            return self.functions[slot - 1]
        return None

    def watched_by(self, function: str) -> tuple[str, ...]:
        """Slots whose holders watch `function` (its witnesses, DESIGN rule 3)."""
        return self._watchers[function]

    def watched(self, function: str) -> tuple[str, ...]:
        """Slots the holder of `function` watches."""
        return tuple(w for w in self.watches.get(function, ()) if w != function)

    def covered_by(self, function: str) -> tuple[int, ...]:
        """Robots allowed to take `function` over, lowest id first."""
        return self._covers[function]

    def covered(self, robot_id: int) -> tuple[str, ...]:
        """The slots `robot_id` may hold (its home slot and its `subs`), in plan order:
        the order of its heartbeat's view digest (`digest.py`). Empty for a robot
        outside the plan."""
        return self._covered.get(robot_id, ())

    def initial_holder(self, function: str) -> int | None:
        return self._holders.get(function)

    def relevant(self, robot_id: int) -> Relevant:
        """The slots and standbys `robot_id` must hear, whatever role it has.

        A robot only ever holds a slot it covers (its home slot or one of its `subs`,
        rule 1), so one set serves every role it can reach: for each covered slot `c`,
        `c` itself (fencing of our own slot, rule 2; claims and LEAVEs for it; heartbeats
        that refute its suspect, rule 4), the slots `c`'s holder watches (their
        heartbeats feed the watchdogs; a holder taking `c` over starts watching them
        with what it has heard, Fig. 7) and the slots that watch `c` (their holders are
        the witnesses whose warnings count, rule 3). Standbys: the robots that cover any
        of those slots, whose liveness heartbeats tell rules 6 and 8 whether anyone is
        left to take a watched slot over."""
        near: set[str] = set()
        for c in self.covered(robot_id):
            near.add(c)
            near.update(self.watched(c))
            near.update(self._watchers[c])
        standbys = {r for f in near for r in self._covers[f]}
        return Relevant(frozenset(self._index[f] for f in near), frozenset(standbys))

    def unheard(self, robot_id: int) -> Unheard:
        """The heartbeats `robot_id` never acts on, whatever role it has: the plan's
        slots outside `relevant`, and the standby heartbeats of robots outside its
        `standbys`, from any robot of the plan but itself (`Node._irrelevant`'s rule)."""
        near = self.relevant(robot_id)
        others = frozenset(self.robots) - {robot_id}
        every_slot = frozenset(range(1, len(self.functions) + 1))
        return Unheard(self.swarm_id, others, every_slot - near.slots, others - near.standbys)

    def standbys(self) -> tuple[int, ...]:
        return tuple(sorted(r for r, p in self.robots.items() if p.function is None))
