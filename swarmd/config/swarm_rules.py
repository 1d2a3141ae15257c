"""Loading a swarm file and the rules that relate its fields to each other.

pydantic (swarm.py) checks each field's shape; `cross_check` then checks what no single
field can: neighbours exist and are active, each function has one holder, every
function has at least `quorum` distinct watchers (DESIGN rule 3), some standby covers
it (rule 8, a warning), the timing works. All problems are collected, none stops the
others, so `swarmd check` can print them all at once.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from swarmd.config.auth import auth_issues
from swarmd.config.errors import ConfigError, Loc, Problem, has_errors
from swarmd.config.source import Source, parse_source, read_source, validate
from swarmd.config.swarm import (
    FUNCTION_NAME,
    MIN_HOME_SPACING,
    RobotEntry,
    SwarmConfig,
    Timing,
)
from swarmd.core.params import PRESETS, Params, ParamsError
from swarmd.core.plan import MAX_FUNCTIONS


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
    data = source.data
    if isinstance(data, dict) and "robot" in data and "robots" not in data:
        # A robot file where a swarm file belongs (`swarmd sim robot2.yaml`): one clear
        # problem instead of four schema errors about fields a robot file never has.
        named = f": {data['swarm']}" if isinstance(data.get("swarm"), str) else ""
        return None, [source.problem((), "this is a robot file (it has `robot:`); give the "
                                     f"swarm file it names{named}")]
    try:
        cfg: SwarmConfig = validate(SwarmConfig, source)
    except ConfigError as exc:
        return None, list(exc.problems)
    cfg._source = source.name
    cfg._directory = source.directory
    problems = cross_check(cfg, source)
    cfg._warnings = tuple(p for p in problems if p.severity == "warning")
    return cfg, problems


def _finish(source: Source) -> SwarmConfig:
    cfg, problems = inspect_swarm(source)
    if cfg is None or has_errors(problems):
        raise ConfigError(problems)
    return cfg


@dataclass
class _Problems:
    """The problems `cross_check` finds, in the order found, located in `src`."""

    src: Source
    out: list[Problem] = field(default_factory=list)

    def err(self, loc: Loc, msg: str) -> None:
        self.out.append(self.src.problem(loc, msg))

    def warn(self, loc: Loc, msg: str) -> None:
        self.out.append(self.src.problem(loc, msg, "warning"))


def cross_check(cfg: SwarmConfig, src: Source) -> list[Problem]:
    p = _Problems(src)
    _check_functions(cfg, p)
    quorum = _check_timing(cfg, p)

    # Signing (config/auth.py): a bad key is an error; an unsigned swarm, or a keys
    # dir not made yet, a warning here (`swarmd start` refuses both).
    for issue in auth_issues(cfg):
        p.out.append(src.problem(issue.loc, issue.message, issue.severity))

    # Robots, one at a time.
    by_id = _robots_by_id(cfg, p)
    holder_of: dict[str, int] = {}
    for i, r in enumerate(cfg.robots):
        here: Loc = ("robots", i)
        _check_role(cfg, r, here, holder_of, p)
        _check_neighbors(r, here, by_id, p)
        _check_subs(cfg, r, here, by_id, p)
        if r.state == "standby" and not r.subs:
            p.warn((*here, "subs"), f"standby robot {r.id} covers no function; it will "
                   "never take over")

    _check_coverage(cfg, quorum, p)
    _check_homes(cfg, p)
    return p.out


def _check_functions(cfg: SwarmConfig, p: _Problems) -> None:
    # Functions: names and count (a 16-bit slot on the wire, swarmd.core.wire).
    for name in cfg.functions:
        if not FUNCTION_NAME.match(name):
            p.err(("functions", name), f"function name {name!r} must start with a letter or "
                  "'_' and use letters, digits, '_', '.', '-' (at most 32)")
    if len(cfg.functions) > MAX_FUNCTIONS:
        p.err(("functions",), f"{len(cfg.functions)} functions; a swarm has at most "
              f"{MAX_FUNCTIONS} (the slot index is 16 bits on the wire)")


def _check_timing(cfg: SwarmConfig, p: _Problems) -> int | None:
    """The timing's problems; returns its quorum (None when the timing is invalid)."""
    # Timing: Params validates itself; name the field its message is about.
    try:
        params = cfg.params()
    except (ParamsError, TypeError) as exc:
        p.err(("timing", _params_field(str(exc), cfg.timing)), str(exc))
        return None
    for loc, msg, severity in timing_bounds(params):
        p.out.append(p.src.problem(("timing", loc), msg, severity))
    return params.quorum


