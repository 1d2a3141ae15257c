"""The swarm file: one YAML file describing the whole swarm (DESIGN.md section 3).

Schema (fixed; runtime, sim and check code against it; see docs/config.md):

    swarm: {id: 1543, name: paper}
    timing: {preset: udp, t_max: 0.6}          # preset + overrides of Params fields
    key_file: null                             # relative to this file
    functions: {f1: {kind: slot, position: [x, y, z]}, f2: {kind: patrol, ...}}
    robots: [{id: 1, state: active, function: f1, neighbors: [2, 4], home: [x, y]},
             {id: 5, state: standby, subs: [1, 4]}]
    alert_hook: null

pydantic checks each field's shape; `_cross_check` then checks what relates fields to
each other (neighbours exist, each function has one holder, enough watchers for the
quorum, ...). Both report through `Problem`s naming the file and the field.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PlainValidator, PrivateAttr, field_validator

from swarmd.config.errors import ConfigError, Loc, Problem, has_errors
from swarmd.config.source import Source, parse_source, read_source, validate
from swarmd.core.params import PRESETS, Params, ParamsError
from swarmd.core.plan import PlanError, RobotPlan, SwarmPlan
from swarmd.keys import KeyFileError, load_key

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


class SwarmInfo(_Model):
    id: int = Field(ge=0, le=0xFFFF, description="16-bit swarm id carried by every frame")
    name: str = ""


class Timing(_Model):
    """A preset of `swarmd.core.params` plus overrides of any of its fields."""

    preset: Literal["udp", "radio"] = "udp"
    heartbeat_interval: float | None = None
    standby_heartbeat_interval: float | None = None
    t_max: float | None = None
    warn_interval: float | None = None
    vote_window: float | None = None
    quorum: int | None = None
    claim_hold: float | None = None
    startup_grace: float | None = None
    standby_timeout: float | None = None
    alert_after: float | None = None
    rejoin_hold: float | None = None

    def overrides(self) -> dict[str, float | int]:
        """The Params fields this file sets explicitly."""
        return {
            k: v for k, v in self.model_dump(exclude={"preset"}).items() if v is not None
        }

    def params(self) -> Params:
        """Preset plus overrides. Raises ParamsError when they cannot work together."""
        return PRESETS[self.preset]().with_overrides(**self.overrides())


Vec3 = tuple[float, float, float]


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
    # functions. Both are accepted and resolved to functions in `_cross_check`.
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, str) and value:
        return value
    raise ValueError(f"must be a robot id or a function name, got {value!r}")


SubRef = Annotated[int | str, PlainValidator(_sub_ref)]


class RobotEntry(_Model):
    id: int = Field(ge=1, le=0xFFFF)
    state: Literal["active", "standby"]
    function: str | None = None
    neighbors: list[int] = Field(default_factory=list)
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
    key_file: str | None = None
    functions: dict[str, FunctionSpec] = Field(min_length=1)
    robots: list[RobotEntry] = Field(min_length=1)
    alert_hook: str | list[str] | None = None

    _source: str = PrivateAttr(default="<string>")
    _directory: Path = PrivateAttr(default_factory=Path.cwd)
    _warnings: tuple[Problem, ...] = PrivateAttr(default=())

    # -- where it came from --------------------------------------------------------------
    @property
    def source(self) -> str:
        """The file name as given to `load_swarm`."""
        return self._source

    @property
    def warnings(self) -> tuple[Problem, ...]:
        """Doubtful but workable things (e.g. a function no standby covers)."""
        return self._warnings

    @property
    def key_path(self) -> Path | None:
        """The swarm key file, resolved relative to the swarm file."""
        if self.key_file is None:
            return None
        p = Path(self.key_file).expanduser()
        return p if p.is_absolute() else self._directory / p

    def key(self) -> bytes | None:
        """The 32-byte swarm key, or None for an unsigned swarm."""
        path = self.key_path
        return load_key(path) if path is not None else None

    # -- what the rest of swarmd needs ---------------------------------------------------
    def params(self) -> Params:
        """Timing preset plus overrides (swarmd.core.params)."""
        return self.timing.params()

    def robot(self, robot_id: int) -> RobotEntry:
        for r in self.robots:
            if r.id == robot_id:
                return r
        raise KeyError(robot_id)

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
        unresolvable entries are skipped (they are errors of `_cross_check`)."""
        by_id = {r.id: r for r in self.robots}
        out: list[str] = []
        for ref in robot.subs:
            if isinstance(ref, int):
                target = by_id.get(ref)
                f = target.holds if target is not None else None
            else:
                f = ref if ref in self.functions else None
            if f is not None and f not in out:
                out.append(f)
        return tuple(out)

    def coverage(self) -> list[Coverage]:
        """One row per function, in wire order; tolerant of a swarm with errors."""
        rows = []
        for name, spec in self.functions.items():
            holders = tuple(r.id for r in self.robots if r.holds == name)
            watchers = sorted(
                {
                    r.id
                    for r in self.robots
                    if r.state == "active"
                    and r.id not in holders
                    and any(h in r.neighbors for h in holders)
                }
            )
            standbys = sorted(
                {r.id for r in self.robots if r.state == "standby"
                 and name in self.sub_functions(r)}
            )
            rows.append(Coverage(name, spec.kind, holders, tuple(watchers), tuple(standbys)))
        return rows

    def to_plan(self) -> SwarmPlan:
        """The core's view (DESIGN rule 1): watches[f_R] = functions of R's neighbours;
        subs (robot ids or names) resolved to functions."""
        by_id = {r.id: r for r in self.robots}
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
        except PlanError as exc:  # _cross_check should have caught it first
            raise ConfigError([Problem(self.source, "<swarm>", str(exc))]) from exc


