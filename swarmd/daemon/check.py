"""`swarmd check`: validate a swarm (or robot) file and report what it will do.

The report is a list of sections, each built from a validated `SwarmConfig` by a
function in `SECTIONS`. A new concern (the channel budget of `swarmd/services/budget.py`) is
one more builder appended there; rendering as rich tables and as JSON is shared.

Exit codes (DESIGN.md section 3, `swarmd check`): 0 when usable (warnings allowed),
1 on any error, 2 when the file cannot be read.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.table import Table
from rich.text import Text

from swarmd.config.errors import ConfigError, ConfigUnreadable, Problem, has_errors
from swarmd.config.robot import from_source as robot_from_source
from swarmd.config.source import read_source
from swarmd.config.swarm import Coverage, SwarmConfig
from swarmd.config.swarm_rules import inspect_swarm
from swarmd.core.params import UNITLESS, Params, ParamsError

if TYPE_CHECKING:
    from swarmd.services.budget import Budget  # budget_section imports it only when it runs

EXIT_OK = 0
"""Usable: no errors, warnings allowed (docs/config.md, `swarmd check`)."""
EXIT_ERRORS = 1
"""Errors: every one is printed."""
EXIT_UNREADABLE = 2
"""The file cannot be read."""


@dataclass(frozen=True)
class Section:
    """One part of the report: a table for people and `data` for `--json`."""

    key: str
    """Key of `data` in the JSON report."""
    title: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    data: Any
    """JSON-serialisable form of the same content."""
    notes: tuple[str, ...] = ()
    """Lines printed under the table."""
    warnings: tuple[str, ...] = ()
    """Lines printed under the table that are warnings (a radio the swarm would
    overload, a function a simulated craft cannot fly): counted in the last line."""


SectionBuilder = Callable[[SwarmConfig], Section | None]


@dataclass
class CheckReport:
    file: str
    problems: list[Problem] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)
    unreadable: bool = False

    @property
    def warnings(self) -> int:
        """Warnings found: the problems that are not errors, and the sections'."""
        return sum(p.severity != "error" for p in self.problems) + sum(
            len(s.warnings) for s in self.sections)

    @property
    def exit_code(self) -> int:
        if self.unreadable:
            return EXIT_UNREADABLE
        return EXIT_ERRORS if has_errors(self.problems) else EXIT_OK

    def as_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "file": self.file,
            "ok": self.exit_code == EXIT_OK,
            "problems": [p.as_json() for p in self.problems],
            "warnings": self.warnings,
        }
        for s in self.sections:
            out[s.key] = s.data
        return out


# -- sections -----------------------------------------------------------------------------


def _params(cfg: SwarmConfig) -> Params | None:
    try:
        return cfg.params()
    except (ParamsError, TypeError):
        return None  # already reported as a problem of the timing field


def coverage_section(cfg: SwarmConfig) -> Section:
    """Function -> holder, watchers (rule 3 witnesses), covering standbys (rule 6)."""
    params = _params(cfg)
    quorum = params.quorum if params is not None else None
    rows: list[tuple[str, ...]] = []
    data: list[dict[str, Any]] = []
    for c in cfg.coverage():
        text = _coverage_status(c, quorum)
        rows.append((
            c.function,
            c.kind,
            ", ".join(map(str, c.holders)) or "-",
            ", ".join(map(str, c.watchers)) or "-",
            ", ".join(map(str, c.standbys)) or "-",
            text,
        ))
        data.append({
            "function": c.function,
            "kind": c.kind,
            "holder": c.holders[0] if c.holders else None,
            "watchers": list(c.watchers),
            "standbys": list(c.standbys),
            "status": text,
        })
    q = f"quorum {quorum}" if quorum is not None else "quorum unknown (timing invalid)"
    return Section(
        key="coverage",
        title=f"Coverage ({len(cfg.functions)} functions, {len(cfg.robots)} robots, {q})",
        columns=("function", "kind", "holder", "watchers", "standbys", "status"),
        rows=tuple(rows),
        data=data,
    )


def _coverage_status(c: Coverage, quorum: int | None) -> str:
    """A function's coverage status: OK, or what is wrong with it."""
    status = []
    if not c.holders:
        status.append("NO HOLDER")
    elif len(c.holders) > 1:
        status.append("TWO HOLDERS")
    if quorum is not None and c.holders and len(c.watchers) < quorum:
        status.append("UNDER QUORUM")
    if not c.standbys:
        status.append("NO STANDBY")
    return ", ".join(status) or "OK"


