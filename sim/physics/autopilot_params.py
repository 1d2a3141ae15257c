"""The simulated autopilot's parameters (`sim.physics.autopilot` has the whole picture):
those a ground station (QGroundControl's set-up and safety pages, Mission Planner) and
MAVSDK read or set, under each firmware's name, with its type, default and unit.

PX4's defaults are v1.15's (`src/modules/*/..._params.c`, `module.yaml`); ArduCopter's
are 4.5's (`ArduCopter/Parameters.cpp`, `libraries/AC_WPNav/AC_WPNav.cpp`,
`libraries/GCS_MAVLink/GCS_Common.cpp` for the SR0_ stream rates). docs/mavlink.md
lists which of them change what the simulation does; the others are reported as the
firmware reports them (a battery or RC failsafe is not simulated).

Units are the firmware's: PX4 in m, m/s and s; ArduCopter in cm, cm/s and ms where its
parameter is (RTL_ALT 1500 is 15 m, WPNAV_SPEED 1000 is 10 m/s).
"""

from __future__ import annotations

from sim.physics.mavlink_defs import INT8, INT16, INT32, REAL32, Param
from swarmd.link.mavlink_modes import Flavour

_PX4: tuple[tuple[str, float, int], ...] = (
    # Take-off, landing and auto-disarm (navigator/mission_params.c,
    # commander/commander_params.c, mc_pos_control/multicopter_*_params.c).
    ("MIS_TAKEOFF_ALT", 2.5, REAL32),     # m above home: the least a take-off climbs
    ("MIS_TKO_LAND_REQ", 0, INT32),       # no take-off or landing item required
    ("MPC_TKO_SPEED", 1.5, REAL32),       # m/s take-off climb
    ("MPC_LAND_SPEED", 0.7, REAL32),      # m/s (reported: the craft lands at 0.5)
    ("COM_DISARM_LAND", 2.0, REAL32),     # s on the ground after a landing
    ("COM_DISARM_PRFLT", 10.0, REAL32),   # s armed on the ground without a take-off
    ("COM_OF_LOSS_T", 1.0, REAL32),       # s without an offboard setpoint: HOLD
    # Speeds in the auto modes (Mission, Hold's goto, Return).
    ("MPC_XY_CRUISE", 5.0, REAL32),       # m/s horizontal in the auto modes
    ("MPC_XY_VEL_MAX", 12.0, REAL32),     # m/s cap of every horizontal speed
    ("MPC_Z_V_AUTO_UP", 3.0, REAL32),     # m/s climb in the auto modes
    ("MPC_Z_V_AUTO_DN", 1.5, REAL32),     # m/s descent in the auto modes
    ("MPC_Z_VEL_MAX_UP", 3.0, REAL32),    # m/s cap of every climb
    ("MPC_Z_VEL_MAX_DN", 1.5, REAL32),    # m/s cap of every descent
    # Mission acceptance (navigator/navigator_params.c).
    ("NAV_ACC_RAD", 10.0, REAL32),        # m horizontal acceptance radius
    ("NAV_MC_ALT_RAD", 0.8, REAL32),      # m vertical acceptance radius
    # Return (navigator/rtl_params.c).
    ("RTL_RETURN_ALT", 60.0, REAL32),     # m above home to return at
    ("RTL_DESCEND_ALT", 30.0, REAL32),    # m above home to descend to before landing
    ("RTL_LAND_DELAY", 0.0, REAL32),      # s hover at RTL_DESCEND_ALT (-1: for ever)
    ("RTL_MIN_DIST", 10.0, REAL32),       # m: closer, the return altitude follows the cone
    ("RTL_CONE_ANG", 45, INT32),          # deg half angle of the return cone
    # Failsafes (commander_params.c; the battery and geofence ones are reported only).
    ("NAV_DLL_ACT", 0, INT32),            # GCS link loss: 0 off, 1 hold, 2 return, 3 land
    ("COM_DL_LOSS_T", 10, INT32),         # s without a GCS HEARTBEAT: link lost
    ("NAV_RCL_ACT", 2, INT32),            # RC loss (no RC is simulated)
    ("COM_LOW_BAT_ACT", 0, INT32),
    ("BAT_LOW_THR", 0.15, REAL32),
    ("BAT_CRIT_THR", 0.07, REAL32),
    ("BAT_EMERGEN_THR", 0.05, REAL32),
    ("GF_ACTION", 2, INT32),
    ("GF_MAX_HOR_DIST", 0.0, REAL32),
    ("GF_MAX_VER_DIST", 0.0, REAL32),
    # Identity.
    ("MAV_COMP_ID", 1, INT32),
    ("MAV_TYPE", 2, INT32),               # quadrotor
    ("SYS_AUTOSTART", 4001, INT32),       # generic quadcopter X
)

