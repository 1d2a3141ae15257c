"""The simulated autopilot's telemetry streams and their rates (`sim.physics.autopilot`
has the whole picture): which message is due when, and what a client changes.

- MAV_CMD_SET_MESSAGE_INTERVAL (both firmwares): param2 > 0 an interval in µs, 0 the
  default rate, -1 off. A message the autopilot cannot stream is refused as the
  firmware refuses it (PX4 `mavlink_receiver.cpp` set_message_interval: FAILED, also
  for HEARTBEAT, which PX4 keeps at 1 Hz;
  ArduPilot `GCS_Common.cpp` set_message_interval: DENIED and a STATUSTEXT "No
  ap_message for mavlink id (N)").
- MAV_CMD_GET_MESSAGE_INTERVAL: MESSAGE_INTERVAL with the interval, -1 when off, 0 ("not
  available") for a message it cannot stream, which ArduPilot also answers FAILED
  (`GCS_Common.cpp` handle_command_get_message_interval).
- REQUEST_DATA_STREAM (ArduPilot only; PX4 ignores the deprecated message): sets a
  stream group's rate in Hz, or every group's (MAV_DATA_STREAM_ALL), 0 or stop turns it
  off; the group's SR0_ parameter follows (`GCS_Common.cpp` handle_request_data_stream),
  and setting an SR0_ parameter sets the group's rate.

A message's own interval (SET_MESSAGE_INTERVAL) wins over its group's rate until the
group's rate is set again. HEARTBEAT is in no group (1 Hz on both firmwares).
"""

from __future__ import annotations

import math

from sim.physics.autopilot_params import SR0_GROUPS
from swarmd.link.mavlink_modes import Flavour

IDS: dict[str, int] = {
    "HEARTBEAT": 0, "SYS_STATUS": 1, "GPS_RAW_INT": 24, "ATTITUDE": 30,
    "LOCAL_POSITION_NED": 32, "GLOBAL_POSITION_INT": 33, "MISSION_CURRENT": 42,
    "VFR_HUD": 74, "BATTERY_STATUS": 147, "EKF_STATUS_REPORT": 193,
    "ESTIMATOR_STATUS": 230, "HOME_POSITION": 242, "EXTENDED_SYS_STATE": 245}
"""Every message the autopilot streams, by MAVLink id."""

PX4_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0, "SYS_STATUS": 2.0, "BATTERY_STATUS": 1.0, "LOCAL_POSITION_NED": 10.0,
    "ATTITUDE": 10.0, "GLOBAL_POSITION_INT": 5.0, "GPS_RAW_INT": 2.0,
    "EXTENDED_SYS_STATE": 1.0, "HOME_POSITION": 0.5, "ESTIMATOR_STATUS": 1.0,
    "MISSION_CURRENT": 1.0, "VFR_HUD": 4.0}
"""Hz of PX4's streams at start (PX4 `mavlink_main.cpp` configure_streams, the rates of
its normal mode, rounded)."""

GROUP_MESSAGES: dict[int, tuple[str, ...]] = {
    2: ("SYS_STATUS", "GPS_RAW_INT", "MISSION_CURRENT", "EXTENDED_SYS_STATE"),
    6: ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"),
    10: ("ATTITUDE",),
    11: ("VFR_HUD",),
    12: ("BATTERY_STATUS", "EKF_STATUS_REPORT"),
}
"""ArduPilot's stream groups (MAV_DATA_STREAM: EXTENDED_STATUS, POSITION, EXTRA1-3) and
the simulated messages in each (`ArduCopter/GCS_Mavlink.cpp` STREAM_*_msgs)."""

APM_GROUP_RATES: dict[str, float] = {"SR0_EXT_STAT": 2.0, "SR0_POSITION": 10.0,
                                     "SR0_EXTRA1": 10.0, "SR0_EXTRA2": 4.0,
                                     "SR0_EXTRA3": 1.0}
"""Hz of ArduPilot's groups at start (as a ground station's REQUEST_DATA_STREAM leaves
them in SITL); the others are 0."""
APM_UNGROUPED: dict[str, float] = {"HEARTBEAT": 1.0, "HOME_POSITION": 0.5}

FAILED, DENIED, ACCEPTED = 4, 2, 0


