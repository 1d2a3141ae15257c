"""The protocol node: one robot's failure-handling state machine, sans-IO."""
# Implementation lands in the next commit; the API below is the contract.

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from swarmd.core.actions import Action
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Health, Role


@dataclass(frozen=True, slots=True)
class Restored:
    """What a restarted robot persisted (the runtime writes it atomically)."""

    known: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    """function -> (holder robot id, epoch) as last known."""
    held: tuple[str, int] | None = None
    """(function, epoch) this robot was executing when it stopped, if any."""


@dataclass(frozen=True, slots=True)
class Snapshot:
    """Read-only view for persistence, the monitor and tests."""

    robot_id: int
    role: Role
    function: str | None
    epoch: int
    health: Health
    known: Mapping[str, tuple[int, int]]
    suspects: Mapping[str, int]
    """function -> suspected holder, for the slots this robot currently warns about."""
    votes: Mapping[str, int]
    """function -> distinct witnesses counted now (standbys)."""
    drops: Mapping[str, int]
    seq: int


class Node:
    def __init__(
        self,
        robot_id: int,
        plan: SwarmPlan,
        params: Params,
        now: float,
        *,
        keys: Sequence[bytes] = (),
        seq_start: int = 0,
        restored: Restored | None = None,
    ) -> None:
        raise NotImplementedError

    def receive(self, data: bytes, now: float) -> list[Action]:
        raise NotImplementedError

    def tick(self, now: float) -> list[Action]:
        raise NotImplementedError

    def robot_health(self, health: Health, now: float) -> list[Action]:
        raise NotImplementedError

    def stop(self, now: float, *, handover: bool) -> list[Action]:
        raise NotImplementedError

    def next_deadline(self) -> float | None:
        raise NotImplementedError

    def snapshot(self) -> Snapshot:
        raise NotImplementedError
