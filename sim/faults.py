"""Fault specifications for `swarmd sim --fault SPEC` (DESIGN section 3).

    crash:R@T            robot R dies at T (real time: SIGKILL)
    restart:R@T          robot R comes back at T (a new process / node with its
                         persisted state); usually after a crash
    pause:R@T+D          robot R freezes at T for D seconds (SIGSTOP / SIGCONT)
    partition:1,2|3,4@T+D  groups stop hearing each other from T for D seconds;
                         robots not named stay in the first group
    liar:R@T             robot R sends false warnings about its neighbours from T
    leave:R@T            robot R leaves gracefully at T (LEAVE, then stops)
    unhealthy:R@T        robot R reports itself faulty at T (DESIGN rule 7)
    motor:R@T            a rotor of robot R fails at T (physics only)

Times are seconds since the run's start.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

KINDS = ("crash", "restart", "pause", "partition", "liar", "leave", "unhealthy", "motor")
_DURATION_KINDS = {"pause", "partition"}


class FaultSpecError(ValueError):
    """A --fault SPEC that cannot be parsed; the message shows the expected form."""


@dataclass(frozen=True, slots=True)
class Fault:
    kind: str
    at: float
    robots: tuple[int, ...] = ()
    """The target robot (one) — or, for a partition, every robot named."""
    duration: float | None = None
    groups: tuple[tuple[int, ...], ...] = ()
    """Partition groups; empty for other kinds."""

    @property
    def robot(self) -> int:
        """The single target of a non-partition fault."""
        if self.kind == "partition":
            raise ValueError("a partition has groups, not one robot")
        return self.robots[0]

    @property
    def end(self) -> float | None:
        return None if self.duration is None else self.at + self.duration

    def spec(self) -> str:
        if self.kind == "partition":
            groups = "|".join(",".join(map(str, g)) for g in self.groups)
            return f"partition:{groups}@{_num(self.at)}+{_num(self.duration or 0.0)}"
        tail = f"+{_num(self.duration)}" if self.duration is not None else ""
        return f"{self.kind}:{self.robot}@{_num(self.at)}{tail}"


def _num(x: float | None) -> str:
    return f"{x:g}" if x is not None else ""


_SPEC = re.compile(
    r"^(?P<kind>[a-z]+):(?P<who>[0-9,| ]+)@(?P<at>[0-9]*\.?[0-9]+)(?:\+(?P<dur>[0-9]*\.?[0-9]+))?$"
)

_FORMS = {
    "crash": "crash:R@T",
    "restart": "restart:R@T",
    "pause": "pause:R@T+D",
    "partition": "partition:1,2|3,4@T+D",
    "liar": "liar:R@T",
    "leave": "leave:R@T",
    "unhealthy": "unhealthy:R@T",
    "motor": "motor:R@T",
}


def parse_fault(spec: str) -> Fault:
    """Parse one SPEC. Raises FaultSpecError naming the expected form."""
    text = spec.strip()
    kind = text.split(":", 1)[0]
    if kind not in KINDS:
        raise FaultSpecError(
            f"unknown fault kind {kind!r} in {spec!r}; kinds: {', '.join(KINDS)}"
        )
    form = _FORMS[kind]
    m = _SPEC.match(text.replace(" ", ""))
    if not m:
        raise FaultSpecError(f"cannot parse fault {spec!r}; expected {form}")
    at = float(m["at"])
    dur = float(m["dur"]) if m["dur"] is not None else None
    if kind in _DURATION_KINDS and (dur is None or dur <= 0):
        raise FaultSpecError(f"fault {spec!r} needs a positive duration: {form}")
    if kind not in _DURATION_KINDS and dur is not None:
        raise FaultSpecError(f"fault {spec!r} takes no duration: {form}")
    who = m["who"]
    try:
        if kind == "partition":
            groups = tuple(
                tuple(int(r) for r in g.split(",") if r) for g in who.split("|")
            )
            if len(groups) < 2 or any(not g for g in groups):
                raise FaultSpecError(f"partition {spec!r} needs two or more groups: {form}")
            named = [r for g in groups for r in g]
            if len(set(named)) != len(named):
                raise FaultSpecError(f"partition {spec!r} names a robot twice")
            return Fault(kind, at, tuple(named), dur, groups)
        if "," in who or "|" in who:
            raise FaultSpecError(f"fault {spec!r} targets one robot: {form}")
        return Fault(kind, at, (int(who),), dur)
    except ValueError as exc:
        if isinstance(exc, FaultSpecError):
            raise
        raise FaultSpecError(f"bad robot id in {spec!r}: {form}") from None


def check_faults(faults: list[Fault], robot_ids: set[int], *, physics: bool) -> list[str]:
    """Problems with a fault list against a swarm: unknown robots, motor without physics."""
    problems = []
    for f in faults:
        unknown = [r for r in f.robots if r not in robot_ids]
        if unknown:
            problems.append(f"{f.spec()}: robot {unknown[0]} is not in the swarm")
        if f.kind == "motor" and not physics:
            problems.append(f"{f.spec()}: motor faults need physics (drop --no-physics/--virtual)")
    return problems
