"""The MAVLink numbers and small types the simulated autopilot (`sim.physics.autopilot`)
speaks in: MAV_RESULT, MAV_STATE, sensor and mode-flag bits, parameter types and frames,
the telemetry rates, each firmware's identity (home, version, capabilities), its
parameters at their defaults, and a command's parameters as one shape.

Nothing here holds state or moves bytes: the autopilot's logic
(`sim.physics.autopilot_core`) and its UDP endpoint (`sim.physics.autopilot`) import it,
never the other way round.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from swarmd.functions import Vec3
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
RATES: dict[str, float] = {"HEARTBEAT": 1.0, "SYS_STATUS": 2.0, "BATTERY_STATUS": 1.0,
                           "LOCAL_POSITION_NED": 10.0, "ATTITUDE": 10.0,
                           "GLOBAL_POSITION_INT": 5.0, "GPS_RAW_INT": 2.0,
                           "EXTENDED_SYS_STATE": 1.0, "HOME_POSITION": 0.5,
                           "ESTIMATOR": 1.0}
MESSAGE_IDS = {0: "HEARTBEAT", 1: "SYS_STATUS", 147: "BATTERY_STATUS", 32: "LOCAL_POSITION_NED",
               30: "ATTITUDE", 33: "GLOBAL_POSITION_INT", 24: "GPS_RAW_INT",
               245: "EXTENDED_SYS_STATE", 242: "HOME_POSITION", 49: "GPS_GLOBAL_ORIGIN",
               148: "AUTOPILOT_VERSION", 193: "ESTIMATOR", 230: "ESTIMATOR"}
"""Messages MAV_CMD_REQUEST_MESSAGE can ask for (param1 is the message id)."""

GEO_ORIGIN: dict[Flavour, Vec3] = {"px4": (47.397742, 8.545594, 488.0),
                                   "ardupilot": (-35.363261, 149.165230, 584.0)}
"""Default latitude, longitude (degrees) and altitude (m AMSL) of the swarm frame's 0:
each firmware's SITL default home (PX4: Zurich; ArduPilot: CMAC, Canberra)."""
VERSION: dict[Flavour, int] = {"px4": (1 << 24) | (15 << 16) | 255,
                               "ardupilot": (4 << 24) | (5 << 16) | 255}
"""AUTOPILOT_VERSION flight_sw_version: PX4 v1.15.0 and ArduCopter 4.5.0, official."""
CAPABILITIES: dict[Flavour, int] = {
    # MISSION_FLOAT, PARAM_FLOAT, MISSION_INT, COMMAND_INT, PARAM_ENCODE_BYTEWISE,
    # SET_POSITION_TARGET_LOCAL_NED, SET_POSITION_TARGET_GLOBAL_INT, MAVLINK2 (no FTP:
    # not simulated, so clients use the parameter and mission messages).
    "px4": 1 | 2 | 4 | 8 | 16 | 256 | 512 | 8192,
    # MISSION_FLOAT, MISSION_INT, COMMAND_INT, SET_POSITION_TARGET_LOCAL_NED,
    # SET_POSITION_TARGET_GLOBAL_INT, MAVLINK2, PARAM_ENCODE_C_CAST.
    "ardupilot": 1 | 4 | 8 | 256 | 512 | 8192 | (1 << 17),
}


@dataclass
class Param:
    value: float
    kind: int
    """MAV_PARAM_TYPE."""


def default_params(flavour: Flavour, sysid: int) -> dict[str, Param]:
    """The parameters the simulated autopilot has, at the firmware's defaults: those its
    behaviour reads (takeoff altitude, auto-disarm delays, offboard loss) and those
    clients read to identify the vehicle. docs/mavlink.md lists them."""
    if flavour == "px4":
        return {"MIS_TAKEOFF_ALT": Param(2.5, REAL32), "COM_DISARM_LAND": Param(2.0, REAL32),
                "COM_DISARM_PRFLT": Param(10.0, REAL32), "COM_OF_LOSS_T": Param(1.0, REAL32),
                "MAV_SYS_ID": Param(sysid, INT32), "MAV_TYPE": Param(2, INT32),
                "SYS_AUTOSTART": Param(4001, INT32)}
    return {"DISARM_DELAY": Param(10, INT8), "SYSID_THISMAV": Param(sysid, INT16),
            "FRAME_CLASS": Param(1, INT8), "FRAME_TYPE": Param(1, INT8)}




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
            return cls(msg.command, (msg.param1, msg.param2, msg.param3, msg.param4,
                                     msg.x / 1e7, msg.y / 1e7, msg.z), msg.frame)
        return cls(msg.command, (msg.param1, msg.param2, msg.param3, msg.param4,
                                 msg.param5, msg.param6, msg.param7))

