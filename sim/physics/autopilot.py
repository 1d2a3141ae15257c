"""A simulated flight controller that speaks MAVLink over a MuJoCo quadrotor (or, without
physics, a point mass: sim/physics/point.py).

As PX4 SITL does, each simulated robot's autopilot listens on its own UDP port on
loopback (one MAVLink system id per robot) and sends its telemetry to every peer it has
heard from in the last `PEER_TIMEOUT` s (and to fixed `peers`, e.g. a ground station's
14550), so the daemon's `mavlink` link and any ground station or SDK can talk to it at
once. `flavour` is `px4` or `ardupilot`: the autopilot answers as that firmware answers
(its HEARTBEAT fields, mode encodings, MAV_RESULT codes, parameters, take-off rules).
docs/mavlink.md tabulates each answer with the firmware source it follows.

Sent: HEARTBEAT 1 Hz, SYS_STATUS 2 Hz, BATTERY_STATUS 1 Hz, LOCAL_POSITION_NED and
ATTITUDE 10 Hz, GLOBAL_POSITION_INT 5 Hz, GPS_RAW_INT 2 Hz, EXTENDED_SYS_STATE 1 Hz,
HOME_POSITION 0.5 Hz, EKF_STATUS_REPORT (ArduPilot) or ESTIMATOR_STATUS (PX4) 1 Hz. A
change of system_status or sensor health sends HEARTBEAT and SYS_STATUS at once.
Latitude, longitude and altitude are the swarm frame's position around `geo_origin`
(default: each firmware's SITL home), flat earth.

Answered: COMMAND_LONG and COMMAND_INT (arm / disarm, DO_SET_MODE, NAV_TAKEOFF, NAV_LAND,
RETURN_TO_LAUNCH, DO_REPOSITION, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE,
REQUEST_AUTOPILOT_CAPABILITIES), SET_MODE, the parameter protocol, the mission list
(empty), PING (PX4) and TIMESYNC, and SET_POSITION_TARGET_LOCAL_NED in GUIDED / OFFBOARD.
Modes: `guided` follows the setpoints (PX4 OFFBOARD needs a setpoint stream to enter and
falls back to HOLD when it stops for COM_OF_LOSS_T; ArduCopter needs NAV_TAKEOFF before
it leaves the ground), `hold` (and ArduPilot's `brake`) stops where it is, `land` lands
where it is, `rtl` flies home and lands, PX4's `takeoff` climbs. On the ground it
disarms by itself as each firmware does.

Faults: a failed motor (`fail_motor`, the simulator's `motor` fault) clears the motor
outputs' health bit in SYS_STATUS and the HEARTBEAT says EMERGENCY while the craft falls
(and after it crashed), as a real autopilot shows a lost motor; `refuse_arm` fails the
arming checks (the SYS_STATUS pre-arm bit clears, arming is refused).

The local NED frame's origin is the robot's home (where the craft powered up); the
simulator's world frame is the swarm frame (x east, y north, z up).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.link import QuadLink
from sim.physics.point import PointLink, PointRobot
from sim.physics.robot import Mode, QuadRobot
from swarmd.core.roles import Health
from swarmd.functions import Setpoint, Vec3
from swarmd.link.base import HealthCallback
from swarmd.link.mavlink import MavlinkLink
from swarmd.link.mavlink_modes import Flavour, custom_mode, mode_name
from swarmd.link.mavlink_pilot import EARTH_RADIUS, PilotConfig, Release, geodetic_offset

log = logging.getLogger("swarmd.sim.autopilot")

PEER_TIMEOUT = 10.0
"""s: a peer not heard from for this long gets no more telemetry."""
TICK = 0.05
"""s between two telemetry passes (10 Hz position)."""

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


def _int(x: float) -> int:
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


class _Target:
    """The craft's setpoint in the world frame (a `Flight` for `QuadRobot.fly`)."""

    def __init__(self, position: Vec3) -> None:
        self.position = position
        self.velocity: Vec3 = (0.0, 0.0, 0.0)

    def setpoint(self, t: float, position: Vec3) -> Setpoint:
        return Setpoint(self.position, self.velocity)

    @property
    def target(self) -> Vec3:
        return self.position


