"""What the virtual simulator's clock has queued: one typed entry per kind of happening,
and what a robot's node is handed: one typed input per node entry point.

`VirtualSwarm` keeps a heap of `(t, n, entry)`: `n` is a counter, so entries at one
instant run in the order they were queued (a run stays a pure function of its seed),
and the entry never needs comparing. A `Tick`, `Deliver` or `DeliverRaw` popped off it
goes to the node as it is; `Stop`, `Report` and `Say` come from faults.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.core import wire
from swarmd.core.roles import Health


@dataclass(frozen=True, slots=True)
class Tick:
    """Robot `robot`'s node asked to be woken now; `gen` tells a stale timer (re-armed
    since) from the current one."""

    robot: int
    gen: int


@dataclass(frozen=True, slots=True)
class Deliver:
    """A frame reaches `robot` (decoded once by the simulator, as its sender made it)."""

    robot: int
    frame: wire.Frame


@dataclass(frozen=True, slots=True)
class DeliverRaw:
    """Raw bytes reach `robot`'s node undecoded: a forger's frames, which decoding and
    verifying are there to refuse."""

    robot: int
    data: bytes


@dataclass(frozen=True, slots=True)
class Boot:
    """Robot `robot` starts (at a time spread over the first moments of the run)."""

    robot: int


@dataclass(frozen=True, slots=True)
class FaultPhase:
    """Injected fault number `index` begins or ends (`phase`: "begin" or "end")."""

    index: int
    phase: str


@dataclass(frozen=True, slots=True)
class Lie:
    """The liar `robot` sends its false warnings of this warn interval."""

    robot: int


@dataclass(frozen=True, slots=True)
class Forge:
    """The forger `robot` sends round `round` of its `attack`."""

    robot: int
    attack: str
    round: int


@dataclass(frozen=True, slots=True)
class Stop:
    """Robot `robot` stops gracefully, handing its function over (`leave:R@T`)."""

    robot: int


@dataclass(frozen=True, slots=True)
class Report:
    """Robot `robot` reports its `health` to its node (`unhealthy:R@T`, `motor:R@T`)."""

    robot: int
    health: Health


@dataclass(frozen=True, slots=True)
class Say:
    """Robot `robot`'s node broadcasts `msg` as its own (the liar's false warnings)."""

    robot: int
    msg: wire.Message


Entry = Tick | Deliver | DeliverRaw | Boot | FaultPhase | Lie | Forge
"""What the heap holds."""
Input = Tick | Deliver | DeliverRaw | Stop | Report | Say
"""What `VirtualSwarm` hands a node: each kind is one of its entry points."""

__all__ = ["Boot", "Deliver", "DeliverRaw", "Entry", "FaultPhase", "Forge", "Input", "Lie",
           "Report", "Say", "Stop", "Tick"]
