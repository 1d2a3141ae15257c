"""The event log's records as types, one frozen class a kind (DESIGN section 3).

The event log is an outside contract: clients parse it by name, one JSON object a line,
`{"t", "robot", "event", ...fields}`. Each class below is one name; its dataclass fields
are the record's fields in the order they are written. `record(t, robot)` builds the
JSON object, so the node emits typed values and only the driver turns them into JSON.

A channel's condition (radio up or down, send errors) is not an event: it goes to the
daemon's own log and counters, so no name outside this module reaches the log.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, ClassVar

from swarmd.core.errors import EventRecordError
from swarmd.core.roles import Role

NAME_KEY = "event"
"""The key of a record's kind: the event log's one name-keyed field (DESIGN section 3).
The daemon's own log and its metrics name an event under the same key; readers that
need only a record's name ask `name_of`."""


class RoleName(StrEnum):
    """A role as the event log spells it: `Role`'s name (the wire's role field) in lower
    case. A `StrEnum`, so a record is written as it always was (`"role": "active"`)."""

    ACTIVE = "active"
    STANDBY = "standby"
    CLAIMING = "claiming"
    FENCED = "fenced"
    REJOINING = "rejoining"

    @classmethod
    def of(cls, role: Role) -> RoleName:
        return cls[role.name]

    @classmethod
    def _missing_(cls, value: object) -> RoleName | None:
        # Logs spell a role as `Role` prints it too (`ACTIVE`, `Role.ACTIVE`), and the
        # paper calls a standby *inactive* (Fig. 5): each reads as the role it names.
        name = str(value).upper().removeprefix("ROLE.")
        return cls.STANDBY if name == "INACTIVE" else cls.__members__.get(name)


class LeaveCause(StrEnum):
    """Why a robot left its function (`leave`'s `reason`): each `LeaveReason` a LEAVE
    frame can carry, by name, and the one only the daemon logs."""

    SHUTDOWN = "shutdown"
    """A graceful stop with handover (`handover_on_stop`)."""
    FAULT = "fault"
    """The robot reported itself faulty (DESIGN rule 7)."""
    FENCED = "fenced"
    """It learnt its slot was taken over (DESIGN rule 2; the node logs `fenced`)."""
    REVOKED = "revoked"
    """Its key was revoked (docs/operations.md): it sends no LEAVE, nobody would believe
    it, so this one is in its own event log only."""


class AlertCause(StrEnum):
    """Why nobody took a function over (`alert`'s `reason`, DESIGN rule 8)."""

    NO_CLAIM = "no claim"
    """Warnings went out for `alert_after` and no standby claimed."""
    NO_STANDBY = "no standby left"
    """No standby that could take it over is alive."""


class Event:
    """Base of every event-log record type; `match` on the subclasses."""

    __slots__ = ()
    name: ClassVar[str]
    """The record's `event` value."""

    def fields(self) -> dict[str, Any]:
        """The record's fields, in contract order (`from_` is written `from`)."""
        return {key: getattr(self, attr) for attr, key in _keys(type(self))}

    def record(self, t: float, robot: int) -> dict[str, Any]:
        """The JSON Lines object: {"t", "robot", "event", ...fields}."""
        return {"t": t, "robot": robot, NAME_KEY: self.name, **self.fields()}

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> Event:
        """The typed event a JSON record (`record`'s output, or a line of an event log
        read back) holds. Keys beyond the kind's fields (`t`, `robot`) are ignored.
        Raises `EventRecordError` for a name no kind has, a record without a field its
        kind's class requires, or (called on a subclass) a record of another kind."""
        name = record.get(NAME_KEY)
        kind = EVENTS.get(name) if isinstance(name, str) else None
        if kind is None:
            raise EventRecordError(f"unknown event {name!r}; known: {', '.join(EVENTS)}")
        if not issubclass(kind, cls):
            raise EventRecordError(f"a {name!r} record is no {cls.__name__}")
        missing = [key for attr, key in _keys(kind) if key not in record
                   and _field(kind, attr).default is dataclasses.MISSING]
        if missing:
            raise EventRecordError(f"{name!r} record without {', '.join(missing)}")
        try:
            return kind(**{attr: record[key] for attr, key in _keys(kind) if key in record})
        except ValueError as exc:  # a field its enum has no member for
            raise EventRecordError(f"{name!r} record: {exc}") from None

    @classmethod
    def contract(cls) -> tuple[str, ...]:
        """The field names every record of this kind carries."""
        return tuple(key for attr, key in _keys(cls)
                     if _field(cls, attr).default is dataclasses.MISSING)


_KEYS: dict[type[Event], tuple[tuple[str, str], ...]] = {}


def _keys(cls: type[Event]) -> tuple[tuple[str, str], ...]:
    """(attribute, JSON key) for each field: a trailing `_` escapes a Python keyword."""
    keys = _KEYS.get(cls)
    if keys is None:
        keys = _KEYS[cls] = tuple((f.name, f.name.removesuffix("_"))
                                  for f in dataclasses.fields(cls))  # type: ignore[arg-type]
    return keys


def _field(cls: type[Event], attr: str) -> dataclasses.Field[Any]:
    return next(f for f in dataclasses.fields(cls) if f.name == attr)  # type: ignore[arg-type]