class AutopilotCore:
    """The autopilot's logic over one craft (`QuadRobot`, or `PointRobot` without
    physics): messages in, messages out, on the craft's clock. Sans-I/O (the server
    below moves the bytes). docs/mavlink.md tabulates every answer and the firmware
    behaviour it follows."""

    def __init__(self, robot: QuadRobot | PointRobot, flavour: Flavour, sysid: int, *,
                 geo_origin: Vec3 | None = None) -> None:
        self.robot = robot
        self.flavour = flavour
        self.sysid = sysid
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.geo_origin = geo_origin or GEO_ORIGIN[flavour]
        self.params = default_params(flavour, sysid)
        self.armed = False
        self.mode = "hold"
        self.refuse_arm = False
        self.forced = Health.OK
        """`set_health`: a fault the simulator injects (DEGRADED: CRITICAL, else EMERGENCY)."""
        self.label = "mavlink"
        """What the trajectory file records as the craft's function (MAVLink has no such
        notion; `SimMavlinkLink` names the daemon's function so pictures can)."""
        self.took_off = False
        """ArduCopter: NAV_TAKEOFF was accepted since arming (GUIDED flies from then on)."""
        self.flew = False
        """Left the ground since arming (decides which auto-disarm delay applies)."""
        self.takeoff_alt: float | None = None
        """PX4: param7 (m AMSL, or NaN) of a take-off accepted while disarmed."""
        self.last_setpoint = -math.inf
        self.target = _Target(robot.position)
        self._due: dict[str, float] = {}
        self._reported: tuple[int, int] | None = None
        self._ground_since: float | None = None
        self.boot = time.monotonic()
        self.counters = {"commands": 0, "setpoints": 0, "refused": 0}

    # -- parameters and frames ------------------------------------------------------------
    def param(self, name: str) -> float:
        return self.params[name].value

    def _wire(self, p: Param) -> float:
        """A parameter's value as PARAM_VALUE carries it: PX4 copies an integer's bytes
        into the float field, ArduPilot casts it (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_*)."""
        if p.kind == REAL32 or self.flavour == "ardupilot":
            return float(p.value)
        return float(struct.unpack("<f", struct.pack("<i", int(p.value)))[0])

    def _unwire(self, raw: float, kind: int) -> float:
        if kind == REAL32 or self.flavour == "ardupilot":
            return float(raw) if kind == REAL32 else float(int(raw))
        return float(struct.unpack("<i", struct.pack("<f", raw))[0])

    def home_geo(self) -> Vec3:
        hx, hy, hz = self.robot.home
        return geodetic(self.geo_origin, hx, hy, hz)

    def _refused(self) -> int:
        """What each firmware answers a command its state does not allow now: PX4's
        Commander TEMPORARILY_REJECTED, ArduPilot's GCS handlers FAILED."""
        return TEMPORARILY_REJECTED if self.flavour == "px4" else FAILED

    # -- what it says ---------------------------------------------------------------------
    def system_status(self) -> int:
        r = self.robot
        if r.failed_motors or r.mode is Mode.CRASHED or self.forced is Health.FAULTY:
            return STATE_EMERGENCY
        if self.forced is Health.DEGRADED:
            return STATE_CRITICAL
        return STATE_ACTIVE if self.armed else STATE_STANDBY

    def sensors_health(self) -> int:
        return ALL_SENSORS & ~MOTORS if self.robot.failed_motors else ALL_SENSORS

    def armable(self) -> bool:
        """The arming checks pass (SYS_STATUS pre-arm bit)."""
        r = self.robot
        return not (self.refuse_arm or r.failed_motors or r.mode is Mode.CRASHED)

    def _time_ms(self, t: float) -> int:
        return int(t * 1000) & 0xFFFFFFFF

    def local_ned(self) -> tuple[Vec3, Vec3]:
        (x, y, z), (vx, vy, vz) = self.robot.position, self.robot.velocity
        hx, hy, hz = self.robot.home
        return (y - hy, x - hx, -(z - hz)), (vy, vx, -vz)

    def base_mode(self) -> int:
        """HEARTBEAT base_mode as each firmware fills it: PX4 sets AUTO, GUIDED and
        STABILIZE in its auto modes and OFFBOARD; ArduCopter always STABILIZE and
        MANUAL_INPUT, GUIDED in its position-controlled modes."""
        if self.flavour == "px4":
            base = CUSTOM | AUTO | GUIDED | STABILIZE
        else:
            base = CUSTOM | STABILIZE | MANUAL_INPUT
            if self.mode in ("guided", "hold", "brake", "rtl"):
                base |= GUIDED
        return base | (ARMED if self.armed else 0)

    def heartbeat(self) -> Any:
        return self.mav.heartbeat_encode(2, 12 if self.flavour == "px4" else 3,
                                         self.base_mode(), custom_mode(self.flavour, self.mode),
                                         self.system_status())

    def telemetry(self, t: float, force: bool = False) -> list[Any]:
        """Messages due at robot time `t`."""
        out: list[Any] = []
        status = (self.system_status(), self.sensors_health())
        changed = status != self._reported
        self._reported = status
        for name, hz in RATES.items():
            due = self._due.get(name, 0.0)
            if t < due and not (changed and name in ("HEARTBEAT", "SYS_STATUS")):
                continue
            self._due[name] = max(due + 1.0 / hz, t)
            out.append(self._message(name, t))
        return out

    def _message(self, name: str, t: float) -> Any:
        r, mav = self.robot, self.mav
        battery = max(0, min(100, round(100 * r.battery)))
        if name == "HEARTBEAT":
            return self.heartbeat()
        if name == "SYS_STATUS":
            # The pre-arm bit: present and enabled (the checks run), healthy while they
            # pass and whenever armed (both firmwares, and MAVLink's definition).
            ready = self.armed or self.armable()
            health = self.sensors_health() | (PREARM if ready else 0)
            return mav.sys_status_encode(ALL_SENSORS | PREARM, ALL_SENSORS | PREARM, health, 200,
                                         int(11100 + 1500 * r.battery), -1, battery,
                                         0, 0, 0, 0, 0, 0)
        if name == "BATTERY_STATUS":
            return mav.battery_status_encode(0, 1, 1, 2500, [4000] * 3 + [65535] * 7, -1, -1,
                                             -1, battery)
        if name == "LOCAL_POSITION_NED":
            (n, e, d), (vn, ve, vd) = self.local_ned()
            return mav.local_position_ned_encode(self._time_ms(t), n, e, d, vn, ve, vd)
        if name == "ATTITUDE":
            roll, pitch, yaw = self._euler()
            return mav.attitude_encode(self._time_ms(t), roll, pitch, yaw, 0, 0, 0)
        if name in ("GLOBAL_POSITION_INT", "GPS_RAW_INT"):
            (x, y, z), (vx, vy, vz) = r.position, r.velocity
            lat, lon, alt = geodetic(self.geo_origin, x, y, z)
            if name == "GPS_RAW_INT":
                ground = math.hypot(vx, vy)
                cog = round(math.degrees(math.atan2(vx, vy)) % 360 * 100) if ground > 0.1 else (
                    65535)
                return mav.gps_raw_int_encode(int(t * 1e6), 3, round(lat * 1e7),
                                              round(lon * 1e7), round(alt * 1000), 80, 120,
                                              round(ground * 100), cog, 12)
            heading = round(math.degrees(self._euler()[2]) % 360 * 100)
            return mav.global_position_int_encode(
                self._time_ms(t), round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
                round((z - r.home[2]) * 1000), round(vy * 100), round(vx * 100),
                round(-vz * 100), heading)
        if name == "EXTENDED_SYS_STATE":
            landed = {Mode.PARKED: 1, Mode.CRASHED: 1, Mode.FLYING: 2, Mode.TAKEOFF: 3,
                      Mode.LANDING: 4}[r.mode]
            return mav.extended_sys_state_encode(0, landed)
        if name in ("HOME_POSITION", "GPS_GLOBAL_ORIGIN"):
            lat, lon, alt = self.home_geo()
            if name == "GPS_GLOBAL_ORIGIN":  # the EKF origin is home (where it powered up)
                return mav.gps_global_origin_encode(round(lat * 1e7), round(lon * 1e7),
                                                    round(alt * 1000))
            return mav.home_position_encode(round(lat * 1e7), round(lon * 1e7),
                                            round(alt * 1000), 0.0, 0.0, 0.0,
                                            [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)
        if name == "AUTOPILOT_VERSION":
            return mav.autopilot_version_encode(
                CAPABILITIES[self.flavour], VERSION[self.flavour], 0, 0, 0, [0] * 8, [0] * 8,
                [0] * 8, 0, 0, self.sysid)
        if self.flavour == "ardupilot":
            return mav.ekf_status_report_encode(1 | 2 | 4 | 8 | 16 | 32 | 256 | 512, 0.02,
                                                0.02, 0.02, 0.02, 0.0)
        return mav.estimator_status_encode(int(t * 1e6), 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512,
                                           0.02, 0.02, 0.02, 0.02, 0, 0, 0.5, 0.5)

    def _euler(self) -> Vec3:
        """Roll, pitch and yaw in NED (yaw from north, clockwise)."""
        w, x, y, z = self.robot.attitude
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        yaw_enu = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        # ENU yaw (from east, counter-clockwise) to NED heading (from north, clockwise)
        return (roll, -pitch, math.atan2(math.cos(yaw_enu), math.sin(yaw_enu)))

    # -- what it is told ------------------------------------------------------------------
    def handle(self, msg: Any, t: float) -> list[Any]:
        """One message from a peer; the replies."""
        kind = msg.get_type()
        if getattr(msg, "target_system", self.sysid) not in (0, self.sysid):
            return []
        src, comp = msg.get_srcSystem(), msg.get_srcComponent()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            self.counters["commands"] += 1
            cmd = Command.of(msg)
            result, extra = self._command(cmd, t)
            if result != ACCEPTED:
                self.counters["refused"] += 1
            return [self.mav.command_ack_encode(cmd.command, result, 0, 0, src, comp), *extra]
        if kind == "SET_MODE":
            result = (self._set_mode_number(msg.custom_mode, t) if msg.base_mode & CUSTOM
                      else UNSUPPORTED)
            # ArduPilot acks the message itself (id 11); PX4 turns it into DO_SET_MODE.
            acked = 11 if self.flavour == "ardupilot" else 176
            return [self.mav.command_ack_encode(acked, result, 0, 0, src, comp)]
        if kind == "SET_POSITION_TARGET_LOCAL_NED" and msg.coordinate_frame == 1:
            self._setpoint(msg, t)
        elif kind.startswith("PARAM_"):
            return self._param_message(msg)
        elif kind == "MISSION_REQUEST_LIST":
            return [self.mav.mission_count_encode(src, comp, self._mission_count(
                msg.mission_type), msg.mission_type)]
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            return self._mission_item(msg, src, comp)
        elif (kind == "PING" and self.flavour == "px4" and msg.target_system == 0
              and msg.target_component == 0):  # ArduPilot answers TIMESYNC, not PING
            return [self.mav.ping_encode(msg.time_usec, msg.seq, src, comp)]
        elif kind == "TIMESYNC" and msg.tc1 == 0:  # a request: our clock, their stamp
            return [self.mav.timesync_encode(int(t * 1e9), msg.ts1)]
        return []

    def _command(self, c: Command, t: float) -> tuple[int, list[Any]]:
        p = c.params
        if c.command == 400:  # MAV_CMD_COMPONENT_ARM_DISARM
            return self._arm(p[0], p[1], t), []
        if c.command == 176:  # MAV_CMD_DO_SET_MODE
            if _int(p[0]) < 0 or not _int(p[0]) & CUSTOM:
                return UNSUPPORTED, []
            main, sub = _int(p[1]) & 0xFF, _int(p[2]) & 0xFF
            number = main if self.flavour == "ardupilot" else (main << 16) | (sub << 24)
            return self._set_mode_number(number, t), []
        if c.command == 22:  # MAV_CMD_NAV_TAKEOFF
            return self._takeoff(c, t), []
        if c.command == 21:  # MAV_CMD_NAV_LAND
            return self._enter("land", t), []
        if c.command == 20:  # MAV_CMD_NAV_RETURN_TO_LAUNCH
            return self._enter("rtl", t), []
        if c.command == 192:  # MAV_CMD_DO_REPOSITION
            return self._reposition(c, t), []
        if c.command == 511:  # SET_MESSAGE_INTERVAL: accepted, the rates here are fixed
            return ACCEPTED, []
        if c.command in (512, 520):  # REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES
            name = "AUTOPILOT_VERSION" if c.command == 520 else MESSAGE_IDS.get(_int(p[0]))
            if name is None:  # a message this autopilot does not send
                return (DENIED if self.flavour == "px4" else FAILED), []
            return ACCEPTED, [self._message(name, t)]
        return UNSUPPORTED, []

    def _arm(self, action: float, magic: float, t: float) -> int:
        r, forced = self.robot, _int(magic) == 21196
        if action not in (0.0, 1.0):
            return UNSUPPORTED
        if action == 0.0:
            if r.mode not in (Mode.PARKED, Mode.CRASHED) and self.armed:
                if not forced:
                    return self._refused()  # in the air
                for m in range(4):  # a forced disarm in the air stops the motors
                    r.fail_motor(m)
            self.armed = False
            return ACCEPTED
        if self.armed:
            return ACCEPTED
        # ArduPilot skips its arming checks for param2 21196; PX4 runs them anyway for a
        # command that came over MAVLink (Commander: checks when from_external).
        skip_checks = forced and self.flavour == "ardupilot"
        if r.failed_motors or r.mode is Mode.CRASHED or (self.refuse_arm and not skip_checks):
            return self._refused()
        self.armed, self.flew, self.took_off = True, False, False
        self._ground_since = None
        if self.mode == "takeoff" and self.takeoff_alt is not None:
            self._climb(self._px4_takeoff_z(self.takeoff_alt))  # armed in Takeoff: it climbs
        return ACCEPTED

    def _set_mode_number(self, number: int, t: float) -> int:
        name = mode_name(self.flavour, number)
        modes = ("guided", "hold", "land", "rtl") + (
            ("takeoff",) if self.flavour == "px4" else ("brake",))
        if name not in modes:
            return self._refused()  # a mode this simulation does not fly
        if name == "takeoff":
            return self._takeoff(Command(22, (0, 0, 0, math.nan, math.nan, math.nan,
                                              math.nan)), t)
        return self._enter(name, t)

    def _enter(self, name: str, t: float) -> int:
        r = self.robot
        if name == "guided" and self.flavour == "px4" and t - self.last_setpoint > (
                self.param("COM_OF_LOSS_T")):
            return TEMPORARILY_REJECTED  # PX4: no OFFBOARD without a setpoint stream
        if r.failed_motors or r.mode is Mode.CRASHED:
            return self._refused()
        self.mode = name
        self.takeoff_alt = None
        if name in ("land", "rtl"):
            r.release(here=name == "land")
        elif name in ("hold", "brake", "guided") and r.mode in (
                Mode.TAKEOFF, Mode.FLYING, Mode.LANDING) and (
                name != "guided" or self.flavour == "ardupilot"):
            self._go(r.position)  # stop where it is (ArduPilot GUIDED: until told where)
        return ACCEPTED

    def _go(self, position: Vec3) -> bool:
        self.target.position = position
        self.target.velocity = (0.0, 0.0, 0.0)
        return self.robot.fly(self.label, self.target)

    def _climb(self, z: float) -> bool:
        """Straight up to `z` (world frame), at least 0.5 m above the ground."""
        x, y, _ = self.robot.position
        self.took_off = True
        return self._go((x, y, max(z, self.robot.home[2] + 0.5)))

    def _px4_takeoff_z(self, alt: float) -> float:
        """PX4 Navigator's take-off altitude: param7 (m AMSL), or when NaN MIS_TAKEOFF_ALT
        above where the craft is; never below where it is."""
        here = self.robot.position[2]
        z = alt - self.geo_origin[2] if math.isfinite(alt) else (
            here + self.param("MIS_TAKEOFF_ALT"))
        return max(z, here)

    def _takeoff(self, c: Command, t: float) -> int:
        r, alt = self.robot, c.params[6]
        if r.failed_motors or r.mode is Mode.CRASHED:
            return self._refused()
        if self.flavour == "px4":
            # Commander: a mode change to AUTO.TAKEOFF (disarmed, it waits for arming);
            # Navigator: the altitude as `_px4_takeoff_z`.
            self.mode = "takeoff"
            if not self.armed:
                self.takeoff_alt = alt
                return ACCEPTED
            self.takeoff_alt = None
            return ACCEPTED if self._climb(self._px4_takeoff_z(alt)) else FAILED
        if c.frame is not None and c.frame not in (FRAME_GLOBAL_RELATIVE_ALT,
                                                   FRAME_GLOBAL_RELATIVE_ALT_INT):
            return DENIED  # ArduCopter takes param7 as m above home only
        if (self.mode != "guided" or not self.armed or r.mode is not Mode.PARKED
                or not math.isfinite(alt) or alt <= 0):
            return FAILED  # ArduCopter: GUIDED, armed, landed and a height above it
        return ACCEPTED if self._climb(r.home[2] + alt) else FAILED

    def _reposition(self, c: Command, t: float) -> int:
        p, r = c.params, self.robot
        flags = max(_int(p[1]), 0)
        if self.flavour == "px4" and flags != 1:
            return UNSUPPORTED  # Commander: only with the change-mode flag, alone
        if self.flavour == "ardupilot" and self.mode != "guided" and not flags & 1:
            return DENIED
        lat, lon, alt = p[4], p[5], p[6]
        if not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90 or abs(
                lon) > 180:
            return DENIED
        east, north, _ = geodetic_offset(self.geo_origin, (lat, lon, 0.0))
        z = r.position[2]
        if math.isfinite(alt):
            relative = c.frame in (FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_RELATIVE_ALT_INT)
            z = r.home[2] + alt if relative else alt - self.geo_origin[2]
        result = self._enter("hold" if self.flavour == "px4" else "guided", t)
        if result != ACCEPTED:
            return result
        if r.mode in (Mode.TAKEOFF, Mode.FLYING, Mode.LANDING):
            self._go((east, north, z))
        else:  # on the ground it stays there: both firmwares move a flying craft only
            self.target.position = (east, north, z)
        return ACCEPTED

    def _setpoint(self, msg: Any, t: float) -> None:
        self.counters["setpoints"] += 1
        self.last_setpoint = t
        if self.mode != "guided" or not self.armed:
            return
        hx, hy, hz = self.robot.home
        mask = msg.type_mask
        finite = all(map(math.isfinite, (msg.x, msg.y, msg.z)))
        if not mask & 7 and finite:  # position used (a NaN one is ignored, not flown)
            self.target.position = (hx + msg.y, hy + msg.x, hz - msg.z)
        use_velocity = not mask & 56 and all(map(math.isfinite, (msg.vx, msg.vy, msg.vz)))
        self.target.velocity = (msg.vy, msg.vx, -msg.vz) if use_velocity else (0.0, 0.0, 0.0)
        r = self.robot
        on_ground = r.mode is Mode.PARKED
        if self.flavour == "ardupilot" and on_ground and not self.took_off:
            return  # ArduCopter: a position target on the ground waits for NAV_TAKEOFF
        if r.flight is not self.target or r.mode not in (Mode.TAKEOFF, Mode.FLYING):
            r.fly(self.label, self.target)

    # -- parameters and missions ------------------------------------------------------------
    def _param_value(self, name: str) -> Any:
        names = list(self.params)
        p = self.params[name]
        return self.mav.param_value_encode(name.encode(), self._wire(p), p.kind, len(names),
                                           names.index(name))

    def _param_message(self, msg: Any) -> list[Any]:
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            return [self._param_value(n) for n in self.params]
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
        name = name.rstrip("\x00")
        if kind == "PARAM_REQUEST_READ":
            names = list(self.params)
            if msg.param_index >= 0:
                if msg.param_index >= len(names):
                    return []
                name = names[msg.param_index]
            return [self._param_value(name)] if name in self.params else []
        if kind == "PARAM_SET" and name in self.params:
            p = self.params[name]
            if math.isfinite(msg.param_value):
                p.value = self._unwire(msg.param_value, p.kind)
            return [self._param_value(name)]
        return []  # an unknown name: neither firmware answers

    def _mission_count(self, mission_type: int) -> int:
        # ArduPilot's mission always holds home as item 0; PX4's empty mission is empty.
        return 1 if self.flavour == "ardupilot" and mission_type == 0 else 0

    def _mission_item(self, msg: Any, src: int, comp: int) -> list[Any]:
        if msg.seq >= self._mission_count(msg.mission_type):
            # MAV_MISSION_INVALID_SEQUENCE
            return [self.mav.mission_ack_encode(src, comp, 13, msg.mission_type)]
        lat, lon, alt = self.home_geo()
        return [self.mav.mission_item_int_encode(src, comp, 0, FRAME_GLOBAL, 16, 0, 1, 0, 0, 0,
                                                 0, round(lat * 1e7), round(lon * 1e7), alt,
                                                 msg.mission_type)]

    # -- what happens with time ---------------------------------------------------------
    def control(self, t: float) -> None:
        """Mode logic that runs with time: PX4's offboard loss, the end of a take-off,
        auto-disarm on the ground."""
        r = self.robot
        # Retried every tick while a failed craft refuses HOLD: logged once it is in.
        if (self.flavour == "px4" and self.mode == "guided"
                and t - self.last_setpoint > self.param("COM_OF_LOSS_T")
                and self._enter("hold", t) == ACCEPTED):
            log.warning("robot %d: setpoints stopped: OFFBOARD -> HOLD", r.robot_id)
        if self.mode == "takeoff" and self.armed and r.mode is Mode.FLYING and abs(
                r.position[2] - self.target.position[2]) < 0.2:
            self.mode = "hold"
        if not self.armed:
            self._ground_since = None
            return
        if r.mode in (Mode.TAKEOFF, Mode.FLYING, Mode.LANDING):
            self.flew = True
            self._ground_since = None
            return
        if self._ground_since is None:
            self._ground_since = t
        delay = self._disarm_delay()
        if delay is not None and t - self._ground_since >= delay:
            self.armed, self.took_off, self.flew = False, False, False
            log.info("robot %d: landed: disarmed", r.robot_id)

    def _disarm_delay(self) -> float | None:
        """s on the ground before the firmware disarms by itself; None: it does not."""
        if self.flavour == "px4":
            # Commander: COM_DISARM_LAND after a landing, COM_DISARM_PRFLT if it never
            # took off; zero or negative turns either off.
            delay = self.param("COM_DISARM_LAND" if self.flew else "COM_DISARM_PRFLT")
        elif self.robot.mode is Mode.CRASHED:
            delay = 2.0  # ArduCopter's crash check disarms after 2 s
        elif self.flew and self.mode in ("land", "rtl"):
            return 0.0  # LAND (and RTL's final descent) disarm on touch-down
        else:
            delay = self.param("DISARM_DELAY")  # 0 turns it off
        return delay if delay > 0 else None


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, server: MavlinkAutopilot) -> None:
        self.server = server

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.server._datagram(data, (str(addr[0]), int(addr[1])))