def timing_section(cfg: SwarmConfig) -> Section | None:
    """The Params in use and the takeover bound that follows from them."""
    params = _params(cfg)
    if params is None:
        return None
    overrides = cfg.timing.overrides()
    rows = tuple(
        (name, f"{value:g}" + ("" if name in UNITLESS else " s"),
         "file" if name in overrides else cfg.timing.preset)
        for name, value in params.as_dict().items()
    )
    bound = params.takeover_bound()
    bursty = params.takeover_bound(lossy=True)
    return Section(
        key="timing",
        title=f"Timing (preset {cfg.timing.preset})",
        columns=("parameter", "value", "from"),
        rows=rows,
        data={
            "preset": cfg.timing.preset,
            "params": params.as_dict(),
            "overrides": sorted(overrides),
            "takeover_bound_s": round(bound, 6),
            "takeover_bound_bursty_s": round(bursty, 6),
        },
        notes=(
            f"takeover bound (no loss): t_max + vote_window + claim_hold = {bound:g} s",
            f"on a link that loses heartbeats in bursts: t_max_bursty + 3 vote_window + "
            f"claim_hold = {bursty:g} s (DESIGN, Detection)",
        ),
    )


def budget_section(cfg: SwarmConfig) -> Section | None:
    """Channel budget on every medium swarmd speaks: frames and
    bytes per second on the air, airtime at 250 kbps, whether a heartbeat fits."""
    from swarmd.services.budget import MEDIA, channel_budget

    params = _params(cfg)
    if params is None:
        return None
    try:
        plan = cfg.to_plan()
    except ConfigError:
        return None
    # The swarm key's tag: shared mode, or per robot with a key_file beside the robot keys.
    signed = cfg.auth_mode == "shared" or (cfg.auth_mode == "per-robot"
                                           and cfg.key_path is not None)
    rows = []
    data = []
    notes: list[str] = []
    warnings: list[str] = []
    for medium in MEDIA:
        b = channel_budget(plan, params, medium=medium, signed=signed,
                           per_robot=cfg.auth_mode == "per-robot")
        rows.append(_budget_row(medium, b))
        data.append(b.as_dict())
        warnings += [f"{medium}: {w}" for w in b.warnings]
        if b.warn_fragments > 1 or b.cert_fragments > 1 or b.anchor_fragments > 1:
            notes.append(_fragments_note(medium, b))
    return Section(
        key="channel_budget",
        title=f"Channel budget ({'signed' if signed else 'unsigned'} frames)",
        columns=("medium", "frames/s", "bytes/s", "airtime", "airtime in failover",
                 "heartbeat"),
        rows=tuple(rows),
        data=data,
        notes=tuple(notes),
        warnings=tuple(warnings),
    )


def _budget_row(medium: str, b: Budget) -> tuple[str, ...]:
    """One medium's line of the channel budget table."""
    return (
        medium,
        f"{b.frames_per_s:.1f}",
        f"{b.bytes_per_s:.0f}",
        "-" if b.airtime_share is None else f"{b.airtime_share:.1%}",
        "-" if b.peak_airtime_share is None else f"{b.peak_airtime_share:.1%}",
        f"{b.heartbeat_bytes}/{b.max_payload} B " + ("fits" if b.heartbeat_fits else
                                                    "DOES NOT FIT"),
    )


def _fragments_note(medium: str, b: Budget) -> str:
    """Which messages a medium carries in several fragments."""
    split = [f"{what} ({size} B) in {n}" for what, size, n in (
        ("warning/claim", b.warn_bytes, b.warn_fragments),
        ("certificate", b.cert_bytes, b.cert_fragments),
        ("heartbeat anchor", b.anchor_bytes, b.anchor_fragments)) if n > 1]
    return (f"{medium}: {', '.join(split)} fragments of <= {b.max_payload} B "
            "(transport/fragment.py; counted in the airtime)")


