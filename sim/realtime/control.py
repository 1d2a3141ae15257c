"""The real-time control pipe between the orchestrator and its robot processes, typed,
with its one codec.

Each robot process has two one-way pipes (multiprocessing `Connection`s):
- control, orchestrator -> robot, a `Command`: `Go` (the run's origin: start the clock),
  `Act` (a fault the robot acts out itself: leave, unhealthy, liar, motor), `Forge` (an
  attack under this robot's key, `sim.shared.forge`);
- reports, robot -> orchestrator, a `Report`: `Ready`, `Failed` (could not start, and
  why), `Drops` (its counted drops), `Late` (event-loop lateness samples), `Stats` (its
  filter's and forger's counts, at exit), and `Logged`: one event-log record, as the
  daemon wrote it (DESIGN section 3).

One message is one JSON object, written in one `send_bytes`: below PIPE_BUF a pipe write
is atomic, so a SIGKILLed robot never leaves half a message. `encode` writes any message;
`decode_command` / `decode_report` read them back and raise `ControlError` (a
`ValueError`) on anything that is no message of their direction, so a reader has one
`except` and one line to print.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sim.shared.faults import FaultKind

_CMD = "cmd"
"""The key naming a command."""
_CTL = "_ctl"
"""The key naming a report other than an event-log record (no event record has it)."""

ACTS = frozenset({FaultKind.LEAVE, FaultKind.UNHEALTHY, FaultKind.LIAR, FaultKind.MOTOR})
"""Faults a robot process acts out when told (`Act.kind`)."""


class ControlError(ValueError):
    """Bytes on a control pipe that are no message of that direction."""


# -- orchestrator -> robot -------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Go:
    """Start: `t0` is the run's origin (Unix time, s)."""

    t0: float


@dataclass(frozen=True, slots=True)
class Act:
    """Act out the fault `kind` (one of `ACTS`)."""

    kind: FaultKind


@dataclass(frozen=True, slots=True)
class Forge:
    """Forge frames in this robot's name: `attack` is one of `sim.shared.faults.ATTACKS`."""

    attack: str


Command = Go | Act | Forge


# -- robot -> orchestrator -------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Ready:
    """The daemon runs; `pid` is the robot process's."""

    pid: int


@dataclass(frozen=True, slots=True)
class Failed:
    """The robot could not start or run: `error` says why (`Type: message`)."""

    error: str


@dataclass(frozen=True, slots=True)
class Drops:
    """The robot's counted drops by reason, as of now (they only grow)."""

    counts: dict[str, int]


@dataclass(frozen=True, slots=True)
class Late:
    """`wakes` event-loop wake-ups, of which `samples` (run time s, ms late) were late."""

    wakes: int
    samples: list[tuple[float, float]]


@dataclass(frozen=True, slots=True)
class Stats:
    """The robot's receive filter's and forger's counts, sent once at exit."""

    passed: int
    lost: int
    partitioned: int
    forged: int


@dataclass(frozen=True, slots=True)
class Logged:
    """One event-log record as the daemon wrote it (`Event.record`)."""

    record: dict[str, Any]


Report = Ready | Failed | Drops | Late | Stats | Logged


# -- the codec -------------------------------------------------------------------------------

def _to_json(msg: Command | Report) -> dict[str, Any]:
    match msg:
        case Go(t0):
            return {_CMD: "go", "t0": t0}
        case Act(kind):
            return {_CMD: str(kind)}
        case Forge(attack):
            return {_CMD: "forge", "attack": attack}
        case Ready(pid):
            return {_CTL: "ready", "pid": pid}
        case Failed(error):
            return {_CTL: "error", "error": error}
        case Drops(counts):
            return {_CTL: "drops", "d": counts}
        case Late(wakes, samples):
            return {_CTL: "late", "n": wakes, "s": [list(s) for s in samples]}
        case Stats(passed, lost, partitioned, forged):
            return {_CTL: "stats", "passed": passed, "lost": lost,
                    "partitioned": partitioned, "forged": forged}
        case Logged(record):
            return record


def encode(msg: Command | Report) -> bytes:
    """One message as the bytes of one pipe write."""
    return json.dumps(_to_json(msg), separators=(",", ":")).encode()


def _object(data: bytes) -> dict[str, Any]:
    try:
        doc = json.loads(data)
    except ValueError as exc:  # UnicodeDecodeError is one too
        raise ControlError(f"not JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ControlError(f"not a JSON object: {type(doc).__name__}")
    return doc


def decode_command(data: bytes) -> Command:
    """A command read off the control pipe. Raises `ControlError`."""
    doc = _object(data)
    cmd = doc.get(_CMD)
    try:
        if cmd == "go":
            return Go(float(doc["t0"]))
        if cmd == "forge":
            return Forge(str(doc["attack"]))
        if isinstance(cmd, str) and cmd in ACTS:
            return Act(FaultKind(cmd))
    except (KeyError, TypeError, ValueError) as exc:
        raise ControlError(f"command {cmd!r} without a valid {exc}") from None
    raise ControlError(f"unknown command {cmd!r}")


def decode_report(data: bytes) -> Report:
    """A report read off a robot's pipe. Raises `ControlError`."""
    doc = _object(data)
    ctl = doc.get(_CTL)
    try:
        match ctl:
            case None:
                return Logged(doc)
            case "ready":
                return Ready(int(doc["pid"]))
            case "error":
                return Failed(str(doc["error"]))
            case "drops":
                return Drops({str(k): int(v) for k, v in _mapping(doc["d"]).items()})
            case "late":
                return Late(int(doc["n"]), [(float(t), float(ms)) for t, ms in doc["s"]])
            case "stats":
                return Stats(int(doc["passed"]), int(doc["lost"]), int(doc["partitioned"]),
                             int(doc["forged"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ControlError(f"report {ctl!r} without a valid {exc}") from None
    raise ControlError(f"unknown report {ctl!r}")


def _mapping(value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise TypeError(f"mapping, got {type(value).__name__}")
    return value


__all__ = [
    "ACTS", "Act", "Command", "ControlError", "Drops", "Failed", "Forge", "Go", "Late",
    "Logged", "Ready", "Report", "Stats", "decode_command", "decode_report", "encode",
]