class MavlinkAutopilot:
    """The simulated autopilot on its UDP port, over a real-time `QuadLink` (which steps
    the physics and writes the trajectory) or a `PointLink` (no physics). See the module
    docstring."""

    def __init__(self, quad: QuadLink | PointLink, flavour: Flavour, port: int, *,
                 sysid: int | None = None, host: str = "127.0.0.1",
                 peers: Iterable[tuple[str, int]] = (), geo_origin: Vec3 | None = None) -> None:
        self.quad = quad
        self.core = AutopilotCore(quad.robot, flavour, sysid or quad.robot_id,
                                  geo_origin=geo_origin)
        self.host, self.port = host, port
        self.fixed_peers = list(peers)
        self._peers: dict[tuple[str, int], float] = {}
        self._parsers: dict[tuple[str, int], Any] = {}
        self._transport: asyncio.DatagramTransport | None = None
        self._task: asyncio.Task[None] | None = None
        self.counters = {"received": 0, "sent": 0, "bad": 0}

    @property
    def refuse_arm(self) -> bool:
        return self.core.refuse_arm

    @refuse_arm.setter
    def refuse_arm(self, value: bool) -> None:
        self.core.refuse_arm = value

    def fail_motor(self, index: int = 0) -> None:
        self.quad.fail_motor(index)
        self._flush(self.core.telemetry(self.quad.robot.t))

    def set_health(self, health: Health) -> None:
        self.core.forced = max(self.core.forced, health)

    def set_label(self, function: str) -> None:
        """Name the function the craft flies in its trajectory file (MAVLink has none)."""
        self.core.label = function

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        transport, _ = await loop.create_datagram_endpoint(
            lambda: _Udp(self), local_addr=(self.host, self.port))
        self._transport = transport
        self._task = loop.create_task(self._run(), name=f"autopilot{self.core.sysid}")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def _datagram(self, data: bytes, addr: tuple[str, int]) -> None:
        self._peers[addr] = time.monotonic()
        parser = self._parsers.get(addr)
        if parser is None:
            parser = self._parsers[addr] = mavlink2.MAVLink(None, srcSystem=self.core.sysid,
                                                           srcComponent=1)
            parser.robust_parsing = True
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception:  # garbage on the port must not stop the autopilot
            self.counters["bad"] += 1
            return
        self.quad.catch_up()
        t = self.quad.robot.t
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.counters["bad"] += 1
                continue
            self.counters["received"] += 1
            try:
                replies = self.core.handle(msg, t)
            except Exception as exc:  # one odd message must not stop the autopilot
                self.counters["bad"] += 1
                log.warning("autopilot %d: %s from %s:%d not handled: %r", self.core.sysid,
                            msg.get_type(), addr[0], addr[1], exc)
                continue
            self._flush(replies)

    def _flush(self, msgs: list[Any]) -> None:
        if self._transport is None or not msgs:
            return
        now = time.monotonic()
        peers = [a for a, seen in self._peers.items() if now - seen < PEER_TIMEOUT]
        peers += [p for p in self.fixed_peers if p not in peers]
        for m in msgs:
            data = m.pack(self.core.mav)
            for addr in peers:
                with contextlib.suppress(OSError):
                    self._transport.sendto(data, addr)
                    self.counters["sent"] += 1

    async def _run(self) -> None:
        while True:
            await asyncio.sleep(TICK)
            self.quad.catch_up()
            t = self.quad.robot.t
            self.core.control(t)
            self._flush(self.core.telemetry(t))


