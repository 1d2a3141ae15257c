"""Fault specifications for `swarmd sim --fault SPEC` (DESIGN section 3).

This module is the one source of the fault kinds: `FaultKind` (whose values are the
SPEC's and the event log's words, `KINDS`), their forms (`_FORMS`) and what each does
(`WHAT`). `swarmd sim --help` prints `help_table()`; README.md,
docs/DESIGN.md and docs/sim.md hold `markdown_table()` between `<!-- fault-table -->`
markers, which `python scripts/fault_table.py` rewrites (tests/test_fault_table.py
fails when they differ). A new kind is one entry in each of the three, then that
command.

Every kind but partition and collide targets one robot or several at once
(`crash:1,2@T`: both at the same instant); `Fault.split()` gives one fault a robot,
which is what the simulators and the checker apply. Times are seconds since the run's
start.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from decimal import Decimal
from enum import StrEnum
from typing import Any

from swarmd.core import events


class FaultKind(StrEnum):
    """A fault's kind. Its value is the word a SPEC starts with and the event log's
    `fault{kind}` (a `str`: a kind compares equal to its word); the simulators and the
    checker dispatch on the members, so a misspelt kind fails where it is written."""

    CRASH = "crash"
    RESTART = "restart"
    PAUSE = "pause"
    PARTITION = "partition"
    FADE = "fade"
    DEAF = "deaf"
    LIAR = "liar"
    LEAVE = "leave"
    UNHEALTHY = "unhealthy"
    MOTOR = "motor"
    COLLIDE = "collide"
    FORGE = "forge"


KINDS: tuple[str, ...] = tuple(k.value for k in FaultKind)
"""The kinds' words, in the order `--help` and the docs list them."""
ATTACKS = ("epoch", "seq", "ahead", "claim", "warn", "replay")
"""What a `forge` fault sends (module docstring)."""
WIPED = "wiped"
"""What follows a restart's time when the robot comes back without its state file."""
_DURATION_KINDS = {FaultKind.PAUSE, FaultKind.PARTITION, FaultKind.FADE, FaultKind.DEAF}
LINK_KINDS = (FaultKind.PARTITION, FaultKind.FADE, FaultKind.DEAF)
"""Faults that lose frames on links rather than stop robots: the checker judges the
swarm's convergence after they heal (DESIGN, "Convergence")."""


class FaultSpecError(ValueError):
    """A --fault SPEC that cannot be parsed; the message shows the expected form."""