_ARDUCOPTER: tuple[tuple[str, float, int], ...] = (
    # Arming, disarming, take-off (ArduCopter/Parameters.cpp, AP_Arming).
    ("ARMING_CHECK", 1, INT32),           # all checks
    ("DISARM_DELAY", 10, INT8),           # s landed before disarming (0: never)
    ("PILOT_TKOFF_ALT", 0.0, REAL32),     # cm: the pilot's (RC) take-off, reported only
    # Waypoint navigation (AC_WPNav): AUTO, GUIDED's goto and RTL.
    ("WPNAV_SPEED", 1000.0, REAL32),      # cm/s horizontal
    ("WPNAV_SPEED_UP", 250.0, REAL32),    # cm/s climb
    ("WPNAV_SPEED_DN", 150.0, REAL32),    # cm/s descent
    ("WPNAV_RADIUS", 200.0, REAL32),      # cm waypoint radius
    ("WPNAV_ACCEL", 250.0, REAL32),       # cm/s/s (reported)
    ("LAND_SPEED", 50, INT16),            # cm/s (reported: the craft lands at 50)
    ("LAND_SPEED_HIGH", 0, INT16),
    # Return (ArduCopter/mode_rtl.cpp).
    ("RTL_ALT", 1500, INT32),             # cm above home to return at
    ("RTL_ALT_FINAL", 0, INT16),          # cm to descend to at home (0: land)
    ("RTL_LOIT_TIME", 5000, INT32),       # ms above home before the descent
    ("RTL_SPEED", 0, INT16),              # cm/s (0: WPNAV_SPEED)
    ("RTL_CLIMB_MIN", 0, INT16),          # cm climbed at least
    ("RTL_CONE_SLOPE", 3.0, REAL32),      # return altitude <= slope x distance (0: off)
    # Failsafes (the battery, RC, EKF and fence ones are reported only).
    ("FS_GCS_ENABLE", 0, INT8),           # GCS loss: 0 off, 1 RTL, 2 continue AUTO, 5 LAND
    ("FS_GCS_TIMEOUT", 5.0, REAL32),      # s without a GCS HEARTBEAT
    ("FS_THR_ENABLE", 1, INT8),
    ("FS_EKF_ACTION", 1, INT8),
    ("BATT_FS_LOW_ACT", 0, INT8),
    ("BATT_FS_CRT_ACT", 0, INT8),
    ("FENCE_ENABLE", 0, INT8),
    ("FENCE_ACTION", 1, INT8),
    # Missions (AP_Mission).
    ("MIS_RESTART", 0, INT8),             # 0: AUTO resumes the mission where it was
    ("MIS_OPTIONS", 0, INT16),
    ("AUTO_OPTIONS", 0, INT32),
    # Identity.
    ("SYSID_MYGCS", 255, INT16),
    ("FRAME_CLASS", 1, INT8),             # quad
    ("FRAME_TYPE", 1, INT8),              # X
)

SR0_GROUPS: dict[str, int] = {"SR0_RAW_SENS": 1, "SR0_EXT_STAT": 2, "SR0_RC_CHAN": 3,
                              "SR0_RAW_CTRL": 4, "SR0_POSITION": 6, "SR0_EXTRA1": 10,
                              "SR0_EXTRA2": 11, "SR0_EXTRA3": 12}
"""ArduPilot's stream-rate parameters of the first link (Hz) and the MAV_DATA_STREAM each
sets (`GCS_MAVLINK_Parameters`); REQUEST_DATA_STREAM writes them."""


def default_params(flavour: Flavour, sysid: int,
                   stream_rates: dict[str, float] | None = None) -> dict[str, Param]:
    """Every parameter of `flavour` at the firmware's default, in a fixed order (the
    index PARAM_VALUE carries). `stream_rates`: ArduPilot's SR0_ values (Hz)."""
    if flavour == "px4":
        table = [("MAV_SYS_ID", float(sysid), INT32), *_PX4]
    else:
        table = [("SYSID_THISMAV", float(sysid), INT16), *_ARDUCOPTER]
        rates = stream_rates or {}
        table += [(name, rates.get(name, 0.0), INT16) for name in SR0_GROUPS]
    return {name: Param(float(value), kind) for name, value, kind in sorted(table)}
