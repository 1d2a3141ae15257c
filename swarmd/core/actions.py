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


@dataclass(frozen=True, slots=True)
class Event:
    """One event-log record: `name` and its fields as DESIGN section 3 lists them."""

    name: str
    fields: Mapping[str, Any] = field(default_factory=dict)

    def record(self, t: float, robot: int) -> dict[str, Any]:
        """The JSON Lines object: {"t", "robot", "event", ...fields}."""
        return {"t": t, "robot": robot, "event": self.name, **self.fields}


Action = Broadcast | Assign | Release | Event
