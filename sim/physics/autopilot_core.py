"""The simulated autopilot's answers (`sim.physics.autopilot` has the whole picture): what
it does with each message a peer sends (commands, mode changes, setpoints, the parameter
and mission protocols, message rates). What it does with time is
`sim.physics.autopilot_flight`'s. Sans-I/O: `sim.physics.autopilot.MavlinkAutopilot`
moves the bytes.
"""

from __future__ import annotations

import logging
import math
import struct
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.autopilot_flight import AutopilotFlight
from sim.physics.autopilot_mission import ACTIVE, COMPLETE, NOT_STARTED
from sim.physics.autopilot_nav import Leg
from sim.physics.mavlink_defs import (
    ACCEPTED,
    CUSTOM,
    DENIED,
    FAILED,
    FRAME_GLOBAL_RELATIVE_ALT,
    FRAME_GLOBAL_RELATIVE_ALT_INT,
    MESSAGE_IDS,
    TEMPORARILY_REJECTED,
    UNSUPPORTED,
    Command,
    command_int,
)
from sim.physics.robot import Mode
from swarmd.base.functions import Vec3
from swarmd.link.mavlink_modes import mode_name
from swarmd.link.mavlink_pilot import geodetic_offset

# The endpoint's logger too: one name for everything the simulated autopilot logs.
log = logging.getLogger("swarmd.sim.autopilot")


_MODES = {"px4": ("guided", "hold", "land", "rtl", "takeoff", "mission"),
          "ardupilot": ("guided", "hold", "land", "rtl", "brake", "auto", "stabilize")}
"""The modes each flavour flies; others (manual and RC modes) are refused as a mode the
firmware cannot enter now (no RC: PX4's position modes; ArduCopter's ACRO, ALT_HOLD...)."""
_APM_NOT_ARMABLE = ("auto", "rtl", "land", "brake")
"""ArduCopter modes that refuse arming (`mode.h` allows_arming)."""