def auth_section(cfg: SwarmConfig) -> Section:
    """How frames are signed (config/auth.py): the mode, where the keys are, who is
    revoked. An unsigned swarm is also a warning among the problems."""
    mode = cfg.auth_mode
    keys_dir = cfg.keys_dir_path
    key = cfg.key_path
    data: dict[str, Any] = {
        "mode": mode, "explicit": cfg.auth_explicit,
        "keys_dir": str(keys_dir) if keys_dir is not None else None,
        "key_file": str(key) if key is not None else None,
        "revoked": sorted(cfg.revoked)}
    if mode == "per-robot":
        line = f"auth: per-robot (Ed25519), public keys in {keys_dir}"
        if keys_dir is not None and not keys_dir.exists():
            line += (f" (not made yet: swarmd keygen --swarm {cfg.source} {keys_dir}; "
                     "swarmd sim makes throwaway keys)")
        if cfg.revoked:
            line += f", revoked: {', '.join(map(str, sorted(cfg.revoked)))}"
        if key is not None:
            line += f", swarm key {key}"
    elif mode == "shared":
        line = (f"auth: shared key {key} (any robot holding it can sign as any other; "
                "docs/operations.md)")
    else:
        line = ("auth: none, frames UNSIGNED: anyone who can send on the channel can speak "
                "for any robot and take over any function")
        line += (" (chosen: auth: none)" if cfg.auth_explicit else
                 " (not said: swarmd start refuses it)")
    return Section(key="auth", title="", columns=(), rows=(), data=data, notes=(line,))


def flight_section(cfg: SwarmConfig) -> Section | None:
    """What the simulator's quadrotors make of each function: `swarmd sim`
    with physics refuses a swarm whose functions a craft cannot fly (a waypoint under
    the ground, a slot at ground level); said here first, as notes, since real robots
    interpret their functions themselves."""
    try:
        from swarmd.base.functions import flight_problems
    except ImportError:  # a robot's install without the simulator
        return None
    problems = {name: flight_problems({name: cfg.function_spec(name)})
                for name in cfg.functions}
    refused = tuple(f"swarmd sim (physics) will refuse: {p}"
                    for bad in problems.values() for p in bad)
    # No table: the coverage table already lists the functions; only problems print.
    return Section(key="flight", title="", columns=(), rows=(), data=problems,
                   warnings=refused)


SECTIONS: list[SectionBuilder] = [coverage_section, timing_section, auth_section,
                                  budget_section, flight_section]
"""Report sections in order; append a builder to add one (e.g. the channel budget)."""


# -- running ------------------------------------------------------------------------------


def run_check(path: str | Path) -> CheckReport:
    """Validate `path` (a swarm file, or a robot file: then its swarm is reported)."""
    report = CheckReport(file=str(path))
    try:
        source = read_source(path)
    except ConfigUnreadable as exc:
        report.problems = list(exc.problems)
        report.unreadable = True
        return report
    except ConfigError as exc:  # YAML syntax
        report.problems = list(exc.problems)
        return report
    cfg: SwarmConfig | None
    data = source.data
    if isinstance(data, dict) and "robot" in data and "robots" not in data:
        try:
            robot = robot_from_source(source)
        except ConfigError as exc:
            report.problems = list(exc.problems)
            return report
        cfg = robot.swarm
        report.problems = list(robot.warnings)
    else:
        cfg, report.problems = inspect_swarm(source)
    if cfg is not None:
        for build in SECTIONS:
            section = build(cfg)
            if section is not None:
                report.sections.append(section)
    return report


def render(report: CheckReport, console: Console) -> None:
    """Print the report for people: problems, then each section's table."""
    for p in report.problems:
        style = "red" if p.severity == "error" else "yellow"
        console.print(Text(str(p), style=style), soft_wrap=True)
    for s in report.sections:
        if s.columns:  # a section may be notes alone
            table = Table(title=s.title, title_justify="left")
            for col in s.columns:
                table.add_column(col)
            for row in s.rows:
                table.add_row(*(Text(cell) for cell in row))
            console.print(table)
        for note in s.notes:
            console.print(Text(note), soft_wrap=True)
        for warning in s.warnings:
            console.print(Text(warning, style="yellow"), soft_wrap=True)
    console.print(verdict(report), soft_wrap=True)


def verdict(report: CheckReport) -> Text:
    """The last line: what was found, in the words of the exit code (0 usable, warnings
    allowed; 1 errors; 2 unreadable). "OK" only when nothing at all was found."""
    errors = sum(p.severity == "error" for p in report.problems)
    warnings = report.warnings
    code = report.exit_code
    if code == EXIT_UNREADABLE:
        return Text(f"{report.file}: cannot be read (exit {code})", style="red")
    if code != EXIT_OK:
        return Text(f"{report.file}: NOT usable: {errors} error(s), {warnings} warning(s) "
                    f"(exit {code})", style="red")
    if warnings:
        return Text(f"{report.file}: usable, with {warnings} warning(s) above (exit {code})",
                    style="yellow")
    return Text(f"{report.file}: OK, no errors or warnings (exit {code})", style="green")
