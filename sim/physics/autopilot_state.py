"""The simulated autopilot's state and what it says on its own (`sim.physics.autopilot`
has the whole picture): its parameters, status, telemetry streams (at the rates of
`autopilot_rates.Streams`), the answers to the parameter protocol, and its mission
(`autopilot_mission.MissionStore`). `AutopilotState` is the base of
`sim.physics.autopilot_flight.AutopilotFlight` (what it does with time) and
`sim.physics.autopilot_core.AutopilotCore` (what it does when told); this module knows
nothing of those.
"""

from __future__ import annotations

import math
import struct
import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.autopilot_mission import Item, MissionRunner, MissionStore
from sim.physics.autopilot_nav import PathTarget
from sim.physics.autopilot_params import SR0_GROUPS, default_params
from sim.physics.autopilot_rates import Streams
from sim.physics.mavlink_defs import (
    ALL_SENSORS,
    ARMED,
    AUTO,
    CAPABILITIES,
    CUSTOM,
    FAILED,
    FRAME_GLOBAL,
    GEO_ORIGIN,
    GUIDED,
    INT8,
    INT16,
    INT32,
    MANUAL_INPUT,
    MOTORS,
    PREARM,
    REAL32,
    STABILIZE,
    STATE_ACTIVE,
    STATE_CRITICAL,
    STATE_EMERGENCY,
    STATE_STANDBY,
    TEMPORARILY_REJECTED,
    VERSION,
    Param,
    geodetic,
)
from sim.physics.point import PointRobot
from sim.physics.robot import Mode, QuadRobot
from swarmd.base.functions import Vec3
from swarmd.core.roles import Health
from swarmd.link.mavlink_modes import Flavour, custom_mode

_LANDED_STATE = {Mode.PARKED: 1, Mode.CRASHED: 1, Mode.FLYING: 2, Mode.TAKEOFF: 3,
                 Mode.LANDING: 4}
"""MAV_LANDED_STATE of each flight mode of the craft (EXTENDED_SYS_STATE)."""
_EKF_FLAGS = 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512
_LIMIT = {INT8: 128, INT16: 32768, INT32: 2 ** 31}
"""The range of each integer parameter type: a value set beyond it is clamped."""
"""EKF_STATUS_REPORT / ESTIMATOR_STATUS flags: attitude, velocities and positions good."""