# -- loading ------------------------------------------------------------------------------


def load_swarm(path: str | Path) -> SwarmConfig:
    """Read, validate and cross-check a swarm file.

    Raises ConfigUnreadable (cannot read), ConfigError (every problem, warnings too).
    Warnings of a usable file are in `cfg.warnings`.
    """
    return _finish(read_source(path))


def parse_swarm(text: str, name: str = "<string>", path: Path | None = None) -> SwarmConfig:
    """Like `load_swarm` for YAML text (tests, `import-launch`); `path`, if given, is
    where relative paths in the text are resolved from."""
    return _finish(parse_source(text, name, path))


def inspect_swarm(source: Source) -> tuple[SwarmConfig | None, list[Problem]]:
    """Validate without raising on cross-check errors: the config (None if its shape is
    invalid) and every problem. `swarmd check` prints a table even for a bad swarm."""
    try:
        cfg: SwarmConfig = validate(SwarmConfig, source)
    except ConfigError as exc:
        return None, list(exc.problems)
    cfg._source = source.name
    cfg._directory = source.directory
    problems = _cross_check(cfg, source)
    cfg._warnings = tuple(p for p in problems if p.severity == "warning")
    return cfg, problems


def _finish(source: Source) -> SwarmConfig:
    cfg, problems = inspect_swarm(source)
    if cfg is None or has_errors(problems):
        raise ConfigError(problems)
    return cfg


