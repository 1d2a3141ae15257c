"""The core's exceptions under one root (`CoreError`), so a driver can tell a core
refusal from anything else with one `except`.

- `CodecError` (a `ValueError`): bytes that are no valid frame; `receive` turns it into
  a counted drop and never lets it out (DESIGN section 2).
- `EventRecordError` (a `ValueError`): an event-log record read back that names no
  event kind or lacks a field of its kind (`Event.from_record`).
- `ParamsError`, `PlanError` (`ValueError`s): timing or a swarm plan that cannot work;
  raised when they are built, before any robot runs.
- `NodeError`, `TransitionError` (`RuntimeError`s): misuse of the node by its driver
  (a bug there), never caused by a peer's frame.
"""

from __future__ import annotations

from swarmd.core.drops import DropReason


class CoreError(Exception):
    """Root of every exception `swarmd.core` raises on purpose."""


class CodecError(CoreError, ValueError):
    """A frame that cannot be decoded or verified. `reason` is the drop counter it goes
    to (DESIGN section 2: every refused frame is a counted drop), typed so that the
    codec can name no counter that does not exist; `detail` says what was wrong, for a
    log or a test."""

    def __init__(self, reason: DropReason, detail: str) -> None:
        self.reason = reason
        self.detail = detail
        super().__init__(f"{reason}: {detail}")


class EventRecordError(CoreError, ValueError):
    """An event-log record that is no event: an unknown name or a missing field."""


class ParamsError(CoreError, ValueError):
    """Timing parameters that cannot work together."""


class PlanError(CoreError, ValueError):
    """A swarm plan the protocol cannot run."""


class NodeError(CoreError, RuntimeError):
    """Misuse of the node API (a bug in the driver), never caused by peer frames."""


class TransitionError(CoreError, RuntimeError):
    """The node tried a transition the table does not allow (a bug, not peer input)."""


__all__ = ["CodecError", "CoreError", "EventRecordError", "NodeError", "ParamsError", "PlanError",
           "TransitionError"]
