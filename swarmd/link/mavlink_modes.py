"""Flight modes of PX4 and ArduPilot (Copter) as HEARTBEAT `custom_mode` numbers.

Pure tables shared by the MAVLink robot link (swarmd/link/mavlink.py) and the simulated
autopilot (sim/physics/autopilot.py), so both sides agree on the encoding.

- ArduCopter: `custom_mode` is the mode number (GUIDED 4, LOITER 5, RTL 6, LAND 9, ...).
- PX4: `custom_mode` packs a main mode in bits 16-23 and a sub mode in bits 24-31
  (`px4_custom_mode.h`): OFFBOARD is main 6; AUTO is main 4 with sub modes TAKEOFF 2,
  LOITER 3, MISSION 4, RTL 5, LAND 6, PRECLAND 9. DO_SET_MODE takes main and sub mode as
  params 2 and 3.

Names the link uses: `guided` (ArduPilot GUIDED, PX4 OFFBOARD: the modes that follow
position setpoints), `hold`, `land`, `rtl`, `takeoff`.
"""

from __future__ import annotations

from typing import Literal

Flavour = Literal["px4", "ardupilot"]

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12

ARDUCOPTER_MODES: dict[int, str] = {
    0: "stabilize", 1: "acro", 2: "alt_hold", 3: "auto", 4: "guided", 5: "hold",
    6: "rtl", 7: "circle", 9: "land", 11: "drift", 13: "sport", 14: "flip",
    15: "autotune", 16: "poshold", 17: "brake", 18: "throw", 19: "avoid_adsb",
    20: "guided_nogps", 21: "smart_rtl", 22: "flowhold", 23: "follow", 24: "zigzag",
    25: "systemid", 26: "heli_autorotate", 27: "auto_rtl",
}
"""ArduCopter mode numbers; LOITER (5) is the link's `hold`."""

PX4_MAIN = {1: "manual", 2: "altctl", 3: "posctl", 4: "auto", 5: "acro", 6: "guided",
            7: "stabilized", 8: "rattitude"}
"""PX4 main modes; OFFBOARD (6) is the link's `guided`."""
PX4_AUTO_SUB = {1: "ready", 2: "takeoff", 3: "hold", 4: "mission", 5: "rtl", 6: "land",
                8: "follow_target", 9: "precland"}
"""PX4 AUTO sub modes; AUTO.LOITER (3) is the link's `hold`."""

FAILSAFE_MODES = frozenset({"rtl", "land", "smart_rtl", "auto_rtl", "precland"})
"""Modes an autopilot enters on its own failsafes (battery, RC or data link loss, EKF)."""


def flavour_of(autopilot: int) -> Flavour | None:
    """The flavour of a HEARTBEAT's `autopilot` field, None for neither."""
    if autopilot == MAV_AUTOPILOT_PX4:
        return "px4"
    if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return "ardupilot"
    return None


def mode_name(flavour: Flavour, custom_mode: int) -> str:
    """The link's name for a HEARTBEAT `custom_mode` (`mode<number>` if unknown)."""
    if flavour == "ardupilot":
        return ARDUCOPTER_MODES.get(custom_mode, f"mode{custom_mode}")
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    if main == 4:
        return PX4_AUTO_SUB.get(sub, f"auto{sub}")
    return PX4_MAIN.get(main, f"mode{custom_mode}")


def mode_number(flavour: Flavour, name: str) -> tuple[int, int]:
    """(param2, param3) of MAV_CMD_DO_SET_MODE for mode `name`. Raises KeyError."""
    if flavour == "ardupilot":
        for number, n in ARDUCOPTER_MODES.items():
            if n == name:
                return number, 0
        raise KeyError(name)
    for sub, n in PX4_AUTO_SUB.items():
        if n == name:
            return 4, sub
    for main, n in PX4_MAIN.items():
        if n == name and main != 4:
            return main, 0
    raise KeyError(name)


def custom_mode(flavour: Flavour, name: str) -> int:
    """HEARTBEAT `custom_mode` of mode `name` (what an autopilot in that mode sends)."""
    main, sub = mode_number(flavour, name)
    if flavour == "ardupilot":
        return main
    return (main << 16) | (sub << 24)