def _cross_check(cfg: SwarmConfig, src: Source) -> list[Problem]:
    out: list[Problem] = []

    def err(loc: Loc, msg: str) -> None:
        out.append(src.problem(loc, msg))

    def warn(loc: Loc, msg: str) -> None:
        out.append(src.problem(loc, msg, "warning"))

    # Functions: names and count (one byte on the wire, swarmd.core.wire).
    for name in cfg.functions:
        if not FUNCTION_NAME.match(name):
            err(("functions", name), f"function name {name!r} must start with a letter or "
                "'_' and use letters, digits, '_', '.', '-' (at most 32)")
    if len(cfg.functions) > 255:
        err(("functions",), f"{len(cfg.functions)} functions; a swarm has at most 255 "
            "(the slot index is one byte on the wire)")

    # Timing: Params validates itself; name the field its message is about.
    quorum: int | None = None
    try:
        quorum = cfg.params().quorum
    except (ParamsError, TypeError) as exc:
        err(("timing", _params_field(str(exc), cfg.timing)), str(exc))

    if cfg.key_file is not None and cfg.key_path is not None:
        try:
            load_key(cfg.key_path)
        except KeyFileError as exc:
            err(("key_file",), str(exc))

    # Robots, one at a time.
    by_id: dict[int, RobotEntry] = {}
    first_index: dict[int, int] = {}
    for i, r in enumerate(cfg.robots):
        if r.id in by_id:
            err(("robots", i, "id"),
                f"robot id {r.id} is used twice (also robots[{first_index[r.id]}])")
        else:
            by_id[r.id] = r
            first_index[r.id] = i
    holder_of: dict[str, int] = {}
    for i, r in enumerate(cfg.robots):
        here: Loc = ("robots", i)
        if r.state == "standby":
            if r.function is not None:
                err((*here, "function"), f"robot {r.id} is a standby and holds no function "
                    "(make it active, or drop `function`)")
            if r.neighbors:
                err((*here, "neighbors"), f"robot {r.id} is a standby; standbys watch nobody "
                    "(they count warnings from the active robots, paper Fig. 9)")
        else:
            if r.subs:
                err((*here, "subs"), f"robot {r.id} is active; only standby robots "
                    "substitute others")
            f = r.holds
            assert f is not None
            if f not in cfg.functions:
                how = "" if r.function is not None else " (the default for an active robot)"
                err((*here, "function"), f"function {f!r}{how} is not defined under "
                    "`functions`")
            elif f in holder_of:
                err((*here, "function"), f"function {f} is already held by robot "
                    f"{holder_of[f]}; each function has one holder at start")
            else:
                holder_of[f] = r.id
        seen: set[int] = set()
        for n in r.neighbors:
            if n in seen:
                err((*here, "neighbors"), f"robot {n} is listed twice")
            seen.add(n)
            if n == r.id:
                err((*here, "neighbors"), f"robot {r.id} lists itself; a robot cannot "
                    "witness its own failure (DESIGN rule 3)")
            elif n not in by_id:
                err((*here, "neighbors"), f"robot {n} is not in the swarm")
            elif by_id[n].state == "standby" and r.state == "active":
                err((*here, "neighbors"), f"robot {n} is a standby; neighbours are the "
                    "robots executing functions (DESIGN rule 1)")
        seen_subs: set[int | str] = set()
        for ref in r.subs:
            if ref in seen_subs:
                err((*here, "subs"), f"{ref!r} is listed twice")
            seen_subs.add(ref)
            if isinstance(ref, int):
                if ref not in by_id:
                    err((*here, "subs"), f"robot {ref} is not in the swarm")
                elif by_id[ref].state != "active":
                    err((*here, "subs"), f"robot {ref} is a standby and has no function "
                        "to substitute")
            elif ref not in cfg.functions:
                err((*here, "subs"), f"function {ref!r} is not defined under `functions`")
        if r.state == "standby" and not r.subs:
            warn((*here, "subs"), f"standby robot {r.id} covers no function; it will "
                 "never take over")

    # Per function: a holder, enough witnesses (rule 3), some standby (rule 8).
    for row in cfg.coverage():
        here = ("functions", row.function)
        if not row.holders:
            err(here, f"no active robot holds {row.function} (an active robot holds "
                "`f<id>` unless it names another function)")
            continue
        if quorum is not None and len(row.watchers) < quorum:
            who = ", ".join(map(str, row.watchers)) or "none"
            err(here, f"watched by {len(row.watchers)} robot(s) ({who}), fewer than the "
                f"quorum of {quorum}: its failure could never be confirmed (DESIGN rule 3); "
                "add its holder to more robots' neighbors")
        if not row.standbys:
            warn(here, f"no standby covers {row.function}: if its holder fails the function "
                 "is lost and an alert is raised (DESIGN rule 8)")

    # Homes: parking spots on the ground, apart from each other (MuJoCo sim).
    homes = [(i, r) for i, r in enumerate(cfg.robots) if r.home is not None]
    for a, (i, r) in enumerate(homes):
        for j, s in homes[:a]:
            assert r.home is not None and s.home is not None
            if math.dist(r.home, s.home) < MIN_HOME_SPACING:
                warn(("robots", i, "home"), f"robot {r.id}'s home is within "
                     f"{MIN_HOME_SPACING} m of robot {s.id}'s (robots[{j}])")
    return out


def _params_field(message: str, timing: Timing) -> str:
    """The Params field a ParamsError is about. An override whose removal makes the
    timing valid is the culprit (`heartbeat_interval: 0.3` breaks the preset's t_max);
    else the first overridden field the message names, else the first named at all."""
    overridden = timing.overrides()
    preset = PRESETS[timing.preset]()
    for name in overridden:
        rest = {k: v for k, v in overridden.items() if k != name}
        try:
            preset.with_overrides(**rest)
        except (ParamsError, TypeError):
            continue
        return name
    names = [n for n in Timing.model_fields if n != "preset"]
    mentioned = sorted(
        (message.find(n), n) for n in names if re.search(rf"\b{n}\b", message)
    )
    for _, n in mentioned:
        if n in overridden:
            return n
    return mentioned[0][1] if mentioned else "preset"