class Streams:
    """When each message is due. Rates in Hz; an interval of None is off."""

    def __init__(self, flavour: Flavour) -> None:
        self.flavour = flavour
        self.group_hz: dict[int, float] = {}
        self.own: dict[str, float | None] = {}
        """Intervals (s) a client set per message; None: off."""
        self._due: dict[str, float] = {}
        if flavour == "ardupilot":
            for name, group in SR0_GROUPS.items():
                self.group_hz[group] = APM_GROUP_RATES.get(name, 0.0)

    def sr0_params(self) -> dict[str, float]:
        """ArduPilot's SR0_ parameter values (Hz) now (none for PX4)."""
        return {name: self.group_hz[g] for name, g in SR0_GROUPS.items()
                if g in self.group_hz}

    def default_interval(self, name: str) -> float | None:
        """s between two `name` when no client set it; None: not sent."""
        if self.flavour == "px4":
            hz = PX4_RATES.get(name, 0.0)
        elif name in APM_UNGROUPED:
            hz = APM_UNGROUPED[name]
        else:
            hz = next((self.group_hz[g] for g, names in GROUP_MESSAGES.items()
                       if name in names), 0.0)
        return 1.0 / hz if hz > 0 else None

    def interval(self, name: str) -> float | None:
        return self.own[name] if name in self.own else self.default_interval(name)

    def streamable(self, message_id: int) -> str | None:
        name = next((n for n, i in IDS.items() if i == message_id), None)
        if name in ("ESTIMATOR_STATUS", "EKF_STATUS_REPORT") and name != (
                "ESTIMATOR_STATUS" if self.flavour == "px4" else "EKF_STATUS_REPORT"):
            return None  # each firmware sends its own estimator report
        return name

    def due(self, t: float, now: tuple[str, ...] = ()) -> list[str]:
        """The messages due at time `t` (and those in `now`, sent at once)."""
        out = []
        for name in IDS:
            every = self.interval(name)
            if every is None:
                continue
            due = self._due.get(name, 0.0)
            if t < due - 1e-9 and name not in now:
                continue
            # On time: the next one `every` after this one was due (the rate stays
            # exact on a coarse tick); late by more than that (a new rate): from now.
            self._due[name] = due + every if t - due < every else t + every
            out.append(name)
        return out

    def next_due(self) -> float:
        """The earliest time a message is due (for the sender's sleep)."""
        times = [self._due.get(n, 0.0) for n in IDS if self.interval(n) is not None]
        return min(times, default=float("inf"))

    # -- what clients change ----------------------------------------------------------
    def set_interval(self, message_id: int, interval_us: float,
                     others: tuple[float, ...] = ()) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL (`others`: params 3, 4 and 7); the MAV_RESULT.
        PX4 keeps its HEARTBEAT at 1 Hz and takes no response target or other
        parameter (`mavlink_receiver.cpp` set_message_interval: FAILED)."""
        name = self.streamable(message_id)
        px4_refuses = self.flavour == "px4" and (name == "HEARTBEAT" or any(
            math.isfinite(p) and round(p) != 0 for p in others))
        if name is None or interval_us != interval_us or interval_us < -1 or px4_refuses:
            return FAILED if self.flavour == "px4" else DENIED
        if interval_us == 0:
            self.own.pop(name, None)
        else:
            self.own[name] = None if interval_us < 0 else interval_us / 1e6
        self._due[name] = 0.0  # the new rate starts now
        return ACCEPTED

    def get_interval(self, message_id: int) -> tuple[int, int | None]:
        """MAV_CMD_GET_MESSAGE_INTERVAL: the MAV_RESULT and the MESSAGE_INTERVAL's
        interval_us (None: no MESSAGE_INTERVAL is sent)."""
        name = self.streamable(message_id)
        if name is None:  # "not available": PX4 accepts the question, ArduPilot fails it
            return (ACCEPTED, 0) if self.flavour == "px4" else (FAILED, 0)
        every = self.interval(name)
        return ACCEPTED, -1 if every is None else round(every * 1e6)

    def set_group(self, stream_id: int, hz: float) -> list[str]:
        """ArduPilot's REQUEST_DATA_STREAM (or an SR0_ parameter): the group's rate
        (every group's for 0, MAV_DATA_STREAM_ALL); the SR0_ parameters it changed."""
        groups = [g for g in self.group_hz if stream_id in (0, g)]
        changed = []
        for name, g in SR0_GROUPS.items():
            if g in groups:
                self.group_hz[g] = max(0.0, hz)
                for message in GROUP_MESSAGES.get(g, ()):
                    self.own.pop(message, None)
                    self._due[message] = 0.0
                changed.append(name)
        return changed
