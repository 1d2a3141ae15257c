"""The swarm file: one YAML file describing the whole swarm (DESIGN.md section 3).

Schema (fixed; runtime, sim and check code against it; see docs/config.md):

    swarm: {id: 1543, name: paper}
    timing: {preset: udp, t_max: 0.6}          # preset + overrides of Params fields
    auth: {mode: per-robot, keys_dir: keys}    # or `none`, or {mode: shared, key_file: ...}
    functions: {f1: {kind: slot, position: [x, y, z]}, f2: {kind: patrol, ...}}
    robots: [{id: 1, state: active, function: f1, neighbors: [2, 4], home: [x, y]},
             {id: 5, state: standby, subs: [1, 4]}]
    alert_hook: null

This module is the schema: pydantic checks each field's shape. What relates fields to
each other (neighbours exist, one holder per function, enough watchers for the quorum)
is checked in `swarm_rules.py`, which also loads files. Both report through
`Problem`s naming the file and the field.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainValidator,
    PrivateAttr,
    StrictInt,
    field_validator,
)

from swarmd.base.keys import load_key
from swarmd.config.errors import ConfigError, Problem
from swarmd.core.params import PRESETS, Params
from swarmd.core.plan import PlanError, RobotPlan, SwarmPlan

FUNCTION_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]{0,31}$")
"""Function names are free text on the config side only (the wire carries the slot
index), but they must not look like robot ids, since `subs` accepts both."""

MIN_HOME_SPACING = 0.5
"""m. Two parking spots closer than this would put two quadrotors on each other."""


class _Model(BaseModel):
    # extra="forbid": a misspelt key (`neighbours`, `t-max`) must fail loudly instead of
    # silently leaving the default in place. allow_inf_nan=False: YAML's `.nan` would
    # pass every comparison in Params' checks and make a watchdog that never fires.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _not_bool(value: Any) -> Any:
    # YAML `t_max: yes` is a mistake, not 1 second; numbers written as text ("1e3",
    # which YAML 1.1 leaves a string) stay accepted.
    if isinstance(value, bool):
        raise ValueError(f"must be a number of seconds, got {value!r}")
    return value


Seconds = Annotated[float, BeforeValidator(_not_bool)]
Level = Annotated[float, BeforeValidator(_not_bool)]
"""A number, not seconds (`Params.suspect_level`, `Params.patience_cap`)."""


class SwarmInfo(_Model):
    # Strict: YAML `id: true` or `id: 1.0` is a mistake, not robot / swarm 1.
    id: StrictInt = Field(ge=0, le=0xFFFF, description="16-bit swarm id carried by every frame")
    name: str = ""


class Timing(_Model):
    """A preset of `swarmd.core.params` plus overrides of any of its fields."""

    preset: Literal["udp", "radio"] = "udp"
    heartbeat_interval: Seconds | None = None
    standby_heartbeat_interval: Seconds | None = None
    t_max: Seconds | None = None
    warn_interval: Seconds | None = None
    vote_window: Seconds | None = None
    quorum: StrictInt | None = None
    claim_hold: Seconds | None = None
    startup_grace: Seconds | None = None
    standby_timeout: Seconds | None = None
    alert_after: Seconds | None = None
    rejoin_hold: Seconds | None = None
    patience_cap: Level | None = None
    suspect_level: Level | None = None

    def overrides(self) -> dict[str, float | int]:
        """The Params fields this file sets explicitly."""
        return {
            k: v for k, v in self.model_dump(exclude={"preset"}).items() if v is not None
        }

    def params(self) -> Params:
        """Preset plus overrides. Raises ParamsError when they cannot work together."""
        return PRESETS[self.preset]().with_overrides(**self.overrides())


Vec3 = tuple[float, float, float]


# -- auth: how frames are signed (docs/config.md, "auth") ------------------------------
#
#     auth: none                                        # unsigned, said explicitly
#     auth: {mode: shared, key_file: swarm.key}         # one HMAC key for the whole swarm
#     auth: {mode: per-robot, keys_dir: keys, revoked: [3]}   # Ed25519, one key per robot
#
# A top-level `key_file:` (no `auth:`) is the shared mode. A swarm file with neither is
# unsigned without saying so: `swarmd check` warns, `swarmd start` refuses it. Per-robot
# mode: `keys_dir` (relative to the swarm file) holds `robot-<id>.pub` for every robot of
# the swarm not in `revoked`; each robot file's `identity_file` names that robot's
# private key (`swarmd.base.identity` has the file formats). What the section's values mean
# on disk (keys that exist, robots that are in the swarm) is checked in `auth.py`.

AuthMode = Literal["none", "shared", "per-robot"]


class NoAuth(_Model):
    """Unsigned frames: anyone who can send on the channel speaks for any robot."""

    mode: Literal["none"]


class SharedAuth(_Model):
    """One 32-byte HMAC key for the whole swarm: the weaker choice for tiny radios
    (every robot holding it can sign as any other; docs/DESIGN.md section 2)."""

    mode: Literal["shared"]
    key_file: str = Field(min_length=1)


class PerRobotAuth(_Model):
    """Each robot signs with its own Ed25519 key; the keys dir holds the public keys."""

    mode: Literal["per-robot"]
    keys_dir: str = Field(default="keys", min_length=1)
    revoked: list[StrictInt] = Field(default_factory=list)
    """Robots whose signatures nobody accepts any more (a lost or compromised robot)."""
    key_file: str | None = None
    """Optionally also a swarm key, given to the core with the identities."""


def _shorthand(value: Any) -> Any:
    # `auth: none` is the one-word form of `auth: {mode: none}`.
    if value == "none":
        return {"mode": "none"}
    if isinstance(value, str):
        raise ValueError(f"must be `none` or a mapping with `mode: shared` or "
                         f"`mode: per-robot`, got {value!r}")
    return value


AuthSpec = Annotated[
    Annotated[NoAuth | SharedAuth | PerRobotAuth, Field(discriminator="mode")],
    BeforeValidator(_shorthand),
]


class SlotFunction(_Model):
    """Hold a position (a formation slot)."""

    kind: Literal["slot"]
    position: Vec3


class PatrolFunction(_Model):
    """Fly a closed route through the waypoints at `speed`."""

    kind: Literal["patrol"]
    waypoints: list[Vec3] = Field(min_length=2)
    speed: float = Field(default=1.0, gt=0, description="m/s")


FunctionSpec = Annotated[SlotFunction | PatrolFunction, Field(discriminator="kind")]


def _sub_ref(value: Any) -> int | str:
    # The paper's launch file names substituted robots by id; DESIGN rule 1 thinks in
    # functions. Both are accepted and resolved to functions in `swarm_rules.cross_check`.
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and value:
        return value
    raise ValueError(f"must be a robot id or a function name, got {value!r}")


SubRef = Annotated[int | str, PlainValidator(_sub_ref)]


class RobotEntry(_Model):
    id: StrictInt = Field(ge=1, le=0xFFFF)
    state: Literal["active", "standby"]
    function: str | None = None
    neighbors: list[StrictInt] = Field(default_factory=list)
    subs: list[SubRef] = Field(default_factory=list)
    home: tuple[float, float] | None = None

    @field_validator("state", mode="before")
    @classmethod
    def _paper_state(cls, value: Any) -> Any:
        # The paper calls standbys "inactive" (launch file, Fig. 5).
        return "standby" if value == "inactive" else value

    @property
    def holds(self) -> str | None:
        """The function this robot executes at start: its `function`, default `f<id>`."""
        if self.state != "active":
            return None
        return self.function if self.function is not None else f"f{self.id}"


@dataclass(frozen=True, slots=True)
class Coverage:
    """Who holds, watches and covers one function (the `swarmd check` table)."""

    function: str
    kind: str
    holders: tuple[int, ...]
    watchers: tuple[int, ...]
    """Distinct robots whose neighbours include the holder (DESIGN rule 3 witnesses)."""
    standbys: tuple[int, ...]


class SwarmConfig(_Model):
    """A validated swarm file. Use `load_swarm` / `parse_swarm` to build one."""

    swarm: SwarmInfo
    timing: Timing = Field(default_factory=Timing)
    auth: AuthSpec | None = None
    key_file: str | None = None
    """The shared mode's key written at the top level (`auth: {mode: shared, ...}`)."""
    functions: dict[str, FunctionSpec] = Field(min_length=1)
    robots: list[RobotEntry] = Field(min_length=1)
    alert_hook: str | list[str] | None = None

    _source: str = PrivateAttr(default="<string>")
    _directory: Path = PrivateAttr(default_factory=Path.cwd)
    _warnings: tuple[Problem, ...] = PrivateAttr(default=())
    # Built once: `sub_functions` and `coverage` are called per robot and per function,
    # and rebuilding these per call made a 5,000-robot swarm take minutes to check.
    _by_id: dict[int, RobotEntry] | None = PrivateAttr(default=None)
    _subs: dict[int, tuple[str, ...]] = PrivateAttr(default_factory=dict)
    _coverage: list[Coverage] | None = PrivateAttr(default=None)

    # -- where it came from --------------------------------------------------------------
    @property
    def source(self) -> str:
        """The file name as given to `load_swarm`."""
        return self._source

    @property
    def warnings(self) -> tuple[Problem, ...]:
        """Doubtful but workable things (e.g. a function no standby covers)."""
        return self._warnings

    def _resolve(self, value: str) -> Path:
        p = Path(value).expanduser()
        return p if p.is_absolute() else self._directory / p

    @property
    def auth_mode(self) -> AuthMode:
        """How frames are signed: `none` (also a file that says nothing), `shared` (one
        swarm key) or `per-robot` (Ed25519, the auth section above)."""
        if isinstance(self.auth, PerRobotAuth):
            return "per-robot"
        if isinstance(self.auth, SharedAuth) or (self.auth is None and self.key_file):
            return "shared"
        return "none"

    @property
    def auth_explicit(self) -> bool:
        """False for a swarm file that says nothing about signing (`swarmd start`
        refuses it; `auth: none` is the explicit unsigned choice)."""
        return self.auth is not None or self.key_file is not None

    @property
    def key_path(self) -> Path | None:
        """The swarm key file (shared mode), resolved relative to the swarm file."""
        auth = self.auth
        if isinstance(auth, SharedAuth | PerRobotAuth):
            return self._resolve(auth.key_file) if auth.key_file is not None else None
        if isinstance(auth, NoAuth) or self.key_file is None:
            return None
        return self._resolve(self.key_file)

    @property
    def keys_dir_path(self) -> Path | None:
        """Per-robot mode: the directory of `robot-<id>.pub`, relative to this file."""
        if isinstance(self.auth, PerRobotAuth):
            return self._resolve(self.auth.keys_dir)
        return None

    @property
    def revoked(self) -> frozenset[int]:
        """Per-robot mode: robots whose signatures nobody accepts."""
        if isinstance(self.auth, PerRobotAuth):
            return frozenset(self.auth.revoked)
        return frozenset()

    def key(self) -> bytes | None:
        """The 32-byte swarm key, or None when the swarm has none."""
        path = self.key_path
        return load_key(path) if path is not None else None

    # -- what the rest of swarmd needs ---------------------------------------------------
    def params(self) -> Params:
        """Timing preset plus overrides (swarmd.core.params)."""
        return self.timing.params()

    def _robots_by_id(self) -> dict[int, RobotEntry]:
        if self._by_id is None:
            by_id: dict[int, RobotEntry] = {}
            for r in self.robots:
                by_id.setdefault(r.id, r)  # the first of a duplicate id, as `robot()` did
            self._by_id = by_id
        return self._by_id

    def robot(self, robot_id: int) -> RobotEntry:
        return self._robots_by_id()[robot_id]

    def robot_ids(self) -> tuple[int, ...]:
        return tuple(r.id for r in self.robots)

    def function_spec(self, name: str) -> dict[str, Any]:
        """A function's parameters as plain data, for the robot link's `assign`."""
        return self.functions[name].model_dump(mode="json")

    def holder(self, function: str) -> int | None:
        """The robot that executes `function` at start."""
        for r in self.robots:
            if r.holds == function:
                return r.id
        return None

    def sub_functions(self, robot: RobotEntry) -> tuple[str, ...]:
        """`robot.subs` resolved to function names (robot ids -> their functions);
        unresolvable entries are skipped (errors of `swarm_rules.cross_check`)."""
        cached = self._subs.get(id(robot))
        if cached is not None:
            return cached
        by_id = self._robots_by_id()
        out: list[str] = []
        for ref in robot.subs:
            if isinstance(ref, int):
                target = by_id.get(ref)
                f = target.holds if target is not None else None
            else:
                f = ref if ref in self.functions else None
            if f is not None and f not in out:
                out.append(f)
        result = tuple(out)
        if by_id.get(robot.id) is robot:  # a robot of this swarm: its id() stays valid
            self._subs[id(robot)] = result
        return result

    def coverage(self) -> list[Coverage]:
        """One row per function, in wire order; tolerant of a swarm with errors.
        Linear in the swarm's size (one pass over the robots), computed once."""
        if self._coverage is not None:
            return list(self._coverage)
        holders: dict[str, list[int]] = {name: [] for name in self.functions}
        held_by: dict[int, list[str]] = {}
        for r in self.robots:
            f = r.holds
            if f in holders:
                holders[f].append(r.id)
                held_by.setdefault(r.id, []).append(f)
        watchers: dict[str, set[int]] = {name: set() for name in self.functions}
        standbys: dict[str, set[int]] = {name: set() for name in self.functions}
        for r in self.robots:
            if r.state == "active":
                for n in set(r.neighbors):
                    for f in held_by.get(n, ()):
                        if r.id not in holders[f]:
                            watchers[f].add(r.id)
            else:
                for f in self.sub_functions(r):
                    standbys[f].add(r.id)
        rows = [
            Coverage(name, spec.kind, tuple(holders[name]), tuple(sorted(watchers[name])),
                     tuple(sorted(standbys[name])))
            for name, spec in self.functions.items()
        ]
        self._coverage = rows
        return list(rows)

    def to_plan(self) -> SwarmPlan:
        """The core's view (DESIGN rule 1): watches[f_R] = functions of R's neighbours;
        subs (robot ids or names) resolved to functions."""
        by_id = self._robots_by_id()
        watches: dict[str, tuple[str, ...]] = {}
        robots: dict[int, RobotPlan] = {}
        for r in self.robots:
            f = r.holds
            robots[r.id] = RobotPlan(r.id, f, self.sub_functions(r))
            if f is not None:
                watched = (by_id[n].holds for n in r.neighbors if n in by_id)
                watches[f] = tuple(w for w in watched if w is not None)
        try:
            return SwarmPlan(
                swarm_id=self.swarm.id,
                functions=tuple(self.functions),
                robots=robots,
                watches=watches,
            )
        except PlanError as exc:  # swarm_rules.cross_check catches these first
            raise ConfigError([Problem(self.source, "<swarm>", str(exc))]) from exc
