"""Flying a function through MAVLink, without I/O: messages in, messages out, clock given.

`Pilot` is the MAVLink link's brain (swarmd/link/mavlink.py runs it in its I/O thread):
`on_message(msg, now)` for every message read, `tick(now)` for what to send now, and
`assign` / `release` from the daemon. It never blocks and never sleeps, so the tests
drive it on virtual time with pymavlink-encoded messages.

Flying (paper Fig. 4's output: the task):

- ArduPilot: mode GUIDED, arm, MAV_CMD_NAV_TAKEOFF to `takeoff_altitude`, then
  SET_POSITION_TARGET_LOCAL_NED at `setpoint_rate`.
- PX4: setpoints streamed from the start (PX4 refuses OFFBOARD without a setpoint
  stream, and leaves it when the stream falls below 2 Hz), mode OFFBOARD, arm; the first
  setpoint is straight above where the craft stands, at `takeoff_altitude`.
- Then the function: a slot's position, or the patrol loop resumed at the failed
  holder's next waypoint (`swarmd.base.functions.PatrolFlight`), on the swarm's clock `t0`.
- `release`: mode `hold`, `land` or `rtl` as configured; the stream stops.

Every command waits for its COMMAND_ACK; unanswered ones are sent again every
`command_timeout` up to `command_retries` times. A denied or unanswered arm, mode change
or take-off is a health problem (`AutopilotView.refused`, row `command_refused` of the
health table), retried every `retry_after` s while the function is still assigned.

Frames: the swarm file's frame is x east, y north, z up (ENU), metres. The autopilot's
LOCAL_POSITION_NED frame is north, east, down from its EKF origin. `origin` is where the
EKF origin lies in the swarm frame (the swarm coordinates of the craft's power-on spot),
so swarm (x, y, z) is NED (y - oy, x - ox, -(z - oz)). With `geo_origin` (latitude,
longitude, altitude of the swarm frame's 0), `origin` comes instead from the autopilot's
GPS_GLOBAL_ORIGIN, and the swarm can be laid out in global coordinates.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from swarmd.base.functions import (
    FunctionSpecError,
    PatrolFlight,
    SlotFlight,
    Vec3,
    flight_for,
    parse_function,
)
from swarmd.core.roles import Health
from swarmd.link.mavlink_health import (
    MAV_AUTOPILOT_INVALID,
    MAV_TYPE_GCS,
    MAV_TYPE_ONBOARD_CONTROLLER,
    Assessment,
    AutopilotView,
    Thresholds,
    assess,
)
from swarmd.link.mavlink_modes import Flavour, mode_number

log = logging.getLogger("swarmd.link.mavlink")

Release = Literal["hold", "land", "rtl"]

MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_RESULT_ACCEPTED, MAV_RESULT_IN_PROGRESS = 0, 5
MAV_FRAME_LOCAL_NED = 1
MAV_LANDED_STATE_ON_GROUND = 1
SETPOINT_MASK = 64 | 128 | 256 | 2048
"""SET_POSITION_TARGET type_mask: use position, velocity and yaw; ignore acceleration
and yaw rate."""
EARTH_RADIUS = 6_371_000.0
"""m: flat-earth conversion around the swarm's geodetic origin (swarms span < 10 km)."""

STREAMS = {
    "HEARTBEAT": (0, 1.0), "SYS_STATUS": (1, 2.0), "BATTERY_STATUS": (147, 1.0),
    "LOCAL_POSITION_NED": (32, 10.0), "EXTENDED_SYS_STATE": (245, 1.0),
    "EKF_STATUS_REPORT": (193, 1.0), "ESTIMATOR_STATUS": (230, 1.0),
}
"""Messages the link asks for (id, Hz) by MAV_CMD_SET_MESSAGE_INTERVAL on (re)connect."""


def swarm_to_ned(p: Vec3, origin: Vec3) -> Vec3:
    """Swarm frame (x east, y north, z up) to the autopilot's local NED frame."""
    return (p[1] - origin[1], p[0] - origin[0], -(p[2] - origin[2]))


def ned_to_swarm(n: Vec3, origin: Vec3) -> Vec3:
    """The inverse of `swarm_to_ned`."""
    return (n[1] + origin[0], n[0] + origin[1], -n[2] + origin[2])


def geodetic_offset(swarm_geo: Vec3, ekf_geo: Vec3) -> Vec3:
    """Where a point at (lat, lon, alt) `ekf_geo` lies in a swarm frame whose 0 is
    `swarm_geo` (degrees, degrees, metres): (east, north, up), flat earth."""
    lat0 = math.radians(swarm_geo[0])
    north = math.radians(ekf_geo[0] - swarm_geo[0]) * EARTH_RADIUS
    east = math.radians(ekf_geo[1] - swarm_geo[1]) * EARTH_RADIUS * math.cos(lat0)
    return (east, north, ekf_geo[2] - swarm_geo[2])