class AutopilotState:
    """What the autopilot over one craft (`QuadRobot`, or `PointRobot` without physics)
    is and says, on the craft's clock; sans-I/O. `AutopilotCore` is the whole logic."""

    def __init__(self, robot: QuadRobot | PointRobot, flavour: Flavour, sysid: int, *,
                 geo_origin: Vec3 | None = None) -> None:
        self.robot = robot
        self.flavour = flavour
        self.sysid = sysid
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.geo_origin = geo_origin or GEO_ORIGIN[flavour]
        self.streams = Streams(flavour)
        self.params = default_params(flavour, sysid, self.streams.sr0_params())
        self.armed = False
        self.mode = "hold" if flavour == "px4" else "stabilize"
        """What each firmware boots in without RC: PX4 Hold, ArduCopter Stabilize."""
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
        self.target = PathTarget(robot.position, lambda: robot.t)
        self.mission = MissionStore(flavour, self.mav, self._home_item)
        self.runner = MissionRunner(self.mission)
        self.outbox: list[Any] = []
        """Messages sent with the next telemetry (events: STATUSTEXT, mission progress)."""
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
            if self.mode in ("guided", "hold", "brake", "rtl", "auto"):
                base |= GUIDED
        return base | (ARMED if self.armed else 0)

    def heartbeat(self) -> Any:
        return self.mav.heartbeat_encode(2, 12 if self.flavour == "px4" else 3,
                                         self.base_mode(), custom_mode(self.flavour, self.mode),
                                         self.system_status())

    def telemetry(self, t: float) -> list[Any]:
        """The events since last time, then the messages due at robot time `t`."""
        out, self.outbox = self.outbox, []
        status = (self.system_status(), self.sensors_health())
        changed = status != self._reported
        self._reported = status
        now = ("HEARTBEAT", "SYS_STATUS") if changed else ()
        return out + [self._message(name, t) for name in self.streams.due(t, now)]

    def say(self, text: str, severity: int = 4) -> None:
        """A STATUSTEXT (severity 4 WARNING, 2 CRITICAL, 6 INFO) with the next messages,
        as both firmwares explain a refusal or an event to the ground station."""
        self.outbox.append(self.mav.statustext_encode(severity, text.encode()[:50]))

    def _message(self, name: str, t: float) -> Any:
        """The message `name` (a streamed one, one of MESSAGE_IDS, or AUTOPILOT_VERSION)
        at robot time `t`."""
        mav = self.mav
        match name:
            case "HEARTBEAT":
                return self.heartbeat()
            case "SYS_STATUS":
                return self._sys_status()
            case "BATTERY_STATUS":
                return mav.battery_status_encode(0, 1, 1, 2500, [4000] * 3 + [65535] * 7, -1,
                                                 -1, -1, self._battery_percent())
            case "LOCAL_POSITION_NED":
                (n, e, d), (vn, ve, vd) = self.local_ned()
                return mav.local_position_ned_encode(self._time_ms(t), n, e, d, vn, ve, vd)
            case "ATTITUDE":
                roll, pitch, yaw = self._euler()
                return mav.attitude_encode(self._time_ms(t), roll, pitch, yaw, 0, 0, 0)
            case "GLOBAL_POSITION_INT":
                return self._global_position(t)
            case "GPS_RAW_INT":
                return self._gps_raw(t)
            case "EXTENDED_SYS_STATE":
                return mav.extended_sys_state_encode(0, _LANDED_STATE[self.robot.mode])
            case "HOME_POSITION" | "GPS_GLOBAL_ORIGIN":
                return self._home_message(name)
            case "MISSION_CURRENT":
                return self.mission_current()
            case "VFR_HUD":
                return self._vfr_hud()
            case "AUTOPILOT_VERSION":
                return mav.autopilot_version_encode(
                    CAPABILITIES[self.flavour], VERSION[self.flavour], 0, 0, 0, [0] * 8,
                    [0] * 8, [0] * 8, 0, 0, self.sysid)
        return self._estimator(t)

    def _battery_percent(self) -> int:
        return max(0, min(100, round(100 * self.robot.battery)))

    def _sys_status(self) -> Any:
        # The pre-arm bit: present and enabled (the checks run), healthy while they
        # pass and whenever armed (both firmwares, and MAVLink's definition).
        ready = self.armed or self.armable()
        health = self.sensors_health() | (PREARM if ready else 0)
        return self.mav.sys_status_encode(ALL_SENSORS | PREARM, ALL_SENSORS | PREARM, health,
                                          200, int(11100 + 1500 * self.robot.battery), -1,
                                          self._battery_percent(), 0, 0, 0, 0, 0, 0)

    def _global_position(self, t: float) -> Any:
        r = self.robot
        (x, y, z), (vx, vy, vz) = r.position, r.velocity
        lat, lon, alt = geodetic(self.geo_origin, x, y, z)
        heading = round(math.degrees(self._euler()[2]) % 360 * 100)
        return self.mav.global_position_int_encode(
            self._time_ms(t), round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
            round((z - r.home[2]) * 1000), round(vy * 100), round(vx * 100),
            round(-vz * 100), heading)

    def _gps_raw(self, t: float) -> Any:
        (x, y, z), (vx, vy, _) = self.robot.position, self.robot.velocity
        lat, lon, alt = geodetic(self.geo_origin, x, y, z)
        ground = math.hypot(vx, vy)
        cog = round(math.degrees(math.atan2(vx, vy)) % 360 * 100) if ground > 0.1 else 65535
        return self.mav.gps_raw_int_encode(int(t * 1e6), 3, round(lat * 1e7), round(lon * 1e7),
                                           round(alt * 1000), 80, 120, round(ground * 100),
                                           cog, 12)

    def _home_message(self, name: str) -> Any:
        lat, lon, alt = self.home_geo()
        if name == "GPS_GLOBAL_ORIGIN":  # the EKF origin is home (where it powered up)
            return self.mav.gps_global_origin_encode(round(lat * 1e7), round(lon * 1e7),
                                                     round(alt * 1000))
        return self.mav.home_position_encode(round(lat * 1e7), round(lon * 1e7),
                                             round(alt * 1000), 0.0, 0.0, 0.0,
                                             [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    def _estimator(self, t: float) -> Any:
        """ArduPilot's EKF_STATUS_REPORT, PX4's ESTIMATOR_STATUS."""
        if self.flavour == "ardupilot":
            return self.mav.ekf_status_report_encode(_EKF_FLAGS, 0.02, 0.02, 0.02, 0.02, 0.0)
        return self.mav.estimator_status_encode(int(t * 1e6), _EKF_FLAGS, 0.02, 0.02, 0.02,
                                                0.02, 0, 0, 0.5, 0.5)

    def _euler(self) -> Vec3:
        """Roll, pitch and yaw in NED (yaw from north, clockwise)."""
        w, x, y, z = self.robot.attitude
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
        yaw_enu = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        # ENU yaw (from east, counter-clockwise) to NED heading (from north, clockwise)
        return (roll, -pitch, math.atan2(math.cos(yaw_enu), math.sin(yaw_enu)))

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
        if kind != "PARAM_SET":
            return []
        if name not in self.params:  # PX4 says so (`mavlink_parameters.cpp`); ArduPilot not
            if self.flavour == "px4":
                self.say(f"[pm] unknown param: {name}", 6)
            return []
        p = self.params[name]
        if math.isfinite(msg.param_value):
            value = self._unwire(msg.param_value, p.kind)
            p.value = value if p.kind == REAL32 else float(max(-_LIMIT[p.kind], min(
                _LIMIT[p.kind] - 1, value)))
            if name in SR0_GROUPS:  # ArduPilot: the group's stream rate
                self.streams.set_group(SR0_GROUPS[name], p.value)
        return [self._param_value(name)]

    def set_stream_group(self, stream_id: int, hz: float) -> None:
        """ArduPilot's REQUEST_DATA_STREAM: the group's rate and its SR0_ parameter."""
        for name in self.streams.set_group(stream_id, hz):
            self.params[name].value = float(round(self.streams.sr0_params()[name]))

    # -- the mission as it is reported -------------------------------------------------
    def _home_item(self) -> Item:
        """ArduPilot's mission item 0: home, a NAV_WAYPOINT in the global frame."""
        lat, lon, alt = self.home_geo()
        return Item(FRAME_GLOBAL, 16, 1, (0.0, 0.0, 0.0, 0.0), round(lat * 1e7),
                    round(lon * 1e7), alt)

    def mission_current(self) -> Any:
        """MISSION_CURRENT: the current item, the count (without ArduPilot's home), the
        mission's state and whether the autopilot is in its mission mode."""
        m = self.mission
        total = len(m.listed()) - m.first
        state = 1 if total <= 0 else self.runner.state
        in_mission = self.mode in ("mission", "auto")
        return self.mav.mission_current_encode(min(m.current, max(total - 1 + m.first, 0)),
                                               max(total, 0), state, 1 if in_mission else 2)

    def _vfr_hud(self) -> Any:
        (vn, ve, vd) = self.local_ned()[1]
        heading = round(math.degrees(self._euler()[2])) % 360
        z = self.robot.position[2]
        throttle = 0 if self.robot.mode in (Mode.PARKED, Mode.CRASHED) else 50
        return self.mav.vfr_hud_encode(math.hypot(vn, ve), math.hypot(vn, ve), heading,
                                       throttle, self.geo_origin[2] + z, -vd)