def _robots_by_id(cfg: SwarmConfig, p: _Problems) -> dict[int, RobotEntry]:
    """Each robot by its id (the first robot with an id; a reuse is an error)."""
    by_id: dict[int, RobotEntry] = {}
    first_index: dict[int, int] = {}
    for i, r in enumerate(cfg.robots):
        if r.id in by_id:
            p.err(("robots", i, "id"),
                  f"robot id {r.id} is used twice (also robots[{first_index[r.id]}])")
        else:
            by_id[r.id] = r
            first_index[r.id] = i
    return by_id


def _check_role(cfg: SwarmConfig, r: RobotEntry, here: Loc, holder_of: dict[str, int],
                p: _Problems) -> None:
    """A standby holds and watches nothing; an active robot substitutes nobody and
    holds a defined function no other robot holds (recorded in `holder_of`)."""
    if r.state == "standby":
        if r.function is not None:
            p.err((*here, "function"), f"robot {r.id} is a standby and holds no function "
                  "(make it active, or drop `function`)")
        if r.neighbors:
            p.err((*here, "neighbors"), f"robot {r.id} is a standby; standbys watch nobody "
                  "(they count warnings from the active robots, paper Fig. 9)")
        return
    if r.subs:
        p.err((*here, "subs"), f"robot {r.id} is active; only standby robots "
              "substitute others")
    f = r.holds
    assert f is not None
    if f not in cfg.functions:
        how = "" if r.function is not None else " (the default for an active robot)"
        p.err((*here, "function"), f"function {f!r}{how} is not defined under "
              "`functions`")
    elif f in holder_of:
        p.err((*here, "function"), f"function {f} is already held by robot "
              f"{holder_of[f]}; each function has one holder at start")
    else:
        holder_of[f] = r.id


def _check_neighbors(r: RobotEntry, here: Loc, by_id: dict[int, RobotEntry],
                     p: _Problems) -> None:
    seen: set[int] = set()
    for n in r.neighbors:
        if n in seen:
            p.err((*here, "neighbors"), f"robot {n} is listed twice")
        seen.add(n)
        if n == r.id:
            p.err((*here, "neighbors"), f"robot {r.id} lists itself; a robot cannot "
                  "witness its own failure (DESIGN rule 3)")
        elif n not in by_id:
            p.err((*here, "neighbors"), f"robot {n} is not in the swarm")
        elif by_id[n].state == "standby" and r.state == "active":
            p.err((*here, "neighbors"), f"robot {n} is a standby; neighbours are the "
                  "robots executing functions (DESIGN rule 1)")


def _check_subs(cfg: SwarmConfig, r: RobotEntry, here: Loc, by_id: dict[int, RobotEntry],
                p: _Problems) -> None:
    seen_subs: set[int | str] = set()
    for ref in r.subs:
        if ref in seen_subs:
            p.err((*here, "subs"), f"{ref!r} is listed twice")
        seen_subs.add(ref)
        if isinstance(ref, int):
            if ref not in by_id:
                p.err((*here, "subs"), f"robot {ref} is not in the swarm")
            elif by_id[ref].state != "active":
                p.err((*here, "subs"), f"robot {ref} is a standby and has no function "
                      "to substitute")
        elif ref not in cfg.functions:
            p.err((*here, "subs"), f"function {ref!r} is not defined under `functions`")


