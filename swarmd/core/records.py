"""The node's data records (DESIGN section 2): who holds a slot, what a restarted robot
persisted, and the read-only view drivers take of a node. Pure data, no rules."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

from swarmd.core.roles import Health, Role


class Holder(NamedTuple):
    """Who executes a function slot, as far as a robot knows, and at which epoch (the
    fencing token of DESIGN rule 2). Robot 0: nobody."""

    robot: int
    epoch: int


class Standing(NamedTuple):
    """The part of a `Snapshot` a driver looks at on every tick, cheap to take (a
    snapshot copies every table): the role, to report a change, and what decides
    whether the state file is due."""

    role: Role
    function: str | None
    epoch: int
    known: tuple[tuple[str, Holder], ...]
    """`Snapshot.known`'s entries, sorted by function."""
    seq: int


@dataclass(frozen=True, slots=True)
class Restored:
    """What a restarted robot persisted (the runtime writes it atomically)."""

    known: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    """function -> (holder robot id, epoch) as last known."""
    held: tuple[str, int] | None = None
    """(function, epoch) this robot was executing when it stopped, if any."""
    peer_seq: Mapping[int, int] = field(default_factory=dict)
    """robot -> highest sequence number accepted from it (`Snapshot.peer_seq`): frames
    at or below it, captured before the restart, stay old (replays) after it."""
    certificate: tuple[bytes, ...] = ()
    """The frames that certify `held` (`Snapshot.certificate`), in every auth mode.
    Verified again on restore; a frame that does not verify is left out."""


@dataclass(frozen=True, slots=True)
class Snapshot:
    """Read-only view for persistence, the monitor and tests."""

    robot_id: int
    role: Role
    function: str | None
    epoch: int
    health: Health
    known: Mapping[str, tuple[int, int]]
    """function -> (holder, epoch); the node fills it with `Holder`s."""
    suspects: Mapping[str, int]
    """function -> suspected holder, for the slots this robot currently warns about."""
    votes: Mapping[str, int]
    """function -> distinct witnesses counted now (standbys)."""
    drops: Mapping[str, int]
    seq: int
    frames_in: int = 0
    """Frames accepted (past the drop filters)."""
    frames_out: int = 0
    heard: Mapping[int, float] = field(default_factory=dict)
    """robot -> time of the last frame accepted from it."""
    peer_seq: Mapping[int, int] = field(default_factory=dict)
    """robot -> highest sequence number accepted from it. Persist it with `known` and
    hand it back as `Restored.peer_seq`: a restarted robot then drops replays of frames
    sent before its restart (a dead robot's captured heartbeats cannot delay its
    takeover)."""
    certificate: tuple[bytes, ...] = ()
    """The WARN or LEAVE frames (raw bytes, in every auth mode) that certify this
    robot's hold of `function`, if it took it over. Persist it with `held` and hand it
    back as `Restored.certificate`, so that after a restart it can still prove its hold
    to a robot that missed the takeover (an old holder back from a partition)."""


class SlotBeat(NamedTuple):
    """The last heartbeat heard for one slot: from `holder` at `epoch`, at time `at`."""

    holder: int
    epoch: int
    at: float


__all__ = ["Holder", "Restored", "SlotBeat", "Snapshot"]
