"""The simulated autopilot's logic (`sim.physics.autopilot` has the whole picture): what
it does with each message a peer sends (commands, mode changes, setpoints, the parameter
and mission protocols) and what happens with time (PX4's offboard loss, the end of a
take-off, auto-disarm on the ground). Sans-I/O: `sim.physics.autopilot.MavlinkAutopilot`
moves the bytes.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from sim.physics.autopilot_state import AutopilotState
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
from swarmd.functions import Vec3
from swarmd.link.mavlink_modes import mode_name
from swarmd.link.mavlink_pilot import geodetic_offset

# The endpoint's logger too: one name for everything the simulated autopilot logs.
log = logging.getLogger("swarmd.sim.autopilot")


class AutopilotCore(AutopilotState):
    """The autopilot's logic over one craft (`QuadRobot`, or `PointRobot` without
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
            if command_int(p[0]) < 0 or not command_int(p[0]) & CUSTOM:
                return UNSUPPORTED, []
            main, sub = command_int(p[1]) & 0xFF, command_int(p[2]) & 0xFF
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
            name = ("AUTOPILOT_VERSION" if c.command == 520
                    else MESSAGE_IDS.get(command_int(p[0])))
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
        flags = max(command_int(p[1]), 0)
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