def _check_coverage(cfg: SwarmConfig, quorum: int | None, p: _Problems) -> None:
    # Per function: a holder, enough witnesses (rule 3), some standby (rule 8).
    for row in cfg.coverage():
        here: Loc = ("functions", row.function)
        if not row.holders:
            p.err(here, f"no active robot holds {row.function} (an active robot holds "
                  "`f<id>` unless it names another function)")
            continue
        if quorum is not None and len(row.watchers) < quorum:
            who = ", ".join(map(str, row.watchers)) or "none"
            p.err(here, f"watched by {len(row.watchers)} robot(s) ({who}), fewer than the "
                  f"quorum of {quorum}: its failure could never be confirmed (DESIGN rule 3); "
                  "add its holder to more robots' neighbors")
        if not row.standbys:
            p.warn(here, f"no standby covers {row.function}: if its holder fails the function "
                   "is lost and an alert is raised (DESIGN rule 8)")


def _check_homes(cfg: SwarmConfig, p: _Problems) -> None:
    # Homes: parking spots on the ground, apart from each other (MuJoCo sim).
    homes = [(i, r) for i, r in enumerate(cfg.robots) if r.home is not None]
    for a, (i, r) in enumerate(homes):
        for j, s in homes[:a]:
            assert r.home is not None and s.home is not None
            if math.dist(r.home, s.home) < MIN_HOME_SPACING:
                p.warn(("robots", i, "home"), f"robot {r.id}'s home is within "
                       f"{MIN_HOME_SPACING} m of robot {s.id}'s (robots[{j}])")


MIN_HEARTBEAT = 0.005
"""s. 200 heartbeats a second per robot: beyond what an 802.15.4 radio carries for even
two robots (~4 ms of airtime a frame at 250 kbit/s) and a busy loop for the CPU."""
ODD_HEARTBEAT = 0.02
"""s. Faster than 50 Hz works on loopback UDP but is odd for any radio: a warning."""
MAX_T_MAX = 600.0
"""s. A watchdog of more than ten minutes leaves a failed function unserved that long."""
ODD_T_MAX = 60.0
"""s. Detection beyond a minute is possible but odd for a flying swarm: a warning."""
MAX_SECONDS = 3600.0
"""s. Any other timing beyond an hour is a typo (units?), never a working swarm."""


def timing_bounds(params: Params) -> list[tuple[str, str, str]]:
    """(field, message, severity) for timings no radio or CPU can carry (errors) and
    for merely odd ones (warnings). Params itself only checks their relations."""
    out: list[tuple[str, str, str]] = []
    for name in ("heartbeat_interval", "standby_heartbeat_interval"):
        value = getattr(params, name)
        if value < MIN_HEARTBEAT:
            out.append((name, f"{name} {value:g} s is {1 / value:,.0f} frames/s per robot; "
                        f"no radio or CPU carries that (at least {MIN_HEARTBEAT:g} s)",
                        "error"))
        elif value < ODD_HEARTBEAT:
            out.append((name, f"{name} {value:g} s ({1 / value:.0f} Hz) is faster than any "
                        "radio medium swarmd speaks carries for a swarm; fine on loopback "
                        "only", "warning"))
    if params.t_max > MAX_T_MAX:
        out.append(("t_max", f"t_max {params.t_max:g} s: a failed robot would go unnoticed "
                    f"for that long (at most {MAX_T_MAX:g} s)", "error"))
    elif params.t_max > ODD_T_MAX:
        out.append(("t_max", f"t_max {params.t_max:g} s: a failure is detected only after "
                    "more than a minute", "warning"))
    for name, value in params.as_dict().items():
        if name not in ("quorum", "t_max") and value > MAX_SECONDS:
            out.append((name, f"{name} {value:g} s is beyond an hour (at most "
                        f"{MAX_SECONDS:g} s; seconds, not milliseconds?)", "error"))
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