@dataclass(frozen=True, slots=True)
class Fault:
    kind: FaultKind
    at: float
    robots: tuple[int, ...] = ()
    """The target robots (one or several) — or, for a partition, every robot named."""
    duration: float | None = None
    groups: tuple[tuple[int, ...], ...] = ()
    """Partition groups; empty for other kinds. For `deaf`, one group: the senders the
    target robot does not hear."""
    oneway: bool = False
    """A one-way partition (`partition:1,2>3,4`): frames of the first group do not reach
    the second; the other way works."""
    attack: str = ""
    """For `forge`: one of `ATTACKS`."""
    wiped: bool = False
    """For `restart` (`restart:R@T:wiped`): the robot comes back without its state file,
    as at a first start (it knows nothing of the swarm's past, not even its own hold)."""
    origin: str | None = field(default=None, compare=False)
    """For one part of a fault on several robots (`split`): the SPEC the user gave."""

    def __post_init__(self) -> None:
        # A kind given by its word (`Fault("crash", ...)`) is the same fault; raises
        # ValueError for a word that is no kind.
        object.__setattr__(self, "kind", FaultKind(self.kind))

    @property
    def robot(self) -> int:
        """The single target of a one-robot fault (use `split()` for several)."""
        if self.kind is FaultKind.PARTITION:
            raise ValueError("a partition has groups, not one robot")
        if len(self.robots) != 1:
            raise ValueError(f"{self.spec()} targets several robots; use split()")
        return self.robots[0]

    def split(self) -> tuple[Fault, ...]:
        """One fault a target robot, same kind and times, each remembering this SPEC
        (`origin`) so that the log and the summary show what the user typed. A
        partition acts on all its robots together and stays whole."""
        if self.kind in (FaultKind.PARTITION, FaultKind.DEAF) \
                or (len(self.robots) == 1 and self.kind is not FaultKind.COLLIDE):
            return (self,)
        spec = self.spec()
        return tuple(replace(self, robots=(r,), origin=spec) for r in self.robots)

    @property
    def end(self) -> float | None:
        """When a pause or a link fault is over (None for the other kinds)."""
        return None if self.duration is None else self.at + self.duration

    def cut(self) -> tuple[frozenset[int] | None, frozenset[int] | None] | None:
        """A one-way link fault as (senders, receivers): while it lasts, frames from a
        sender in `senders` do not reach a receiver in `receivers` (None: every robot).
        None for the kinds that are no such cut (a two-way partition has groups)."""
        if self.kind is FaultKind.FADE:
            return frozenset(self.robots), None
        if self.kind is FaultKind.DEAF:
            return frozenset(self.groups[0]), frozenset(self.robots)
        if self.kind is FaultKind.PARTITION and self.oneway:
            return frozenset(self.groups[0]), frozenset(self.groups[1])
        return None

    def spec(self) -> str:
        """The SPEC text: `parse_fault(f.spec()) == f`."""
        if self.kind is FaultKind.PARTITION:
            groups = (">" if self.oneway else "|").join(",".join(map(str, g))
                                                        for g in self.groups)
            return f"partition:{groups}@{_num(self.at)}+{_num(self.duration or 0.0)}"
        if self.kind is FaultKind.DEAF:
            senders = ",".join(map(str, self.groups[0]))
            return f"deaf:{self.robots[0]}:{senders}@{_num(self.at)}+{_num(self.duration)}"
        tail = f"+{_num(self.duration)}" if self.duration is not None else ""
        if self.attack:
            tail += f":{self.attack}"
        if self.wiped:
            tail += f":{WIPED}"
        who = ",".join(map(str, self.robots))
        return f"{self.kind}:{who}@{_num(self.at)}{tail}"


def fault_record(fault: Fault, t: float) -> dict[str, Any]:
    """The `fault` event of an injected fault, one per fault, when it is applied (DESIGN
    section 3 `fault{kind}`; docs/sim.md): `robot` is the target, 0 for a partition;
    `spec` always, `duration` and `groups` when the fault has them. Both simulators log
    this, so a log reads the same whichever produced it. A fault on several robots is
    logged once a robot (`fault_records`), each record with the SPEC the user gave."""
    groups = [list(g) for g in fault.groups] or None
    record = events.Fault(fault.kind.value, fault.origin or fault.spec(), fault.duration,
                          groups)
    return record.record(round(t, 6), 0 if fault.kind is FaultKind.PARTITION else fault.robot)


def fault_records(fault: Fault, t: float) -> list[dict[str, Any]]:
    """The `fault` events of a fault, one per target robot (one for a partition)."""
    return [fault_record(part, t) for part in fault.split()]


def _num(x: float | None) -> str:
    """A time as `parse_fault` reads it back exactly: the shortest round-tripping
    decimal, never an exponent (`1e-05` would not parse)."""
    if x is None:
        return ""
    text = repr(float(x))
    if "e" in text or "E" in text:
        text = format(Decimal(text), "f")
    return text[:-2] if text.endswith(".0") else text


ROBOT_IDS = range(1, 0x10000)
"""Robot ids a swarm file accepts (docs/config.md: `robots[i].id` is 1..65535)."""

_SECONDS = re.compile(r"[0-9]+(?:\.[0-9]*)?|\.[0-9]+")
_ROBOT = re.compile(r"[0-9]+")

