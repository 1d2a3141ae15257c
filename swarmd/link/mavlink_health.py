"""An autopilot's MAVLink telemetry mapped to the robot's health (paper Fig. 4's one input).

Pure: `AutopilotView.observe(msg, now)` keeps what the autopilot last said (any object
with pymavlink's `get_type()` and the message's fields as attributes), and
`assess(view, now, thresholds)` runs the table `RULES`, one row per way an autopilot
shows a problem; the robot's health is the worst row that fires (DESIGN rule 7: FAULTY
stops the heartbeat and hands the function over, DEGRADED keeps working but is shown).
Every number and every row's health is a field of `Thresholds`, so a robot file can
tune them (`link: {kind: mavlink, health: {...}}`). docs/mavlink.md shows the table as
`health_table()` renders it (a test keeps the two equal).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from swarmd.core.roles import Health
from swarmd.link.mavlink_modes import FAILSAFE_MODES, Flavour, flavour_of, mode_name

# MAVLink enum values (common.xml / ardupilotmega.xml), spelled out: this module is pure
# and must not depend on which pymavlink dialect a process loaded.
MAV_STATE_UNINIT, MAV_STATE_BOOT, MAV_STATE_CALIBRATING = 0, 1, 2
MAV_STATE_CRITICAL, MAV_STATE_EMERGENCY = 5, 6
MAV_STATE_POWEROFF, MAV_STATE_FLIGHT_TERMINATION = 7, 8
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER = 6, 18
MAV_AUTOPILOT_INVALID = 8

SENSORS: dict[str, int] = {
    "gyro": 1,  # MAV_SYS_STATUS_SENSOR_3D_GYRO
    "accel": 2,  # MAV_SYS_STATUS_SENSOR_3D_ACCEL
    "mag": 4,  # MAV_SYS_STATUS_SENSOR_3D_MAG
    "gps": 32,  # MAV_SYS_STATUS_SENSOR_GPS
    "motors": 32768,  # MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
}
"""SYS_STATUS sensor bits the link judges, by the name used in `Thresholds.sensors`."""

EKF_REQUIRED = 1 | 2 | 8 | 32
"""EKF_STATUS_REPORT / ESTIMATOR_STATUS flags a position-holding craft needs: attitude,
horizontal velocity, relative horizontal position, absolute vertical position (the two
enums share these bit values)."""
ESTIMATOR_GPS_GLITCH, ESTIMATOR_ACCEL_ERROR = 1024, 2048
EKF_CONST_POS_MODE = 128


def _default_sensors() -> dict[str, Health]:
    return {"gyro": Health.FAULTY, "accel": Health.FAULTY, "mag": Health.DEGRADED,
            "gps": Health.DEGRADED, "motors": Health.FAULTY}


@dataclass(frozen=True)
class Thresholds:
    """Every number and row health of the table (defaults are docs/mavlink.md's)."""

    heartbeat_timeout: float = 3.0
    """s of autopilot HEARTBEAT silence (it sends 1 Hz) before the robot is FAULTY."""
    battery_degraded: float = 30.0
    """% remaining below which the robot is DEGRADED."""
    battery_faulty: float = 15.0
    """% remaining below which the robot is FAULTY (it cannot finish a function)."""
    estimator_degraded: float = 0.5
    """EKF variance / PX4 innovation test ratio at or above which: DEGRADED."""
    estimator_faulty: float = 0.8
    """... FAULTY (ArduPilot's own EKF failsafe, FS_EKF_THRESH, defaults to 0.8)."""
    critical: Health = Health.DEGRADED
    """system_status CRITICAL ("failsafe, can still navigate")."""
    not_ready: Health = Health.DEGRADED
    """system_status UNINIT / BOOT / CALIBRATING."""
    failsafe_mode: Health = Health.FAULTY
    """The autopilot switched itself to RTL / LAND (not asked by the link)."""
    command_refused: Health = Health.FAULTY
    """An arm, mode or take-off command denied or unanswered after its retries."""
    refused_hold: float = 30.0
    """s a refusal keeps counting after the last one (a later success clears it)."""
    sensors: dict[str, Health] = field(default_factory=_default_sensors)
    """Health of a SYS_STATUS sensor present and enabled but not healthy."""


@dataclass
class AutopilotView:
    """What the autopilot last said, and when (see the module docstring)."""

    started: float = 0.0
    """When the link started: no HEARTBEAT by `started + heartbeat_timeout` is FAULTY."""
    last_heartbeat: float | None = None
    flavour: Flavour | None = None
    system_status: int = 0
    base_mode: int = 0
    custom_mode: int = 0
    sensors: tuple[int, int, int] | None = None
    """SYS_STATUS (present, enabled, health) bit sets."""
    battery: float | None = None
    """% remaining (BATTERY_STATUS, else SYS_STATUS), None when the autopilot does not know."""
    battery_from_status: bool = False
    estimator: tuple[str, int, float] | None = None
    """(message, flags, worst variance or test ratio)."""
    commanded_mode: str | None = None
    """The mode the link itself last asked for: a commanded LAND is not a failsafe."""
    release_mode: str | None = None
    """The mode the link asked for on release (hold, land, rtl); it stops counting as
    asked for once the craft shows the mode of a later assignment (`commanded_mode`)."""
    refused: tuple[str, float] | None = None
    """(what was refused, when)."""
    time_boot_ms: int | None = None
    rebooted: int = 0
    """Times the autopilot's boot clock went backwards (a reboot)."""

    def commanded(self, mode: str, *, release: bool = False) -> None:
        """The link asked the craft for `mode` (`release`: on a release, hold/land/rtl)."""
        if release:
            self.release_mode = mode
        else:
            self.commanded_mode = mode

    def refusal(self, what: str, now: float, *, drops_mode: bool) -> None:
        """The autopilot refused `what` at `now`; `drops_mode`: it was a mode change, so
        the craft does not fly the mode the link asked for."""
        self.refused = (what, now)
        if drops_mode:
            self.commanded_mode = None

    def accepted_critical(self) -> None:
        """A critical command was accepted: an earlier refusal no longer stands."""
        self.refused = None

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> str | None:
        if self.flavour is None or not self.base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        return mode_name(self.flavour, self.custom_mode)

    def alive(self, now: float, timeout: float) -> bool:
        return self.last_heartbeat is not None and now - self.last_heartbeat <= timeout

    def observe(self, msg: Any, now: float) -> bool:
        """Take one message from the autopilot; True if it was a HEARTBEAT."""
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self.last_heartbeat = now
            self.flavour = flavour_of(msg.autopilot) or self.flavour
            self.system_status = msg.system_status
            self.base_mode = msg.base_mode
            self.custom_mode = msg.custom_mode
            mode = self.mode
            if mode is not None and mode == self.commanded_mode != self.release_mode:
                self.release_mode = None  # flying what the link asked for again
            return True
        if kind == "SYS_STATUS":
            self.sensors = (msg.onboard_control_sensors_present,
                            msg.onboard_control_sensors_enabled,
                            msg.onboard_control_sensors_health)
            if (self.battery is None or self.battery_from_status) and msg.battery_remaining >= 0:
                self.battery, self.battery_from_status = float(msg.battery_remaining), True
        elif kind == "BATTERY_STATUS":
            if msg.battery_remaining >= 0:
                self.battery, self.battery_from_status = float(msg.battery_remaining), False
        elif kind == "EKF_STATUS_REPORT":
            worst = max(msg.velocity_variance, msg.pos_horiz_variance, msg.pos_vert_variance,
                        msg.compass_variance)
            self.estimator = ("EKF_STATUS_REPORT", msg.flags, worst)
        elif kind == "ESTIMATOR_STATUS":
            worst = max(msg.vel_ratio, msg.pos_horiz_ratio, msg.pos_vert_ratio, msg.mag_ratio)
            self.estimator = ("ESTIMATOR_STATUS", msg.flags, worst)
        boot = getattr(msg, "time_boot_ms", None)
        if isinstance(boot, int) and kind in ("ATTITUDE", "LOCAL_POSITION_NED"):
            if self.time_boot_ms is not None and boot + 1000 < self.time_boot_ms:
                self.rebooted += 1
            self.time_boot_ms = boot
        return False


@dataclass(frozen=True)
class Rule:
    """One row of the health table."""

    name: str
    source: str
    """The message (or the link's own observation) the row reads."""
    condition: str
    """When it fires, in words, naming the `Thresholds` fields."""
    outcome: str
    """Its health, naming the `Thresholds` field that sets it."""
    check: Callable[[AutopilotView, float, Thresholds], tuple[Health, str] | None]


def _heartbeat(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    if v.last_heartbeat is None:
        if now - v.started > th.heartbeat_timeout:
            return Health.FAULTY, "no autopilot HEARTBEAT since the link started"
        return None
    silent = now - v.last_heartbeat
    if silent > th.heartbeat_timeout:
        return Health.FAULTY, f"autopilot HEARTBEAT silent for {silent:.1f} s"
    return None


def _status(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    s = v.system_status
    if s in (MAV_STATE_EMERGENCY, MAV_STATE_FLIGHT_TERMINATION, MAV_STATE_POWEROFF):
        return Health.FAULTY, f"system_status {_STATE_NAMES[s]}"
    if s == MAV_STATE_CRITICAL:
        return th.critical, "system_status CRITICAL"
    if s in (MAV_STATE_UNINIT, MAV_STATE_BOOT, MAV_STATE_CALIBRATING):
        return th.not_ready, f"system_status {_STATE_NAMES[s]}"
    return None


_STATE_NAMES = {0: "UNINIT", 1: "BOOT", 2: "CALIBRATING", 5: "CRITICAL", 6: "EMERGENCY",
                7: "POWEROFF", 8: "FLIGHT_TERMINATION"}


def _sensors(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    if v.sensors is None:
        return None
    present, enabled, healthy = v.sensors
    worst: tuple[Health, str] | None = None
    for name, bit in SENSORS.items():
        if present & bit and enabled & bit and not healthy & bit:
            h = th.sensors.get(name, Health.FAULTY)
            if worst is None or h > worst[0]:
                worst = (h, f"SYS_STATUS {name} unhealthy")
    return worst


def _battery(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    if v.battery is None:
        return None
    if v.battery < th.battery_faulty:
        return Health.FAULTY, f"battery {v.battery:.0f}% < {th.battery_faulty:g}%"
    if v.battery < th.battery_degraded:
        return Health.DEGRADED, f"battery {v.battery:.0f}% < {th.battery_degraded:g}%"
    return None


def _estimator(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    if v.estimator is None:
        return None
    msg, flags, worst = v.estimator
    if flags & EKF_REQUIRED != EKF_REQUIRED:
        return Health.FAULTY, f"{msg}: no position solution (flags {flags:#x})"
    if msg == "ESTIMATOR_STATUS" and flags & ESTIMATOR_ACCEL_ERROR:
        return Health.FAULTY, f"{msg}: accelerometer error"
    if worst >= th.estimator_faulty:
        return Health.FAULTY, f"{msg}: variance {worst:.2f} >= {th.estimator_faulty:g}"
    if worst >= th.estimator_degraded:
        return Health.DEGRADED, f"{msg}: variance {worst:.2f} >= {th.estimator_degraded:g}"
    if msg == "ESTIMATOR_STATUS" and flags & ESTIMATOR_GPS_GLITCH:
        return Health.DEGRADED, f"{msg}: GPS glitch"
    if msg == "EKF_STATUS_REPORT" and flags & EKF_CONST_POS_MODE:
        return Health.DEGRADED, f"{msg}: constant position mode"
    return None


def _failsafe(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    mode = v.mode
    if mode is not None and mode in FAILSAFE_MODES and mode not in (v.commanded_mode,
                                                                    v.release_mode):
        return th.failsafe_mode, f"autopilot switched itself to {mode.upper()}"
    return None


def _refused(v: AutopilotView, now: float, th: Thresholds) -> tuple[Health, str] | None:
    if v.refused is None or now - v.refused[1] > th.refused_hold:
        return None
    return th.command_refused, f"{v.refused[0]} refused"


RULES: tuple[Rule, ...] = (
    Rule("heartbeat", "HEARTBEAT", "none for `heartbeat_timeout` s (3), also none since "
         "start", "FAULTY", _heartbeat),
    Rule("emergency", "HEARTBEAT", "system_status EMERGENCY, FLIGHT_TERMINATION or POWEROFF",
         "FAULTY", _status),
    Rule("critical", "HEARTBEAT", "system_status CRITICAL", "`critical` (DEGRADED)", _status),
    Rule("not_ready", "HEARTBEAT", "system_status UNINIT, BOOT or CALIBRATING",
         "`not_ready` (DEGRADED)", _status),
    Rule("sensor", "SYS_STATUS", "gyro, accel, mag, GPS or motor outputs present and "
         "enabled but not healthy", "`sensors` (gyro, accel, motors FAULTY; mag, gps "
         "DEGRADED)", _sensors),
    Rule("battery_low", "BATTERY_STATUS (else SYS_STATUS)", "remaining < `battery_degraded` "
         "% (30)", "DEGRADED", _battery),
    Rule("battery_critical", "BATTERY_STATUS (else SYS_STATUS)", "remaining < "
         "`battery_faulty` % (15)", "FAULTY", _battery),
    Rule("estimator_lost", "EKF_STATUS_REPORT / ESTIMATOR_STATUS", "attitude, horizontal "
         "velocity, relative horizontal or absolute vertical position flag missing; PX4 "
         "accel error", "FAULTY", _estimator),
    Rule("estimator_variance", "EKF_STATUS_REPORT / ESTIMATOR_STATUS", "worst variance "
         "(ArduPilot) or test ratio (PX4) >= `estimator_degraded` (0.5) / "
         "`estimator_faulty` (0.8)", "DEGRADED / FAULTY", _estimator),
    Rule("estimator_glitch", "EKF_STATUS_REPORT / ESTIMATOR_STATUS", "PX4 GPS glitch; "
         "ArduPilot constant position mode", "DEGRADED", _estimator),
    Rule("failsafe_mode", "HEARTBEAT", "mode RTL, LAND, SMART_RTL, AUTO_RTL or PRECLAND "
         "that the link did not ask for", "`failsafe_mode` (FAULTY)", _failsafe),
    Rule("command_refused", "COMMAND_ACK", "arm, mode or take-off denied, or no ACK after "
         "`command_retries`; counts for `refused_hold` s (30)", "`command_refused` "
         "(FAULTY)", _refused),
)
"""The health table (docs/mavlink.md). Rows sharing a check are one check's outcomes."""


@dataclass(frozen=True)
class Assessment:
    health: Health
    reasons: tuple[str, ...]
    """Why, one per firing row (empty when OK)."""


def assess(view: AutopilotView, now: float, th: Thresholds) -> Assessment:
    """The robot's health now: the worst row of `RULES` that fires."""
    worst = Health.OK
    reasons: list[str] = []
    seen: set[Callable[..., Any]] = set()
    for rule in RULES:
        if view.last_heartbeat is None and rule.check is not _heartbeat:
            continue  # nothing heard yet: the zeros of an empty view mean nothing
        if rule.check in seen:
            continue
        seen.add(rule.check)
        hit = rule.check(view, now, th)
        if hit is None or hit[0] is Health.OK:
            continue
        worst = max(worst, hit[0])
        reasons.append(hit[1])
    if not view.alive(now, th.heartbeat_timeout):
        # A silent autopilot's last words are stale: only the silence counts.
        reasons = [r for r in reasons if "HEARTBEAT" in r] or reasons
    return Assessment(worst, tuple(reasons))


def health_table() -> str:
    """The table as Markdown (docs/mavlink.md holds this text)."""
    lines = ["| row | message | fires when | health |", "|---|---|---|---|"]
    for r in RULES:
        lines.append(f"| `{r.name}` | {r.source} | {r.condition} | {r.outcome} |")
    return "\n".join(lines)
