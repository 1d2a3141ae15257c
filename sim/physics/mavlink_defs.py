"""The MAVLink numbers and small types the simulated autopilot (`sim.physics.autopilot`)
speaks in: MAV_RESULT, MAV_STATE, sensor and mode-flag bits, parameter types and frames,
each firmware's identity (home, version, capabilities), and a command's parameters as
one shape.

Nothing here holds state or moves bytes: the autopilot's logic
(`sim.physics.autopilot_core`) and its UDP endpoint (`sim.physics.autopilot`) import it,
never the other way round.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from swarmd.base.functions import Vec3
from swarmd.link.mavlink_modes import Flavour
from swarmd.link.mavlink_pilot import EARTH_RADIUS

ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
STATE_STANDBY, STATE_ACTIVE, STATE_CRITICAL, STATE_EMERGENCY = 3, 4, 5, 6
ALL_SENSORS = 1 | 2 | 4 | 8 | 32 | 32768
"""gyro, accel, mag, baro, GPS, motor outputs."""
MOTORS = 32768
PREARM = 0x10000000
"""MAV_SYS_STATUS_PREARM_CHECK: set healthy while the arming checks pass."""
CUSTOM, AUTO, GUIDED, STABILIZE, MANUAL_INPUT, ARMED = 1, 4, 8, 16, 64, 128
"""MAV_MODE_FLAG bits of HEARTBEAT base_mode."""
REAL32, INT8, INT16, INT32 = 9, 2, 4, 6
"""MAV_PARAM_TYPE of the simulated parameters."""
FRAME_GLOBAL, FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_INT, FRAME_GLOBAL_RELATIVE_ALT_INT = (
    0, 3, 5, 6)
MESSAGE_IDS = {0: "HEARTBEAT", 1: "SYS_STATUS", 147: "BATTERY_STATUS", 32: "LOCAL_POSITION_NED",
               30: "ATTITUDE", 33: "GLOBAL_POSITION_INT", 24: "GPS_RAW_INT",
               245: "EXTENDED_SYS_STATE", 242: "HOME_POSITION", 49: "GPS_GLOBAL_ORIGIN",
               148: "AUTOPILOT_VERSION", 193: "EKF_STATUS_REPORT", 230: "ESTIMATOR_STATUS",
               42: "MISSION_CURRENT", 74: "VFR_HUD"}
"""Messages MAV_CMD_REQUEST_MESSAGE can ask for (param1 is the message id); each
firmware answers only its own estimator report (ArduPilot EKF_STATUS_REPORT, PX4
ESTIMATOR_STATUS)."""

GEO_ORIGIN: dict[Flavour, Vec3] = {"px4": (47.397742, 8.545594, 488.0),
                                   "ardupilot": (-35.363261, 149.165230, 584.0)}
"""Default latitude, longitude (degrees) and altitude (m AMSL) of the swarm frame's 0:
each firmware's SITL default home (PX4: Zurich; ArduPilot: CMAC, Canberra)."""
VERSION: dict[Flavour, int] = {"px4": (1 << 24) | (15 << 16) | 255,
                               "ardupilot": (4 << 24) | (5 << 16) | 255}
"""AUTOPILOT_VERSION flight_sw_version: PX4 v1.15.0 and ArduCopter 4.5.0, official."""
CAPABILITIES: dict[Flavour, int] = {
    # MAV_PROTOCOL_CAPABILITY: MISSION_FLOAT 1, PARAM_FLOAT 2, MISSION_INT 4, COMMAND_INT 8,
    # PARAM_ENCODE_BYTEWISE 16, SET_POSITION_TARGET_LOCAL_NED 128,
    # SET_POSITION_TARGET_GLOBAL_INT 256, MAVLINK2 8192. Not claimed, as not simulated:
    # FTP (so clients use the parameter and mission messages), SET_ATTITUDE_TARGET,
    # TERRAIN, MISSION_FENCE and MISSION_RALLY (PX4 `mavlink_main.cpp`
    # get_capabilities and ArduPilot `GCS_Common.cpp` capabilities claim those).
    "px4": 1 | 2 | 4 | 8 | 16 | 128 | 256 | 8192,
    # ArduPilot: the same without PARAM_FLOAT and PARAM_ENCODE_BYTEWISE, with
    # PARAM_ENCODE_C_CAST (1 << 17).
    "ardupilot": 1 | 4 | 8 | 128 | 256 | 8192 | (1 << 17),
}


@dataclass
class Param:
    value: float
    kind: int
    """MAV_PARAM_TYPE."""


def command_int(x: float) -> int:
    """A command parameter as the integer it encodes; -1 for NaN (MAVLink's "unset")."""
    return round(x) if math.isfinite(x) else -1


def geodetic(origin: Vec3, east: float, north: float, up: float) -> Vec3:
    """(lat, lon, alt) of the point (east, north, up) m from `origin` (flat earth, the
    inverse of swarmd.link.mavlink_pilot.geodetic_offset)."""
    lat = origin[0] + math.degrees(north / EARTH_RADIUS)
    lon = origin[1] + math.degrees(east / (EARTH_RADIUS * math.cos(math.radians(origin[0]))))
    return (lat, lon, origin[2] + up)


@dataclass(frozen=True)
class Command:
    """A COMMAND_LONG or COMMAND_INT, the same way: params 1-7 (5 and 6 in degrees),
    and the frame of a COMMAND_INT (None for a COMMAND_LONG)."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    frame: int | None = None

    @classmethod
    def of(cls, msg: Any) -> Command:
        if msg.get_type() == "COMMAND_INT":
            # INT32_MAX in x or y is MAVLink's "unset" for a COMMAND_INT: NaN here.
            x, y = (math.nan if v == 2**31 - 1 else v / 1e7 for v in (msg.x, msg.y))
            return cls(msg.command, (msg.param1, msg.param2, msg.param3, msg.param4, x, y,
                                     msg.z), msg.frame)
        return cls(msg.command, (msg.param1, msg.param2, msg.param3, msg.param4,
                                 msg.param5, msg.param6, msg.param7))