_FORMS = {
    "crash": "crash:R@T or crash:R1,R2@T",
    "restart": "restart:R@T or restart:R1,R2@T or restart:R@T:wiped",
    "pause": "pause:R@T+D or pause:R1,R2@T+D",
    "partition": "partition:1,2|3,4@T+D or partition:1,2>3,4@T+D",
    "fade": "fade:R@T+D or fade:R1,R2@T+D",
    "deaf": "deaf:R:S@T+D or deaf:R:S1,S2@T+D",
    "liar": "liar:R@T or liar:R1,R2@T",
    "leave": "leave:R@T or leave:R1,R2@T",
    "unhealthy": "unhealthy:R@T or unhealthy:R1,R2@T",
    "motor": "motor:R@T or motor:R1,R2@T",
    "collide": "collide:R1,R2@T",
    "forge": "forge:R@T:ATTACK (ATTACK: " + ", ".join(ATTACKS) + ")",
}

WHAT = {
    "crash": "robot R dies at T (real time: SIGKILL of its process)",
    "restart": "robot R comes back at T: a new process (node) on its persisted state, "
               "usually after a crash; with ':wiped', without its state file (a wiped "
               "or replaced companion computer), as at a first start",
    "pause": "robot R freezes at T for D seconds (SIGSTOP, then SIGCONT)",
    "partition": "the groups stop hearing each other from T for D seconds; robots named "
                 "nowhere stay in the first group; with '>' (partition:1,2>3,4) one way "
                 "only: 3 and 4 do not hear 1 and 2, who still hear them",
    "fade": "everything robot R sends is lost from T for D seconds; R still hears "
            "everyone (a fading transmitter)",
    "deaf": "robot R hears nothing from robot S from T for D seconds; S still hears R",
    "liar": "robot R sends false warnings about its neighbours from T",
    "leave": "robot R leaves gracefully at T (LEAVE, then stops)",
    "unhealthy": "robot R reports itself faulty at T (DESIGN rule 7: LEAVE, standby)",
    "motor": "a rotor of robot R fails at T (physics only: not with --virtual or "
             "--no-physics)",
    "collide": "R1 and R2 collide at T: with physics both crafts lose their motors and "
               "fall; in --virtual and --no-physics, two crashes at one instant",
    "forge": "an insider holding R's key sends forged frames from T; ATTACK is "
             + ", ".join(ATTACKS) + " (docs/sim.md)",
}
"""What each fault kind does, one sentence: `swarmd sim --help` and the docs' tables."""

_SEVERAL = ("R is a robot id, T the seconds from the start (before --duration), D how "
            "many seconds it lasts. Every kind but partition and collide also takes "
            "several robots at once: crash:1,2@T.")


def _short_form(kind: str) -> str:
    """The kind's SPEC in its shortest form (`crash:R@T`, `forge:R@T:ATTACK`)."""
    return _FORMS[kind].split(" or ")[0].split(" (")[0]


def help_table(width: int = 76) -> str:
    """The fault kinds as plain text lines of at most `width` columns: the SPEC, then
    what it does, wrapped under its own column (`swarmd sim --help`)."""
    import textwrap

    forms = {k: _short_form(k) for k in KINDS}
    indent = max(map(len, forms.values())) + 2
    lines = ["Fault kinds (--fault SPEC):"]
    for kind in KINDS:
        lines += textwrap.wrap(WHAT[kind], width, initial_indent=forms[kind].ljust(indent),
                               subsequent_indent=" " * indent, break_on_hyphens=False)
    lines += textwrap.wrap(_SEVERAL, width, break_on_hyphens=False)
    return "\n".join(lines)


def markdown_table() -> str:
    """The fault kinds as a Markdown table, with the same words as `help_table`."""
    rows = [f"| `{_short_form(k).replace('|', chr(92) + '|')}` | {WHAT[k]} |" for k in KINDS]
    return "\n".join(["| SPEC | what it does |", "|---|---|", *rows, "", _SEVERAL])


_Bad = Callable[[str], FaultSpecError]
"""Builds the error for one SPEC: `bad(what)` names what is wrong and the form."""


