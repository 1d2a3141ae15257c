"""What the core asks its driver to do: frozen dataclasses, one class a kind.

The driver executes them in order after every call into the node (DESIGN section 2):
`Broadcast` goes on the channel, `Assign` / `Release` go to the robot (the paper's single
output: which task to perform, Fig. 4), an `Event` (one class a kind, `events.py`) goes
to the event log (DESIGN section 3).
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.core.events import Event


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


Action = Broadcast | Assign | Release | Event
