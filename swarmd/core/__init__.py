"""The sans-IO protocol core (DESIGN.md section 2): pure, deterministic, stdlib only.

A driver builds a `Node` from a `SwarmPlan` and `Params`, calls its entry points with
the time, and executes the actions they return: `Broadcast`, `Assign`, `Release`, and
the event-log records (`Event` subclasses). The wire messages (`wire.Heartbeat`, ...)
stay in `swarmd.core.wire`, whose names overlap the events'.
"""

from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Broadcast, Release
from swarmd.core.events import (
    CORE_EVENTS,
    EVENTS,
    Alert,
    Backoff,
    Claim,
    Event,
    Fault,
    Fenced,
    Leave,
    Refute,
    Started,
    Stopped,
    Suspect,
    Takeover,
    Vote,
    Warn,
)
from swarmd.core.node import Holder, Node, NodeError, Restored, Snapshot
from swarmd.core.params import PRESETS, Params, ParamsError, radio, udp
from swarmd.core.plan import PlanError, RobotPlan, SwarmPlan
from swarmd.core.roles import Health, Role, TransitionError, Trigger
from swarmd.core.wire import CodecError, Frame, decode, encode

__all__ = [
    "CORE_EVENTS",
    "EVENTS",
    "PRESETS",
    "Action",
    "Alert",
    "Assign",
    "Backoff",
    "Broadcast",
    "Claim",
    "CodecError",
    "Event",
    "Fault",
    "Fenced",
    "Frame",
    "Health",
    "Holder",
    "Leave",
    "Node",
    "NodeError",
    "Params",
    "ParamsError",
    "PlanError",
    "Refute",
    "Release",
    "Restored",
    "RobotPlan",
    "Role",
    "Snapshot",
    "Started",
    "Stopped",
    "Suspect",
    "SwarmPlan",
    "Takeover",
    "TransitionError",
    "Trigger",
    "Vote",
    "Warn",
    "decode",
    "encode",
    "radio",
    "udp",
    "wire",
]
