"""What the simulated autopilot does with time (`sim.physics.autopilot` has the whole
picture): its modes and the legs it flies in them (a goto, a Return, the mission's
items; `autopilot_nav`), the end of a take-off, PX4's offboard loss, the ground
station's data-link loss failsafe, and auto-disarm on the ground. `AutopilotCore`
(`sim.physics.autopilot_core`) adds what it does when told.

Data-link loss (PX4 NAV_DLL_ACT after COM_DL_LOSS_T, `commander/Commander.cpp`
data_link_check; ArduCopter FS_GCS_ENABLE after FS_GCS_TIMEOUT, `ArduCopter/events.cpp`
failsafe_gcs_check): armed and in the air, once a ground station's HEARTBEAT was heard
(ArduPilot: from system SYSID_MYGCS) and then stops, the craft holds, returns or lands
as the parameter says. Both are off by default, as in the firmware.
"""

from __future__ import annotations

import logging
import math

from sim.physics.autopilot_mission import ACTIVE, Where
from sim.physics.autopilot_nav import Leg, Speeds, rtl_legs
from sim.physics.autopilot_state import AutopilotState
from sim.physics.mavlink_defs import ACCEPTED, TEMPORARILY_REJECTED
from sim.physics.point import PointRobot
from sim.physics.robot import Mode, QuadRobot
from swarmd.base.functions import Vec3
from swarmd.link.mavlink_modes import Flavour

log = logging.getLogger("swarmd.sim.autopilot")

_PX4_DLL = {1: "hold", 2: "rtl", 3: "land"}
"""NAV_DLL_ACT: the mode PX4 enters when the data link is lost."""
_APM_GCS = {1: "rtl", 2: "rtl", 3: "rtl", 4: "land", 5: "land"}
"""FS_GCS_ENABLE: the mode ArduCopter enters (2 keeps flying a mission in AUTO; 3 and 4
are SmartRTL, not simulated, with its fallbacks RTL and LAND)."""
AIRBORNE = (Mode.TAKEOFF, Mode.FLYING, Mode.LANDING)


