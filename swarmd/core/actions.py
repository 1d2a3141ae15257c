"""What the core asks its driver to do: frozen dataclasses, one class a kind.

The runtime executes them in order after every call into the node (STYLE.md point 8):
`Broadcast` goes on the channel, `Assign` / `Release` go to the robot (the paper's single
output: which task to perform, Fig. 4), `Event` goes to the event log (DESIGN section 3).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True, slots=True)
class Broadcast:
    frame: bytes


@dataclass(frozen=True, slots=True)
class Assign:
    """Start executing `function`; `epoch` fences older holders (DESIGN rule 2)."""

    function: str
    epoch: int


@dataclass(frozen=True, slots=True)
class Release:
    """Stop executing `function` at once."""

    function: str


EVENT_FIELDS: Mapping[str, tuple[str, ...]] = {
    "started": ("role", "function"),
    "suspect": ("subject", "function"),
    "warn": ("subject", "function"),
    "vote": ("subject", "function", "from", "count"),
    "claim": ("subject", "function", "epoch"),
    "backoff": ("subject", "function", "winner"),
    "takeover": ("function", "epoch", "replaced"),
    "fenced": ("function", "epoch"),
    "refute": (),
    "leave": ("function", "reason"),
    "alert": ("function", "reason"),
    "fault": ("kind",),
    "stopped": (),
}
"""The event log's names and the fields each one always carries (DESIGN section 3, an
outside contract: clients parse it). A record may carry more fields (`refute` names its
subject and function), never fewer, and no other name goes into the log: a channel's
condition (radio up/down, send errors) goes to the daemon's own log and counters.
`fault` is written by `swarmd sim` only."""


@dataclass(frozen=True, slots=True)
class Event:
    """One event-log record: `name` and its fields as DESIGN section 3 lists them."""

    name: str
    fields: Mapping[str, Any] = field(default_factory=dict)

    def record(self, t: float, robot: int) -> dict[str, Any]:
        """The JSON Lines object: {"t", "robot", "event", ...fields}."""
        return {"t": t, "robot": robot, "event": self.name, **self.fields}


Action = Broadcast | Assign | Release | Event