def parse_fault(spec: str) -> Fault:
    """Parse one SPEC. Raises FaultSpecError naming what is wrong and the expected form.

    Blanks around the parts are ignored (`crash : 2 @ 3`); blanks inside a number are
    not (`crash:2 3@3` is an error, never robot 23).
    """
    text = spec.strip()
    shown = _clip(spec)
    head, colon, rest = text.partition(":")
    kind = _kind_of(head.strip(), shown)
    form = _FORMS[kind]

    def bad(what: str) -> FaultSpecError:
        return FaultSpecError(f"fault {shown}: {what}; expected {form}")

    if not colon:
        raise bad("no ':' after the kind")
    who, at_sign, when = rest.partition("@")
    if not at_sign:
        raise bad("no '@T' (the time the fault starts)")
    when, attack = _split_attack(kind, when, bad)
    wiped = attack == WIPED
    attack = "" if wiped else attack
    senders: tuple[int, ...] = ()
    if kind is FaultKind.DEAF:
        target, colon3, heard = who.partition(":")
        if not colon3:
            raise bad("no ':S' (the robot(s) it does not hear)")
        who = target
        senders = tuple(_robot(r, bad) for r in heard.split(","))
    at, dur = _times(kind, when, bad)
    if kind is FaultKind.PARTITION:
        return _partition(who, at, dur, bad)
    fault = _targeted(kind, who, at, dur, senders, attack, bad)
    return replace(fault, wiped=True) if wiped else fault