class AutopilotFlight(AutopilotState):
    """The autopilot's modes and what it flies in them, on the craft's clock."""

    def __init__(self, robot: QuadRobot | PointRobot, flavour: Flavour, sysid: int, *,
                 geo_origin: Vec3 | None = None) -> None:
        super().__init__(robot, flavour, sysid, geo_origin=geo_origin)
        self.legs: list[Leg] = []
        """What the craft flies in an auto mode, the present leg first."""
        self.speed_xy: float | None = None
        """m/s of a DO_CHANGE_SPEED in the present mode (None: the firmware's cruise)."""
        self.last_gcs = -math.inf
        """Robot time of the last ground station HEARTBEAT."""
        self._paused: list[Leg] = []
        """ArduCopter's legs stopped by DO_PAUSE_CONTINUE."""
        self._leg_started = False
        self._leg_reached: float | None = None
        self._link_lost = False
        self._reported_current = -1

    # -- modes ---------------------------------------------------------------------------
    def _enter(self, name: str, t: float) -> int:
        r = self.robot
        if name == "guided" and self.flavour == "px4" and t - self.last_setpoint > (
                self.param("COM_OF_LOSS_T")):
            return TEMPORARILY_REJECTED  # PX4: no OFFBOARD without a setpoint stream
        if r.failed_motors or r.mode is Mode.CRASHED:
            return self._refused()
        if name in ("mission", "auto") and not self._mission_ready():
            return self._refused()
        self.mode = name
        self.takeoff_alt, self.legs, self.speed_xy = None, [], None
        flying = r.mode in AIRBORNE
        if name == "land" or (name == "stabilize" and flying):
            r.release(here=True)  # Stabilize without RC has no throttle: it comes down
        elif name == "rtl" and flying:
            self._start(rtl_legs(self.flavour, r.position, r.home, self.param))
        elif name in ("mission", "auto"):
            self.runner.start()
        elif name in ("hold", "brake", "guided") and flying and (
                name != "guided" or self.flavour == "ardupilot"):
            self._go(r.position)  # stop where it is (ArduPilot GUIDED: until told where)
        return ACCEPTED

    def _mission_ready(self) -> bool:
        """A mission to fly (both firmwares refuse their mission mode without one);
        ArduCopter armed on the ground also needs a NAV_TAKEOFF first (`mode_auto.cpp`)."""
        if not self.runner.flyable():
            self.say("Mission: no mission to fly")
            return False
        items = self.mission.listed()[self.mission.first:]
        first_nav = next(it for it in items if it.command in (16, 17, 19, 20, 21, 22))
        if (self.flavour == "ardupilot" and self.armed and self.robot.mode is Mode.PARKED
                and first_nav.command != 22):
            self.say("Auto: Missing Takeoff Cmd")
            return False
        return True

    def speeds(self) -> Speeds:
        return Speeds.auto(self.flavour, self.param, self.speed_xy)

    def _go(self, position: Vec3) -> bool:
        """Hold `position` at once (a setpoint, not a leg)."""
        self.target.hold(position)
        return self.robot.fly(self.label, self.target)

    def _climb(self, z: float) -> bool:
        """Straight up to `z` (world frame), at least 0.5 m above the ground."""
        x, y, _ = self.robot.position
        self.took_off = True
        return self._go((x, y, max(z, self.robot.home[2] + 0.5)))

    def _start(self, legs: list[Leg]) -> None:
        self.legs, self._leg_started = legs, False

    # -- with time -----------------------------------------------------------------------
    def control(self, t: float) -> None:
        """Mode logic that runs with time: PX4's offboard loss, the data-link loss
        failsafe, the legs of the auto modes, the end of a take-off, auto-disarm."""
        r = self.robot
        # Retried every tick while a failed craft refuses HOLD: logged once it is in.
        if (self.flavour == "px4" and self.mode == "guided"
                and t - self.last_setpoint > self.param("COM_OF_LOSS_T")
                and self._enter("hold", t) == ACCEPTED):
            log.warning("robot %d: setpoints stopped: OFFBOARD -> HOLD", r.robot_id)
        self._data_link(t)
        if self.armed:
            self._fly_legs(t)
        self._report_progress()
        if self.mode == "takeoff" and self.armed and r.mode is Mode.FLYING and abs(
                r.position[2] - self.target.position[2]) < 0.2:
            self.mode = "hold"
        self._auto_disarm(t)

    def _fly_legs(self, t: float) -> None:
        r = self.robot
        if not self.legs and self.mode in ("mission", "auto") and self.runner.state == ACTIVE:
            self._start(self.runner.legs(Where(r.position, r.home, self.geo_origin,
                                               self.flavour, self.param,
                                               r.mode is Mode.PARKED)))
            self._report_progress()  # each item current in turn, even one passed at once
        if not self.legs:
            return
        leg = self.legs[0]
        if not self._leg_started:
            self._leg_started, self._leg_reached = True, None
            if leg.goal is None:
                r.release(here=True)
            else:
                self.target.go(r.position, leg.goal, leg.speeds)
                self.took_off = True
                r.fly(self.label, self.target)
        arrived = r.mode is Mode.PARKED if leg.goal is None else leg.reached(r.position)
        in_mission = self.mode in ("mission", "auto")
        # ArduCopter reports an item reached on arrival, before its hold time; PX4 once
        # the hold is over (`mode_auto.cpp` verify_nav_wp; `navigator/mission.cpp`).
        early = self.flavour == "ardupilot" and in_mission and leg.hold > 0
        if arrived and self._leg_reached is None:
            self._leg_reached = t
            if early and leg.seq is not None:
                self.runner.reached.append(leg.seq)
        if self._leg_reached is not None and t - self._leg_reached >= leg.hold:
            self.legs.pop(0)
            self._leg_started = False
            if in_mission:
                self.runner.done(leg, report=not early)
                self._report_progress()

    def _report_progress(self) -> None:
        """MISSION_ITEM_REACHED for each item done, MISSION_CURRENT when it changed."""
        for seq in self.runner.reached:
            self.outbox.append(self.mav.mission_item_reached_encode(seq))
        self.runner.reached.clear()
        if self.mission.current != self._reported_current:
            self._reported_current = self.mission.current
            self.outbox.append(self.mission_current())

    def _data_link(self, t: float) -> None:
        if self.flavour == "px4":
            action, timeout = _PX4_DLL.get(int(self.param("NAV_DLL_ACT"))), self.param(
                "COM_DL_LOSS_T")
        else:
            action, timeout = _APM_GCS.get(int(self.param("FS_GCS_ENABLE"))), self.param(
                "FS_GCS_TIMEOUT")
        lost = t - self.last_gcs > timeout and self.last_gcs > -math.inf
        if not lost or self._link_lost:
            self._link_lost = lost
            return
        self._link_lost = True
        if action is None or not self.armed or self.robot.mode not in AIRBORNE:
            return
        if self.flavour == "ardupilot" and self.param("FS_GCS_ENABLE") == 2 and (
                self.mode == "auto"):
            return  # 2: a mission in AUTO goes on
        if self._enter(action, t) == ACCEPTED:
            self.say("Failsafe: GCS link lost, " + action.upper(), 2)

    def _auto_disarm(self, t: float) -> None:
        r = self.robot
        if not self.armed:
            self._ground_since = None
            return
        if r.mode in AIRBORNE:
            self.flew = True
            self._ground_since = None
            return
        if self._ground_since is None:
            self._ground_since = t
        delay = self._disarm_delay()
        if delay is not None and t - self._ground_since >= delay:
            self.armed, self.took_off, self.flew = False, False, False
            self.legs = []
            log.info("robot %d: landed: disarmed", r.robot_id)

    def _disarm_delay(self) -> float | None:
        """s on the ground before the firmware disarms by itself; None: it does not."""
        if self.flavour == "px4":
            # Commander: COM_DISARM_LAND after a landing, COM_DISARM_PRFLT if it never
            # took off; zero or negative turns either off.
            delay = self.param("COM_DISARM_LAND" if self.flew else "COM_DISARM_PRFLT")
        elif self.robot.mode is Mode.CRASHED:
            delay = 2.0  # ArduCopter's crash check disarms after 2 s
        elif self.flew and self.mode in ("land", "rtl", "auto"):
            return 0.0  # LAND, RTL's and a mission's landing disarm on touch-down
        else:
            delay = self.param("DISARM_DELAY")  # 0 turns it off
        return delay if delay > 0 else None
