"""The sans-IO protocol core (DESIGN.md section 2): pure, deterministic, stdlib only."""

from swarmd.core.actions import Action, Assign, Broadcast, Event, Release
from swarmd.core.params import Params, ParamsError, radio, udp
from swarmd.core.plan import PlanError, RobotPlan, SwarmPlan
from swarmd.core.roles import Health, Role
from swarmd.core.wire import CodecError, Frame, decode, encode

__all__ = [
    "Action",
    "Assign",
    "Broadcast",
    "CodecError",
    "Event",
    "Frame",
    "Health",
    "Params",
    "ParamsError",
    "PlanError",
    "Release",
    "RobotPlan",
    "Role",
    "SwarmPlan",
    "decode",
    "encode",
    "radio",
    "udp",
]