async def start_autopilot(quad: QuadLink | PointLink, flavour: Flavour, port: int,
                          **kwargs: Any) -> MavlinkAutopilot:
    """Start `quad` (real-time physics) and its autopilot on UDP `port` of loopback."""
    if not quad.running:
        await quad.start(lambda h: None)  # health goes out as MAVLink, not to a daemon
    ap = MavlinkAutopilot(quad, flavour, port, **kwargs)
    await ap.start()
    return ap


def link_config(port: int, flavour: Flavour, home: Vec3, *,
                release: Release = "rtl") -> dict[str, Any]:
    """The robot file's `link:` section for a daemon flying this simulated autopilot
    (swarmd.config.robot.MavlinkLinkConfig)."""
    return {"kind": "mavlink", "url": f"udpout:127.0.0.1:{port}", "autopilot": flavour,
            "target_system": None, "origin": [home[0], home[1], home[2]],
            "release": release, "takeoff_altitude": 1.0}


class SimMavlinkLink:
    """A `RobotLink` for the simulator: the daemon's `MavlinkLink` talking over loopback
    UDP to a simulated autopilot flying a MuJoCo craft, all in the robot's process.
    `fail_motor` / `set_health` / `refuse_arm` act on the autopilot: the daemon learns
    of them only through MAVLink."""

    def __init__(self, quad: QuadLink, flavour: Flavour, port: int, *,
                 release: Release = "rtl", refuse_arm: bool = False,
                 heartbeat_timeout: float = 3.0,
                 wall: Callable[[], float] = time.time) -> None:
        self.quad = quad
        self.flavour = flavour
        self.port = port
        home = quad.home
        from swarmd.link.mavlink_health import Thresholds

        self.link = MavlinkLink(
            f"udpout:127.0.0.1:{port}", source_system=quad.robot_id, pilot=PilotConfig(
                flavour=flavour, target_system=quad.robot_id, origin=home, release=release,
                takeoff_altitude=1.0, t0=quad.restart_of,
                health=Thresholds(heartbeat_timeout=heartbeat_timeout)),
            wall=wall)
        self.autopilot: MavlinkAutopilot | None = None
        self._refuse_arm = refuse_arm

    @classmethod
    def for_robot(cls, cfg: Any, flavour: Flavour, port: int,
                  restart_of: float | None = None, craft: str | None = None,
                  **kwargs: Any) -> SimMavlinkLink:
        """From a loaded robot file, as `QuadLink.for_robot` (home, trajectory file,
        `craft` preset, `restart_of`); `kwargs` go to the constructor."""
        return cls(QuadLink.for_robot(cfg, restart_of=restart_of, craft=craft), flavour,
                   port, **kwargs)

    async def start(self, on_health: HealthCallback) -> None:
        self.autopilot = await start_autopilot(self.quad, self.flavour, self.port)
        self.autopilot.refuse_arm = self._refuse_arm
        await self.link.start(on_health)

    def assign(self, function: str, epoch: int, params: Any) -> None:
        if self.autopilot is not None:
            self.autopilot.set_label(function)  # the trajectory file's label only
        self.link.assign(function, epoch, params)

    def release(self, function: str) -> None:
        self.link.release(function)

    def fail_motor(self, index: int = 0) -> None:
        if self.autopilot is not None:
            self.autopilot.fail_motor(index)

    def set_health(self, health: Health) -> None:
        if self.autopilot is not None:
            self.autopilot.set_health(health)

    async def close(self) -> None:
        await self.link.close()
        if self.autopilot is not None:
            await self.autopilot.close()
        await self.quad.close()
