"""What a robot is doing, as one value per role with the data that role needs (paper
Fig. 5 with the wait state; the transitions are `roles.TRANSITIONS`).

A node holds exactly one of these. A field exists only in the role that has it: a
standby has no function, a claimant has its wait state (`claims.WaitState`), a holder
its function, epoch and watchdogs, a fenced robot the end of its fence hold, a
rejoining robot its rejoin hold (`rejoin.Rejoin`). Changing role replaces the value
(`NodeBase._to`), so no field is ever left behind by a role that ended: nothing is
kept in step by hand.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import ClassVar

from swarmd.core.claims import WaitState
from swarmd.core.rejoin import Rejoin
from swarmd.core.roles import Role
from swarmd.core.watchdog import SlotWatch


@dataclass(slots=True)
class Active:
    """Executes `function` at `epoch` and watches the slots it watches (Fig. 7)."""

    function: str
    epoch: int
    watches: dict[str, SlotWatch] = field(default_factory=dict)
    role: ClassVar[Role] = Role.ACTIVE


@dataclass(slots=True)
class Standby:
    """The paper's *inactive*: heartbeats slowly, counts warnings (Fig. 9)."""

    role: ClassVar[Role] = Role.STANDBY


@dataclass(slots=True)
class Claiming:
    """The paper's *wait*: claims a slot and holds (`WaitState`)."""

    wait: WaitState
    role: ClassVar[Role] = Role.CLAIMING


@dataclass(slots=True)
class Fenced:
    """Stopped its function on a greater entry (rule 2); a standby again at `until`."""

    until: float
    role: ClassVar[Role] = Role.FENCED


@dataclass(slots=True)
class Rejoining:
    """A restarted holder listening before it resumes its slot (rule 2 across a reboot)."""

    rejoin: Rejoin
    role: ClassVar[Role] = Role.REJOINING


RoleState = Active | Standby | Claiming | Fenced | Rejoining

NO_WATCHES: Mapping[str, SlotWatch] = MappingProxyType({})
"""The watchdogs of a robot that holds nothing: only `Active` owns a dict it fills."""


__all__ = ["NO_WATCHES", "Active", "Claiming", "Fenced", "Rejoining", "RoleState", "Standby"]