class AutopilotCore(AutopilotFlight):
    """The autopilot's answers over one craft (`QuadRobot`, or `PointRobot` without
    physics): messages in, messages out, on the craft's clock. Sans-I/O (the server in
    `sim.physics.autopilot` moves the bytes). docs/mavlink.md tabulates every answer and
    the firmware behaviour it follows."""

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
        if kind.startswith("SET_POSITION_TARGET_"):
            self._setpoint(msg, t)
        elif kind.startswith("PARAM_"):
            return self._param_message(msg)
        elif kind.startswith("MISSION_"):
            return self._mission_message(msg, t)
        elif kind == "HEARTBEAT":
            self._heard(msg, src, t)
        elif kind == "REQUEST_DATA_STREAM" and self.flavour == "ardupilot":
            # PX4 ignores the deprecated message; ArduPilot sets the group's rate.
            self.set_stream_group(msg.req_stream_id,
                                  msg.req_message_rate if msg.start_stop else 0)
        elif (kind == "PING" and self.flavour == "px4" and msg.target_system == 0
              and msg.target_component == 0):  # ArduPilot answers TIMESYNC, not PING
            return [self.mav.ping_encode(msg.time_usec, msg.seq, src, comp)]
        elif kind == "TIMESYNC" and msg.tc1 == 0:  # a request: our clock, their stamp
            return [self.mav.timesync_encode(int(t * 1e9), msg.ts1)]
        return []

    def _heard(self, msg: Any, src: int, t: float) -> None:
        """A ground station's HEARTBEAT keeps the data link alive (ArduPilot counts only
        SYSID_MYGCS's, `GCS_Common.cpp` handle_heartbeat)."""
        if msg.type == 6 and (self.flavour == "px4" or src == self.param("SYSID_MYGCS")):
            self.last_gcs = t

    def _mission_message(self, msg: Any, t: float) -> list[Any]:
        if msg.get_type() == "MISSION_SET_CURRENT":
            return self._set_current(msg.seq)
        before = self.mission.version
        replies = self.mission.handle(msg, t)
        if self.mission.version != before and self.mode in ("mission", "auto"):
            self.legs = []  # a new mission: flown from its first item
            self.runner.start()
        return replies

    def _set_current(self, seq: int) -> list[Any]:
        """MISSION_SET_CURRENT (and DO_SET_MISSION_CURRENT): MISSION_CURRENT either way;
        PX4 also says when the item does not exist (`mavlink_mission.cpp`)."""
        if self.mission.set_current(seq):
            if self.mode in ("mission", "auto"):
                self.legs, self.runner.state = [], ACTIVE  # flown from that item now
            elif self.runner.state == COMPLETE:
                self.runner.state = NOT_STARTED  # entered later, it starts there
        elif self.flavour == "px4":
            self.say("WPM: WP CURR CMD: Not in range")
        self._reported_current = self.mission.current
        return [self.mission_current()]

    def _command(self, c: Command, t: float) -> tuple[int, list[Any]]:
        p = c.params
        match c.command:
            case 400:  # MAV_CMD_COMPONENT_ARM_DISARM
                return self._arm(p[0], p[1], t), []
            case 176:  # MAV_CMD_DO_SET_MODE
                if command_int(p[0]) < 0 or not command_int(p[0]) & CUSTOM:
                    return UNSUPPORTED, []
                main, sub = command_int(p[1]) & 0xFF, command_int(p[2]) & 0xFF
                number = main if self.flavour == "ardupilot" else (main << 16) | (sub << 24)
                return self._set_mode_number(number, t), []
            case 22:  # MAV_CMD_NAV_TAKEOFF
                return self._takeoff(c, t), []
            case 21:  # MAV_CMD_NAV_LAND
                return self._enter("land", t), []
            case 20:  # MAV_CMD_NAV_RETURN_TO_LAUNCH
                return self._enter("rtl", t), []
            case 192:  # MAV_CMD_DO_REPOSITION
                return self._reposition(c, t), []
            case 300:  # MAV_CMD_MISSION_START
                return self._mission_start(p[0], p[1], t), []
            case 224:  # MAV_CMD_DO_SET_MISSION_CURRENT
                ok = self.mission.set_current(command_int(p[0]))
                return (ACCEPTED if ok else DENIED), self._set_current(command_int(p[0]))
            case 178:  # MAV_CMD_DO_CHANGE_SPEED
                return self._change_speed(p[1]), []
            case 193:  # MAV_CMD_DO_PAUSE_CONTINUE
                return self._pause(p[0], t), []
        return self._message_command(c, t)

    def _message_command(self, c: Command, t: float) -> tuple[int, list[Any]]:
        """The commands about messages: their rates, one on request, the protocol
        version."""
        p = c.params
        if c.command == 511:  # MAV_CMD_SET_MESSAGE_INTERVAL
            result = self.streams.set_interval(command_int(p[0]), p[1], (p[2], p[3], p[6]))
            if result == DENIED:  # ArduPilot says why (`GCS_Common.cpp`)
                self.say(f"No ap_message for mavlink id ({command_int(p[0])})", 6)
            return result, []
        if c.command == 510:  # MAV_CMD_GET_MESSAGE_INTERVAL
            result, interval = self.streams.get_interval(command_int(p[0]))
            return result, ([] if interval is None else [
                self.mav.message_interval_encode(command_int(p[0]) & 0xFFFF, interval)])
        if c.command == 519:  # MAV_CMD_REQUEST_PROTOCOL_VERSION: PX4 only
            if self.flavour == "px4":
                return ACCEPTED, [ProtocolVersion()]
            return UNSUPPORTED, []
        if c.command in (512, 520):  # REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES
            name = ("AUTOPILOT_VERSION" if c.command == 520
                    else MESSAGE_IDS.get(command_int(p[0])))
            if name is not None and name.startswith(("EKF_", "ESTIMATOR_")):
                name = name if self.streams.streamable(command_int(p[0])) else None
            if name is None:  # a message this autopilot does not send
                return (DENIED if self.flavour == "px4" else FAILED), []
            return ACCEPTED, [self._message(name, t)]
        return UNSUPPORTED, []

    def _arm(self, action: float, magic: float, t: float) -> int:
        r, forced = self.robot, command_int(magic) == 21196
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
        if self.flavour == "ardupilot" and self.mode in _APM_NOT_ARMABLE and not skip_checks:
            self.say("Arm: Mode not armable")  # `AP_Arming_Copter.cpp` mandatory_checks
            return self._refused()
        self.armed, self.flew, self.took_off = True, False, False
        self._ground_since = None
        if self.mode == "takeoff" and self.takeoff_alt is not None:
            self._climb(self._px4_takeoff_z(self.takeoff_alt))  # armed in Takeoff: it climbs
        return ACCEPTED

    def _set_mode_number(self, number: int, t: float) -> int:
        name = mode_name(self.flavour, number)
        if name not in _MODES[self.flavour]:
            return self._refused()  # a mode this simulation does not fly (RC, acro...)
        if name == "takeoff":
            return self._takeoff(Command(22, (0, 0, 0, math.nan, math.nan, math.nan,
                                              math.nan)), t)
        return self._enter(name, t)

    def _px4_takeoff_z(self, alt: float) -> float:
        """PX4 Navigator's take-off altitude (`navigator/takeoff.cpp`
        set_takeoff_position): param7 (m AMSL) but never below MIS_TAKEOFF_ALT above home,
        MIS_TAKEOFF_ALT above home when NaN, never below where the craft is; each case
        said in a STATUSTEXT as PX4 says it."""
        here = self.robot.position[2]
        least = self.robot.home[2] + self.param("MIS_TAKEOFF_ALT")
        said = f"Using minimum takeoff altitude: {self.param('MIS_TAKEOFF_ALT'):.2f} m"
        if not math.isfinite(alt):
            z = least
            self.say(said, 6)  # info: the usual case, not a complaint
        else:
            z = alt - self.geo_origin[2]
            if z < least - 0.1:  # PX4 does not complain under 10 cm
                self.say(said, 2)
            z = max(z, least)
        if z < here:
            self.say("Already higher than takeoff altitude", 2)
        return max(z, here)

    def _takeoff(self, c: Command, t: float) -> int:
        r, alt = self.robot, c.params[6]
        if r.failed_motors or r.mode is Mode.CRASHED:
            return self._refused()
        self.legs = []  # a take-off replaces what the craft was flying
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
        flags = max(command_int(p[1]), 0)
        if self.flavour == "px4" and flags != 1:
            return UNSUPPORTED  # Commander: only with the change-mode flag, alone
        if self.flavour == "ardupilot" and self.mode != "guided" and not flags & 1:
            return DENIED
        goal = self._reposition_goal(c)
        if goal is None:
            return DENIED
        result = self._enter("hold" if self.flavour == "px4" else "guided", t)
        if result != ACCEPTED:
            return result
        if r.mode in (Mode.TAKEOFF, Mode.FLYING, Mode.LANDING):
            self._start([Leg(goal, self.speeds(), hold=math.inf)])
        else:  # on the ground it stays there: both firmwares move a flying craft only
            self.target.position = goal
        return ACCEPTED

    def _reposition_goal(self, c: Command) -> Vec3 | None:
        """Where a DO_REPOSITION goes (world frame); None: bad coordinates. PX4 keeps the
        craft's latitude and longitude when they are NaN (QGroundControl's "pause" and
        "change altitude", `navigator_main.cpp`); ArduPilot refuses them, and 0, 0."""
        lat, lon, alt = c.params[4], c.params[5], c.params[6]
        r = self.robot
        x, y, z = r.position
        if self.flavour == "px4" and math.isnan(lat) and math.isnan(lon):
            pass
        elif not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90 or abs(
                lon) > 180 or (self.flavour == "ardupilot" and lat == 0 and lon == 0):
            return None
        else:
            x, y, _ = geodetic_offset(self.geo_origin, (lat, lon, 0.0))
        if math.isfinite(alt):
            relative = c.frame in (FRAME_GLOBAL_RELATIVE_ALT, FRAME_GLOBAL_RELATIVE_ALT_INT)
            z = r.home[2] + alt if relative else alt - self.geo_origin[2]
        return (x, y, z)

    def _mission_start(self, first: float, last: float, t: float) -> int:
        """MAV_CMD_MISSION_START: AUTO for ArduPilot, armed only, and it refuses first and
        last items (`GCS_Mavlink.cpp` handle_command_mission_start); PX4's as
        `_px4_mission_start`."""
        if self.flavour == "px4":
            return self._px4_mission_start(first, t)
        if first != 0 or last != 0:
            return DENIED
        if not self.armed:
            return FAILED  # ArduCopter starts a mission armed only
        return ACCEPTED if self._enter("auto", t) == ACCEPTED else FAILED

    def _px4_mission_start(self, first: float, t: float) -> int:
        """PX4's Commander (VEHICLE_CMD_MISSION_START): no mission to fly, or param1
        not an item (nor -1, the current one), is DENIED; else Mission mode AND arming,
        so the craft on the ground takes off by itself (a ground station starts a
        mission with this one command). Arming refused: TEMPORARILY_REJECTED, the mode
        already Mission. Navigator flies from item param1 when it is 0 or more."""
        if not self.runner.flyable():
            self.say("Mission start denied! No valid mission", 2)
            return DENIED
        if not (math.isfinite(first) and -1 <= first < len(self.mission.listed())):
            return DENIED
        if first >= 0:
            self.mission.set_current(int(first))
        if self._enter("mission", t) != ACCEPTED or self._arm(1.0, 0.0, t) != ACCEPTED:
            self.say("Switching to Mission is currently not available", 2)
            return TEMPORARILY_REJECTED
        return ACCEPTED

    def _change_speed(self, speed: float) -> int:
        """DO_CHANGE_SPEED param2 (m/s) for the legs of the present mode: PX4 in any mode
        (-1: no change); ArduCopter in AUTO, GUIDED and RTL, a positive speed."""
        if self.flavour == "ardupilot" and (self.mode not in ("auto", "guided", "rtl")
                                            or not speed > 0):
            return FAILED
        if speed > 0 and math.isfinite(speed):
            self.speed_xy = self.runner.speed = speed
            self.legs = [Leg(leg.goal, self.speeds(), leg.radius, leg.hold, leg.seq)
                         for leg in self.legs]
            self._leg_started = False  # the present leg again, at the new speed
        return ACCEPTED

    def _pause(self, action: float, t: float) -> int:
        """DO_PAUSE_CONTINUE: ArduCopter stops where it is in AUTO, GUIDED and RTL and
        goes on with 1; PX4 has no such command (QGroundControl pauses it with a
        DO_REPOSITION to where it is)."""
        if self.flavour == "px4":
            return UNSUPPORTED
        if self.mode not in ("auto", "guided", "rtl") or self.robot.mode not in (
                Mode.TAKEOFF, Mode.FLYING):
            return FAILED
        if action == 0:
            if self.legs:
                self._paused, self.legs = self.legs, []
            self._go(self.robot.position)
        elif action == 1:
            self._start(self._paused or self.legs)
            self._paused = []
        else:
            return DENIED
        return ACCEPTED

    def _setpoint(self, msg: Any, t: float) -> None:
        """SET_POSITION_TARGET_LOCAL_NED (LOCAL_NED; ArduPilot also LOCAL_OFFSET_NED,
        BODY_NED and BODY_OFFSET_NED, relative to the craft) or _GLOBAL_INT (GLOBAL_INT,
        GLOBAL_RELATIVE_ALT_INT), in OFFBOARD / GUIDED."""
        self.counters["setpoints"] += 1
        self.last_setpoint = t
        if self.mode != "guided" or not self.armed:
            return
        position, velocity = self._setpoint_world(msg)
        if position is not None:
            self.legs = []  # a setpoint replaces a goto's leg
            self.target.hold(position, self.target.velocity)
        self.target.velocity = velocity
        r = self.robot
        if self.flavour == "ardupilot" and r.mode is Mode.PARKED and not self.took_off:
            return  # ArduCopter: a position target on the ground waits for NAV_TAKEOFF
        if r.flight is not self.target or r.mode not in (Mode.TAKEOFF, Mode.FLYING):
            r.fly(self.label, self.target)

    def _setpoint_world(self, msg: Any) -> tuple[Vec3 | None, Vec3]:
        """A setpoint's position (None: not given, or in a frame not flown) and velocity
        in the world frame (x east, y north, z up)."""
        mask, frame, r = msg.type_mask, msg.coordinate_frame, self.robot
        is_global = msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"
        finite = math.isfinite(msg.alt) if is_global else all(
            map(math.isfinite, (msg.x, msg.y, msg.z)))
        use_velocity = not mask & 56 and all(map(math.isfinite, (msg.vx, msg.vy, msg.vz)))
        vn, ve, vd = (msg.vx, msg.vy, msg.vz) if use_velocity else (0.0, 0.0, 0.0)
        velocity = (ve, vn, -vd)
        if mask & 7 or not finite:  # position not used (a NaN one is ignored, not flown)
            return None, velocity
        if is_global:
            if frame not in (5, 6):
                return None, velocity  # the terrain frame: no terrain here
            x, y, _ = geodetic_offset(self.geo_origin, (msg.lat_int / 1e7, msg.lon_int / 1e7,
                                                        0.0))
            z = r.home[2] + msg.alt if frame == 6 else msg.alt - self.geo_origin[2]
            return (x, y, z), velocity
        hx, hy, hz = r.home
        if frame == 1:
            return (hx + msg.y, hy + msg.x, hz - msg.z), velocity
        if self.flavour == "px4" or frame not in (7, 8, 9):
            return None, velocity  # PX4 flies positions in LOCAL_NED only
        north, east = msg.x, msg.y
        if frame in (8, 9):  # body frames: forward, right of the heading
            yaw = self._euler()[2]
            north = msg.x * math.cos(yaw) - msg.y * math.sin(yaw)
            east = msg.x * math.sin(yaw) + msg.y * math.cos(yaw)
        x, y, z = r.position
        return (x + east, y + north, z - msg.z), velocity


class ProtocolVersion(mavlink2.MAVLink_message):  # type: ignore[misc]
    """PROTOCOL_VERSION (id 300), which pymavlink's dialects lack: PX4 answers
    MAV_CMD_REQUEST_PROTOCOL_VERSION with MAVLink 2 (version 200, from 100 to 200;
    `mavlink_main.cpp` send_protocol_version). Hashes zero: no git hashes here."""

    CRC_EXTRA = 217
    """From the message's fields, as MAVLink computes it (common.xml)."""

    def __init__(self) -> None:
        super().__init__(300, "PROTOCOL_VERSION")
        self._fieldnames = ["version", "min_version", "max_version", "spec_version_hash",
                            "library_version_hash"]
        self.version, self.min_version, self.max_version = 200, 100, 200
        self.spec_version_hash = self.library_version_hash = [0] * 8

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        payload = struct.pack("<HHH8B8B", self.version, self.min_version, self.max_version,
                              *self.spec_version_hash, *self.library_version_hash)
        packed: bytes = self._pack(mav, self.CRC_EXTRA, payload, force_mavlink1=force_mavlink1)
        return packed