def _kind_of(word: str, shown: str) -> FaultKind:
    """The kind a SPEC starts with, or an error suggesting the closest one."""
    if word not in KINDS:
        close = difflib.get_close_matches(word.lower()[:40], KINDS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise FaultSpecError(
            f"fault {shown}: unknown kind {_clip(word)}{hint}; kinds: {', '.join(KINDS)}"
        )
    return FaultKind(word)


def _split_attack(kind: FaultKind, when: str, bad: _Bad) -> tuple[str, str]:
    """The part after '@' without a forge's `:ATTACK` or a restart's `:wiped`, and
    that word ("" for the other kinds, which take no ':' after their time)."""
    attack = ""
    if kind is FaultKind.FORGE:
        when, colon2, attack = when.partition(":")
        attack = attack.strip()
        if not colon2 or attack not in ATTACKS:
            raise bad(f"unknown or missing attack {attack!r}")
    elif kind is FaultKind.RESTART and ":" in when:
        when, _, attack = when.partition(":")
        attack = attack.strip()
        if attack != WIPED:
            raise bad(f"a restart takes only ':{WIPED}' after its time, got {attack!r}")
    elif ":" in when:
        raise bad(f"a {kind} takes no ':' after its time")
    return when, attack


def _times(kind: FaultKind, when: str, bad: _Bad) -> tuple[float, float | None]:
    """`T` or `T+D`: the start and the duration, which only the kinds that last have."""
    at_text, plus, dur_text = when.partition("+")
    at = _seconds(at_text, "time T", bad)
    dur = _seconds(dur_text, "duration D", bad) if plus else None
    if kind in _DURATION_KINDS and dur is None:
        raise bad("missing '+D' (how long it lasts, in seconds)")
    if kind in _DURATION_KINDS and dur is not None and dur <= 0:
        raise bad(f"duration D must be positive, got {dur_text.strip()!r}")
    if kind not in _DURATION_KINDS and dur is not None:
        raise bad(f"a {kind} takes no duration '+{dur_text.strip()}'")
    return at, dur


def _targeted(kind: FaultKind, who: str, at: float, dur: float | None,
              senders: tuple[int, ...], attack: str, bad: _Bad) -> Fault:
    """A fault on one robot or several (every kind but partition)."""
    if "|" in who:
        raise bad(f"a {kind} has no groups, got {who.strip()!r}")
    robots = tuple(_robot(r, bad) for r in who.split(","))
    twice = sorted({r for r in robots if robots.count(r) > 1})
    if twice:
        raise bad(f"robot {twice[0]} is named twice")
    if kind is FaultKind.COLLIDE and len(robots) < 2:
        raise bad(f"a collision needs two or more robots, got {who.strip()!r}")
    if kind is FaultKind.DEAF:
        if len(robots) != 1:
            raise bad("a deaf fault names one robot that does not hear")
        if robots[0] in senders or len(set(senders)) != len(senders):
            raise bad("a robot hears itself; name each sender once")
        return Fault(kind, at, robots, dur, (senders,))
    return Fault(kind, at, robots, dur, attack=attack)


def _partition(who: str, at: float, dur: float | None, bad: _Bad) -> Fault:
    """A partition: two or more groups split by '|', or two by '>' (one way)."""
    oneway = ">" in who
    if oneway and "|" in who:
        raise bad("a partition is two-way ('|') or one-way ('>'), not both")
    groups = tuple(tuple(_robot(r, bad) for r in g.split(","))
                   for g in who.split(">" if oneway else "|"))
    if oneway and len(groups) != 2:
        raise bad("a one-way partition has two groups: senders>receivers")
    if len(groups) < 2:
        raise bad("a partition needs two or more groups separated by '|'")
    named = [r for g in groups for r in g]
    twice = sorted({r for r in named if named.count(r) > 1})
    if twice:
        raise bad(f"robot {twice[0]} is named twice")
    return Fault(FaultKind.PARTITION, at, tuple(named), dur, groups, oneway=oneway)


_MAX_NUMBER_CHARS = 32
"""A robot id longer than this is a mistake; refusing it early also keeps a number of
thousands of digits away from `int()` (a ValueError beyond 4300 digits). Times go
through `float()`, which has no such limit (a huge one is `inf`: "too large")."""


def _clip(text: str, width: int = 60) -> str:
    """`repr(text)`, shortened so that a message stays one readable line."""
    shown = repr(text)
    return shown if len(shown) <= width else f"{shown[:width - 5]}...{shown[-2:]}"


def _seconds(text: str, what: str, bad: Callable[[str], FaultSpecError]) -> float:
    """A non-negative decimal number of seconds (`3`, `2.5`, `.5`, `3.`)."""
    t = text.strip()
    if not t:
        raise bad(f"{what} is missing")
    if t.startswith("-"):
        raise bad(f"{what} must not be negative, got {_clip(t)}")
    if not _SECONDS.fullmatch(t):
        raise bad(f"{what} must be a number of seconds like 3 or 2.5, got {_clip(t)}")
    value = float(t)
    if not math.isfinite(value):
        raise bad(f"{what} {_clip(t)} is too large")
    return value


def _robot(text: str, bad: Callable[[str], FaultSpecError]) -> int:
    """One robot id (1..65535), as a swarm file allows."""
    t = text.strip()
    if not t:
        raise bad("a robot id is missing")
    if len(t) > _MAX_NUMBER_CHARS:
        raise bad(f"{_clip(t)} is not a robot id (1..65535)")
    if not _ROBOT.fullmatch(t):
        raise bad(f"{t!r} is not a robot id (1..65535)")
    rid = int(t)
    if rid not in ROBOT_IDS:
        raise bad(f"robot id {rid} is out of range 1..65535")
    return rid


def check_faults(faults: list[Fault], robot_ids: set[int], *, physics: bool,
                 duration: float | None = None) -> list[str]:
    """Problems with a fault list against a swarm: unknown robots, a motor fault
    without a flying craft (`physics` is False for --virtual and --no-physics: a motor
    needs rotors), and (given the run's `duration`) a fault that would start after the
    end."""
    problems = []
    for f in faults:
        unknown = [r for r in f.robots if r not in robot_ids]
        if unknown:
            problems.append(f"{f.spec()}: robot {unknown[0]} is not in the swarm "
                            f"(robots: {_ranges(robot_ids)})")
        if f.kind is FaultKind.MOTOR and not physics:
            problems.append(f"{f.spec()}: motor faults need physics (not with --virtual "
                            f"or --no-physics); unhealthy:{','.join(map(str, f.robots))}"
                            f"@{_num(f.at)} is what a failed motor does to the protocol")
        if duration is not None and f.at >= duration:
            problems.append(f"{f.spec()}: starts at {_num(f.at)} s, not before the end of the "
                            f"run (--duration {_num(duration)})")
    return problems


def _ranges(ids: set[int]) -> str:
    """`1-4, 10, 20-22`: a swarm's robot ids, short enough for a message."""
    out: list[tuple[int, int]] = []
    for r in sorted(ids):
        if out and out[-1][1] == r - 1:
            out[-1] = (out[-1][0], r)
        else:
            out.append((r, r))
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in out)