@dataclass(frozen=True)
class PilotConfig:
    flavour: Flavour | None = None
    """None: from the autopilot's HEARTBEAT."""
    target_system: int | None = None
    """None: the first autopilot heard."""
    target_component: int = 1
    takeoff_altitude: float = 2.0
    """m above the EKF origin the craft climbs to before heading for the function."""
    setpoint_rate: float = 10.0
    """Hz (PX4 needs > 2 Hz to stay in OFFBOARD)."""
    release: Release = "rtl"
    command_timeout: float = 1.0
    command_retries: int = 3
    retry_after: float = 2.0
    """s between two attempts at a step that was refused."""
    settle: float = 1.5
    """s an accepted mode change or arm has to show in the HEARTBEAT (1 Hz)."""
    origin: Vec3 = (0.0, 0.0, 0.0)
    geo_origin: Vec3 | None = None
    t0: float | None = None
    """Unix time of the swarm clock's 0 (patrols); None: the link's start."""
    health: Thresholds = field(default_factory=Thresholds)


@dataclass
class _Command:
    what: str
    command: int
    params: tuple[float, ...]
    critical: bool
    sent_at: float = 0.0
    attempts: int = 0


class Pilot:
    """See the module docstring."""

    def __init__(self, mav: Any, cfg: PilotConfig, *, now: float = 0.0,
                 wall0: float = 0.0) -> None:
        self.mav = mav
        """A pymavlink `MAVLink` object, used only to encode messages."""
        self.cfg = cfg
        self.view = AutopilotView(started=now)
        self.target: int | None = cfg.target_system
        self.target_component = cfg.target_component
        self.origin: Vec3 | None = cfg.origin if cfg.geo_origin is None else None
        self.wall0 = wall0
        """Unix time at `now` = 0 of the clock passed in (patrol clock conversion)."""
        self.counters = {"messages": 0, "commands": 0, "retries": 0, "refused": 0,
                         "acks": 0, "setpoints": 0, "reconnects": 0, "reboots": 0}
        self.function: str | None = None
        self.flight: SlotFlight | PatrolFlight | None = None
        self.position: Vec3 | None = None
        """Last LOCAL_POSITION_NED, NED."""
        self.landed_state: int | None = None
        self._queue: deque[_Command] = deque()
        self._pending: _Command | None = None
        self._done: dict[str, float] = {}
        self._failed: dict[str, float] = {}
        self._took_off = False
        self._climb_from: Vec3 | None = None
        self._stream_started: float | None = None
        self._next_setpoint = now
        self._next_heartbeat = now
        self._connected = False
        self._releasing: str | None = None
        self._reboots_seen = 0
        self._t0 = cfg.t0 if cfg.t0 is not None else wall0 + now
        """Unix time of the patrol clock's 0: the configured t0, else the link's start."""

    # -- inputs --------------------------------------------------------------------------
    @property
    def flavour(self) -> Flavour:
        return self.cfg.flavour or self.view.flavour or "px4"

    def assign(self, function: str, params: Mapping[str, Any], now: float) -> bool:
        """Fly `function` (its swarm-file spec; `t0` in params overrides the clock's)."""
        try:
            spec = parse_function(function, params)
            t0 = float(params.get("t0", self._t0))
        except (FunctionSpecError, TypeError, ValueError) as exc:
            log.error("cannot fly %s: %s", function, exc)
            return False
        if function == self.function and self.flight is not None:
            return True  # a new epoch of the same function: keep flying it
        self.function = function
        self._t0 = t0
        self.flight = flight_for(spec, self._run_time(now, t0))
        self._releasing = None
        self._failed.clear()
        self._drop_flight_commands()
        return True

    def release(self, function: str | None, now: float) -> None:
        """Stop `function` (whatever flies when it is None or "": the daemon's start as
        a standby, which must stop what the vehicle flew before the daemon died)."""
        if function and function != self.function:
            return
        self.function, self.flight = None, None
        self._stream_started = None
        self._drop_flight_commands()
        self._releasing = self.cfg.release
        self._failed.clear()

    def on_message(self, msg: Any, now: float) -> None:
        self.counters["messages"] += 1
        src = msg.get_srcSystem()
        kind = msg.get_type()
        if kind == "HEARTBEAT" and self.target is None and _is_autopilot(msg):
            self.target = src
            self.target_component = msg.get_srcComponent()
        if self.target is None or src != self.target:
            return
        if kind == "HEARTBEAT" and not _is_autopilot(msg):
            return  # a camera or gimbal of the same system
        if kind == "HEARTBEAT" and not self._connected:
            self._connected = True
            if self.view.last_heartbeat is not None:
                self.counters["reconnects"] += 1
                log.warning("autopilot %d is back", src)
            self._request_streams()
        self.view.observe(msg, now)
        if self.view.rebooted != self._reboots_seen:
            self._reboots_seen = self.view.rebooted
            self.counters["reboots"] += 1
            self._took_off = False
            self._request_streams()
        if kind == "LOCAL_POSITION_NED":
            self.position = (msg.x, msg.y, msg.z)
        elif kind == "EXTENDED_SYS_STATE":
            self.landed_state = msg.landed_state
        elif kind == "GPS_GLOBAL_ORIGIN" and self.cfg.geo_origin is not None:
            ekf = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
            self.origin = geodetic_offset(self.cfg.geo_origin, ekf)
        elif kind == "COMMAND_ACK":
            self._ack(msg, now)

    # -- outputs -------------------------------------------------------------------------
    def health(self, now: float) -> Assessment:
        return assess(self.view, now, self.cfg.health)

    def tick(self, now: float) -> list[Any]:
        """Messages to send now."""
        out: list[Any] = []
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + 1.0
            out.append(self.mav.heartbeat_encode(MAV_TYPE_ONBOARD_CONTROLLER,
                                                 MAV_AUTOPILOT_INVALID, 0, 0, 4))
        if self._connected and not self.view.alive(now, self.cfg.health.heartbeat_timeout):
            self._connected = False
            self._pending = None
            self._queue.clear()
            log.warning("autopilot silent for %.1f s", now - (self.view.last_heartbeat or 0))
        if self.target is None or not self._connected:
            return out
        self._plan(now)
        self._send_commands(now, out)
        if (self.flight is not None and self._stream_started is not None
                and now >= self._next_setpoint):
            self._next_setpoint = max(self._next_setpoint + 1.0 / self.cfg.setpoint_rate,
                                      now - 0.5 / self.cfg.setpoint_rate)
            sp = self._setpoint(now)
            if sp is not None:
                out.append(sp)
                self.counters["setpoints"] += 1
        return out

    # -- the flight sequence -------------------------------------------------------------
    def _plan(self, now: float) -> None:
        v = self.view
        if self._releasing is not None:
            if not v.armed:
                self._releasing = None  # disarmed: nothing flies, nothing to hold or land
            elif v.mode == self._releasing or self._recent("release", now):
                self._releasing = None if v.mode == self._releasing else self._releasing
            else:
                self._step("release", now, lambda: self._mode_cmd("release", self._releasing))
            return
        if self.flight is None or self.origin is None:
            return
        if not v.armed and self.landed_state in (None, MAV_LANDED_STATE_ON_GROUND):
            self._took_off = False
        if self.flavour == "px4" and self._stream_started is None:
            self._stream_started = now
            self._next_setpoint = now
            self._climb_from = None
        if v.mode != "guided":
            if self.flavour == "px4" and now - (self._stream_started or now) < 0.3:
                return  # PX4: a few setpoints first
            self._step("guided", now, lambda: self._mode_cmd("guided", "guided"))
            return
        if not v.armed:
            self._step("arm", now, lambda: _Command("arm", MAV_CMD_COMPONENT_ARM_DISARM,
                                                    (1, 0, 0, 0, 0, 0, 0), True))
            return
        if self.flavour == "ardupilot" and not self._took_off:
            if self._in_air():
                self._took_off = True
            else:
                self._step("takeoff", now, lambda: _Command(
                    "takeoff", MAV_CMD_NAV_TAKEOFF,
                    (0, 0, 0, math.nan, 0, 0, self.cfg.takeoff_altitude), True))
                return
        if self._stream_started is None:
            self._stream_started = now
            self._next_setpoint = now

    def _in_air(self) -> bool:
        if self.position is None:
            return False
        return -self.position[2] >= 0.8 * self.cfg.takeoff_altitude

    def _step(self, what: str, now: float, make: Any) -> None:
        if self._pending is not None and self._pending.what == what:
            return
        if any(c.what == what for c in self._queue) or self._recent(what, now):
            return
        failed = self._failed.get(what)
        if failed is not None and now - failed < self.cfg.retry_after:
            return
        cmd = make()
        if cmd is not None:
            self._queue.append(cmd)

    def _recent(self, what: str, now: float) -> bool:
        done = self._done.get(what)
        return done is not None and now - done < self.cfg.settle

    def _mode_cmd(self, what: str, name: str | None) -> _Command | None:
        if name is None:
            return None
        try:
            main, sub = mode_number(self.flavour, name)
        except KeyError:
            log.error("no %s mode %r on %s", what, name, self.flavour)
            return None
        self.view.commanded(name, release=what == "release")
        return _Command(what, MAV_CMD_DO_SET_MODE, (1, main, sub, 0, 0, 0, 0), True)

    def _drop_flight_commands(self) -> None:
        self._queue = deque(c for c in self._queue if not c.critical)
        if self._pending is not None and self._pending.critical:
            self._pending = None

    def _request_streams(self) -> None:
        wanted = dict(STREAMS)
        wanted.pop("ESTIMATOR_STATUS" if self.flavour == "ardupilot" else "EKF_STATUS_REPORT")
        for name, (msg_id, hz) in wanted.items():
            self._queue.append(_Command(f"interval {name}", MAV_CMD_SET_MESSAGE_INTERVAL,
                                        (msg_id, 1e6 / hz, 0, 0, 0, 0, 0), False))
        if self.cfg.geo_origin is not None:
            self._queue.append(_Command("GPS_GLOBAL_ORIGIN", MAV_CMD_REQUEST_MESSAGE,
                                        (49, 0, 0, 0, 0, 0, 0), False))

    # -- commands and acks ---------------------------------------------------------------
    def _send_commands(self, now: float, out: list[Any]) -> None:
        p = self._pending
        if p is not None and now - p.sent_at >= self.cfg.command_timeout:
            if p.attempts > self.cfg.command_retries:
                self._pending = None
                self._fail(p, "no COMMAND_ACK", now)
            else:
                self.counters["retries"] += 1
                out.append(self._encode(p, now))
        if self._pending is None and self._queue:
            self._pending = self._queue.popleft()
            out.append(self._encode(self._pending, now))

    def _encode(self, c: _Command, now: float) -> Any:
        c.sent_at = now
        c.attempts += 1
        self.counters["commands"] += 1
        assert self.target is not None
        return self.mav.command_long_encode(self.target, self.target_component, c.command,
                                            min(c.attempts - 1, 255), *c.params)

    def _ack(self, msg: Any, now: float) -> None:
        p = self._pending
        if p is None or msg.command != p.command:
            return
        self.counters["acks"] += 1
        if msg.result == MAV_RESULT_IN_PROGRESS:
            p.sent_at = now  # still working on it: wait another timeout
            return
        self._pending = None
        if msg.result == MAV_RESULT_ACCEPTED:
            self._done[p.what] = now
            self._failed.pop(p.what, None)
            if p.critical:
                self.view.accepted_critical()
            if p.what == "takeoff":
                self._took_off = True
            return
        self._fail(p, f"result {msg.result}", now)

    def _fail(self, c: _Command, why: str, now: float) -> None:
        if not c.critical:
            log.info("%s: %s (optional, ignored)", c.what, why)
            return
        self.counters["refused"] += 1
        self._failed[c.what] = now
        self.view.refusal(f"{c.what} ({why})", now, drops_mode=c.what in ("guided", "release"))
        log.warning("autopilot refused %s: %s", c.what, why)

    # -- setpoints -----------------------------------------------------------------------
    def _run_time(self, now: float, t0: float) -> float:
        return self.wall0 + now - t0

    def _setpoint(self, now: float) -> Any | None:
        assert self.flight is not None
        if self.origin is None or self.target is None:
            return None
        here = self.position or (0.0, 0.0, 0.0)
        alt = self.cfg.takeoff_altitude
        vel: Vec3 = (0.0, 0.0, 0.0)
        if self.flavour == "px4" and not self._took_off:
            # Straight up first: a craft heading for a far target from the ground tilts
            # into it before it clears the ground.
            if self._climb_from is None:
                self._climb_from = here
            if -here[2] < 0.8 * alt:
                target = (self._climb_from[0], self._climb_from[1], -alt)
                return self._encode_setpoint(target, vel, now)
            self._took_off = True
        sp = self.flight.setpoint(self._run_time(now, self._t0), ned_to_swarm(here, self.origin))
        target = swarm_to_ned(sp.position, self.origin)
        vel = (sp.velocity[1], sp.velocity[0], -sp.velocity[2])
        return self._encode_setpoint(target, vel, now)

    def _encode_setpoint(self, p: Vec3, v: Vec3, now: float) -> Any:
        assert self.target is not None
        return self.mav.set_position_target_local_ned_encode(
            int(now * 1000) & 0xFFFFFFFF, self.target, self.target_component,
            MAV_FRAME_LOCAL_NED, SETPOINT_MASK, p[0], p[1], p[2], v[0], v[1], v[2],
            0, 0, 0, 0.0, 0)

    # -- for the link and the tests ------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def streaming(self) -> bool:
        return self.flight is not None and self._stream_started is not None


def _is_autopilot(msg: Any) -> bool:
    return bool(msg.autopilot != MAV_AUTOPILOT_INVALID
                and msg.type not in (MAV_TYPE_GCS, MAV_TYPE_ONBOARD_CONTROLLER))


def health_name(h: Health) -> str:
    return h.name.lower()