@dataclass(frozen=True, slots=True)
class Started(Event):
    """The node runs: as `role` (active or standby), holding `function` or None; after
    a rejoin hold (DESIGN rule 2 across a reboot), the hold's outcome."""

    name: ClassVar[str] = "started"
    role: RoleName
    function: str | None

    def __post_init__(self) -> None:
        # A record read back holds the plain name: the enum checks and types it.
        object.__setattr__(self, "role", RoleName(self.role))


@dataclass(frozen=True, slots=True)
class Suspect(Event):
    """A watchdog fired: `subject`, holder of the watched `function`, fell silent for
    T_max (paper Fig. 7)."""

    name: ClassVar[str] = "suspect"
    subject: int
    function: str


@dataclass(frozen=True, slots=True)
class Warn(Event):
    """This robot starts warning the standbys about `subject` (paper Fig. 8)."""

    name: ClassVar[str] = "warn"
    subject: int
    function: str


@dataclass(frozen=True, slots=True)
class Vote(Event):
    """A standby counted a new witness `from_` against `subject`; `count` distinct
    witnesses within the window so far (paper Fig. 9, DESIGN rule 3)."""

    name: ClassVar[str] = "vote"
    subject: int
    function: str
    from_: int
    count: int


@dataclass(frozen=True, slots=True)
class Claim(Event):
    """This standby claims `function` from `subject` at `epoch` (the paper's wait state)."""

    name: ClassVar[str] = "claim"
    subject: int
    function: str
    epoch: int


@dataclass(frozen=True, slots=True)
class Backoff(Event):
    """This robot gave up its claim on `function`: `winner` claims or holds it (lowest id
    wins; a higher epoch knows more)."""

    name: ClassVar[str] = "backoff"
    subject: int
    function: str
    winner: int


@dataclass(frozen=True, slots=True)
class Takeover(Event):
    """The claim hold ran out: this robot executes `function` at `epoch` in place of
    `replaced`."""

    name: ClassVar[str] = "takeover"
    function: str
    epoch: int
    replaced: int


@dataclass(frozen=True, slots=True)
class Fenced(Event):
    """This robot heard its `function` held at `epoch` by another and stopped it (DESIGN
    rule 2)."""

    name: ClassVar[str] = "fenced"
    function: str
    epoch: int


@dataclass(frozen=True, slots=True)
class Refute(Event):
    """`subject`, suspected on `function`, was heard alive (DESIGN rule 4). The contract
    names no field (`refute{}`); the core always says whom and which slot."""

    name: ClassVar[str] = "refute"
    subject: int
    function: str

    @classmethod
    def contract(cls) -> tuple[str, ...]:
        return ()


@dataclass(frozen=True, slots=True)
class Leave(Event):
    """This robot stops executing `function` and tells the swarm (`reason`: fault,
    DESIGN rule 7, or shutdown, a graceful stop with handover; `LeaveCause`)."""

    name: ClassVar[str] = "leave"
    function: str
    reason: LeaveCause

    def __post_init__(self) -> None:
        object.__setattr__(self, "reason", LeaveCause(self.reason))


@dataclass(frozen=True, slots=True)
class Alert(Event):
    """Nobody can or did take `function` over (DESIGN rule 8): for an operator."""

    name: ClassVar[str] = "alert"
    function: str
    reason: AlertCause

    def __post_init__(self) -> None:
        object.__setattr__(self, "reason", AlertCause(self.reason))


@dataclass(frozen=True, slots=True)
class Stopped(Event):
    """The node stopped (graceful stop)."""

    name: ClassVar[str] = "stopped"


@dataclass(frozen=True, slots=True)
class Fault(Event):
    """A fault injected by a simulator (`kind` as in `crash:R@T`), never by the core.
    `spec` is the fault as given; `duration` and `groups` are written when the fault has
    them (a pause, a partition)."""

    name: ClassVar[str] = "fault"
    kind: str
    spec: str | None = None
    duration: float | None = None
    groups: list[list[int]] | None = None

    def fields(self) -> dict[str, Any]:
        return {key: value for key, value in Event.fields(self).items()
                if value is not None or key == "kind"}


def name_of(record: Mapping[str, Any]) -> str | None:
    """A record's event name, without reading the rest of it (a hot path: every record
    of a run goes through the checker); None when it has none."""
    name = record.get(NAME_KEY)
    return name if isinstance(name, str) else None


def event_of(record: Mapping[str, Any]) -> Event | None:
    """`Event.from_record`, or None for a record that is no event: for readers that pass
    over what they cannot read (a live view, a plot)."""
    try:
        return Event.from_record(record)
    except EventRecordError:
        return None


CORE_EVENTS: tuple[type[Event], ...] = (
    Started, Suspect, Warn, Vote, Claim, Backoff, Takeover, Fenced, Refute, Leave, Alert,
    Stopped,
)
"""Every kind the core emits, in DESIGN section 3's order."""

EVENTS: dict[str, type[Event]] = {cls.name: cls for cls in CORE_EVENTS}
EVENTS[Fault.name] = Fault
"""Every name the event log may hold -> its type."""


__all__ = [
    "CORE_EVENTS", "EVENTS", "NAME_KEY", "Alert", "AlertCause", "Backoff", "Claim", "Event",
    "Fault", "Fenced", "Leave", "LeaveCause", "Refute", "RoleName", "Started", "Stopped",
    "Suspect", "Takeover", "Vote", "Warn", "event_of", "name_of",
]
