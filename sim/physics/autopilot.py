"""A simulated flight controller that speaks MAVLink over a MuJoCo quadrotor.

As PX4 SITL does, each simulated robot's autopilot listens on its own UDP port on
loopback (one MAVLink system id per robot) and sends its telemetry to every peer it has
heard from in the last `PEER_TIMEOUT` s (and to fixed `peers`, e.g. a ground station's
14550), so the daemon's `mavlink` link and any ground station or SDK can talk to it at
once. `flavour` is `px4` or `ardupilot`: the HEARTBEAT's autopilot field and the mode
encodings differ (swarmd/link/mavlink_modes.py), and so does the way to take off.

Sent: HEARTBEAT 1 Hz, SYS_STATUS 2 Hz, BATTERY_STATUS 1 Hz, LOCAL_POSITION_NED and
ATTITUDE 10 Hz, EXTENDED_SYS_STATE 1 Hz, HOME_POSITION 0.5 Hz, EKF_STATUS_REPORT
(ArduPilot) or ESTIMATOR_STATUS (PX4) 1 Hz, COMMAND_ACK for every COMMAND_LONG. A change
of system_status or sensor health sends HEARTBEAT and SYS_STATUS at once.

Understood: MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_DO_SET_MODE (and the SET_MODE
message), MAV_CMD_NAV_TAKEOFF, MAV_CMD_NAV_LAND, MAV_CMD_NAV_RETURN_TO_LAUNCH,
MAV_CMD_SET_MESSAGE_INTERVAL and MAV_CMD_REQUEST_MESSAGE (accepted), and
SET_POSITION_TARGET_LOCAL_NED in GUIDED / OFFBOARD. Modes: `guided` follows the
setpoints (PX4 OFFBOARD needs a setpoint in the last `OFFBOARD_TIMEOUT` s to enter, and
falls back to HOLD when they stop; ArduPilot needs NAV_TAKEOFF before it leaves the
ground), `hold` holds where it is, `land` lands where it is, `rtl` flies home and lands;
a craft that touches down disarms.

Faults: a failed motor (`fail_motor`, the simulator's `motor` fault) clears the motor
outputs' health bit in SYS_STATUS and the HEARTBEAT says EMERGENCY while the craft falls
(and after it crashed), as a real autopilot shows a lost motor; `refuse_arm` makes it
deny every arm command (a pre-arm check failing).

The local NED frame's origin is the robot's home (where the craft powered up); the
simulator's world frame is the swarm frame (x east, y north, z up).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable, Iterable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.link import QuadLink
from sim.physics.robot import Mode, QuadRobot
from swarmd.core.roles import Health
from swarmd.functions import Setpoint, Vec3
from swarmd.link.base import HealthCallback
from swarmd.link.mavlink import MavlinkLink
from swarmd.link.mavlink_modes import Flavour, custom_mode, mode_name
from swarmd.link.mavlink_pilot import PilotConfig, Release

log = logging.getLogger("swarmd.sim.autopilot")

PEER_TIMEOUT = 10.0
"""s: a peer not heard from for this long gets no more telemetry."""
OFFBOARD_TIMEOUT = 1.0
"""s without a setpoint after which PX4 leaves OFFBOARD (its COM_OF_LOSS_T)."""
TICK = 0.05
"""s between two telemetry passes (10 Hz position)."""
LANDED_DISARM = 0.5
"""s on the ground after a landing before the autopilot disarms."""

ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
STATE_STANDBY, STATE_ACTIVE, STATE_CRITICAL, STATE_EMERGENCY = 3, 4, 5, 6
ALL_SENSORS = 1 | 2 | 4 | 8 | 32 | 32768
"""gyro, accel, mag, baro, GPS, motor outputs."""
MOTORS = 32768
RATES: dict[str, float] = {"HEARTBEAT": 1.0, "SYS_STATUS": 2.0, "BATTERY_STATUS": 1.0,
                           "LOCAL_POSITION_NED": 10.0, "ATTITUDE": 10.0,
                           "EXTENDED_SYS_STATE": 1.0, "HOME_POSITION": 0.5,
                           "ESTIMATOR": 1.0}


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
    """The autopilot's logic over one `QuadRobot`: messages in, messages out, on the
    robot's clock. Sans-I/O (the server below moves the bytes)."""

    def __init__(self, robot: QuadRobot, flavour: Flavour, sysid: int) -> None:
        self.robot = robot
        self.flavour = flavour
        self.sysid = sysid
        self.mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.armed = False
        self.mode = "hold"
        self.refuse_arm = False
        self.forced = Health.OK
        """`set_health`: a fault the simulator injects (DEGRADED: CRITICAL, else EMERGENCY)."""
        self.label = "mavlink"
        """What the trajectory file records as the craft's function (MAVLink has no such
        notion; `SimMavlinkLink` names the daemon's function so pictures can)."""
        self.took_off = False
        self.last_setpoint = -math.inf
        self.target = _Target(robot.position)
        self._due: dict[str, float] = {}
        self._reported: tuple[int, int] | None = None
        self._ground_since: float | None = None
        self.boot = time.monotonic()
        self.counters = {"commands": 0, "setpoints": 0, "refused": 0}

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

    def _time_ms(self, t: float) -> int:
        return int(t * 1000) & 0xFFFFFFFF

    def local_ned(self) -> tuple[Vec3, Vec3]:
        (x, y, z), (vx, vy, vz) = self.robot.position, self.robot.velocity
        hx, hy, hz = self.robot.home
        return (y - hy, x - hx, -(z - hz)), (vy, vx, -vz)

    def heartbeat(self) -> Any:
        base = 1 | (128 if self.armed else 0)  # CUSTOM_MODE_ENABLED, SAFETY_ARMED
        return self.mav.heartbeat_encode(2, 12 if self.flavour == "px4" else 3, base,
                                         custom_mode(self.flavour, self.mode),
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
            return mav.sys_status_encode(ALL_SENSORS, ALL_SENSORS, self.sensors_health(), 200,
                                         int(11100 + 1500 * r.battery), -1, battery,
                                         0, 0, 0, 0, 0, 0)
        if name == "BATTERY_STATUS":
            return mav.battery_status_encode(0, 1, 1, 2500, [4000] * 3 + [65535] * 7, -1, -1,
                                             -1, battery)
        if name == "LOCAL_POSITION_NED":
            (n, e, d), (vn, ve, vd) = self.local_ned()
            return mav.local_position_ned_encode(self._time_ms(t), n, e, d, vn, ve, vd)
        if name == "ATTITUDE":
            w, x, y, z = (float(v) for v in r.data.qpos[3:7])
            roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
            pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
            yaw_enu = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            # ENU yaw (from east, counter-clockwise) to NED heading (from north, clockwise)
            yaw = math.atan2(math.cos(yaw_enu), math.sin(yaw_enu))
            return mav.attitude_encode(self._time_ms(t), roll, -pitch, yaw, 0, 0, 0)
        if name == "EXTENDED_SYS_STATE":
            landed = {Mode.PARKED: 1, Mode.CRASHED: 1, Mode.FLYING: 2, Mode.TAKEOFF: 3,
                      Mode.LANDING: 4}[r.mode]
            return mav.extended_sys_state_encode(0, landed)
        if name == "HOME_POSITION":
            return mav.home_position_encode(0, 0, 0, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                            0.0, 0.0, 0.0)
        if self.flavour == "ardupilot":
            return mav.ekf_status_report_encode(1 | 2 | 4 | 8 | 16 | 32 | 256 | 512, 0.02,
                                                0.02, 0.02, 0.02, 0.0)
        return mav.estimator_status_encode(int(t * 1e6), 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512,
                                           0.02, 0.02, 0.02, 0.02, 0, 0, 0.5, 0.5)

    # -- what it is told ------------------------------------------------------------------
    def handle(self, msg: Any, t: float) -> list[Any]:
        """One message from a peer; the replies."""
        kind = msg.get_type()
        if getattr(msg, "target_system", self.sysid) not in (0, self.sysid):
            return []
        if kind == "COMMAND_LONG":
            self.counters["commands"] += 1
            result = self._command(msg, t)
            if result != ACCEPTED:
                self.counters["refused"] += 1
            return [self.mav.command_ack_encode(msg.command, result, 0, 0,
                                                msg.get_srcSystem(), msg.get_srcComponent())]
        if kind == "SET_MODE":
            self._set_mode_number(msg.custom_mode, t)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED" and msg.coordinate_frame == 1:
            self._setpoint(msg, t)
        return []

    def _command(self, msg: Any, t: float) -> int:
        c = msg.command
        if c == 400:  # MAV_CMD_COMPONENT_ARM_DISARM
            if msg.param1 != 1:
                if self.robot.mode in (Mode.PARKED, Mode.CRASHED) or msg.param2 == 21196:
                    self.armed = False
                    return ACCEPTED
                return DENIED  # in the air
            if self.refuse_arm or self.robot.failed_motors or self.robot.mode is Mode.CRASHED:
                return DENIED
            self.armed = True
            self._ground_since = None
            return ACCEPTED
        if c == 176:  # MAV_CMD_DO_SET_MODE
            main, sub = int(msg.param2), int(msg.param3)
            number = main if self.flavour == "ardupilot" else (main << 16) | (sub << 24)
            return self._set_mode_number(number, t)
        if c == 22:  # MAV_CMD_NAV_TAKEOFF
            return self._takeoff(float(msg.param7), t)
        if c == 21:  # MAV_CMD_NAV_LAND
            return self._enter("land", t)
        if c == 20:  # MAV_CMD_NAV_RETURN_TO_LAUNCH
            return self._enter("rtl", t)
        if c in (511, 512):  # SET_MESSAGE_INTERVAL, REQUEST_MESSAGE: fixed rates here
            return ACCEPTED
        return UNSUPPORTED

    def _set_mode_number(self, number: int, t: float) -> int:
        name = mode_name(self.flavour, number)
        if name not in ("guided", "hold", "land", "rtl", "takeoff"):
            return UNSUPPORTED
        return self._enter(name, t)

    def _enter(self, name: str, t: float) -> int:
        r = self.robot
        if name == "guided" and self.flavour == "px4" and t - self.last_setpoint > (
                OFFBOARD_TIMEOUT):
            return DENIED  # PX4: no OFFBOARD without a setpoint stream
        if r.failed_motors or r.mode is Mode.CRASHED:
            return FAILED
        self.mode = name
        if name in ("land", "rtl"):
            r.release(here=name == "land")
        elif name == "hold" and r.mode in (Mode.TAKEOFF, Mode.FLYING, Mode.LANDING):
            self.target.position = r.position
            self.target.velocity = (0.0, 0.0, 0.0)
            r.fly(self.label, self.target)
        return ACCEPTED

    def _takeoff(self, alt: float, t: float) -> int:
        r = self.robot
        if not self.armed or r.failed_motors:
            return DENIED
        if self.flavour == "ardupilot" and self.mode != "guided":
            return DENIED  # ArduCopter takes off in GUIDED (or AUTO) only
        if self.flavour == "px4":
            self.mode = "takeoff"
        x, y, _ = r.position
        self.target.position = (x, y, r.home[2] + max(alt, 0.5))
        self.target.velocity = (0.0, 0.0, 0.0)
        self.took_off = True
        return ACCEPTED if r.fly(self.label, self.target) else FAILED

    def _setpoint(self, msg: Any, t: float) -> None:
        self.counters["setpoints"] += 1
        self.last_setpoint = t
        if self.mode != "guided" or not self.armed:
            return
        hx, hy, hz = self.robot.home
        mask = msg.type_mask
        if not mask & 7:  # position used
            self.target.position = (hx + msg.y, hy + msg.x, hz - msg.z)
        self.target.velocity = ((msg.vy, msg.vx, -msg.vz) if not mask & 56
                                else (0.0, 0.0, 0.0))
        r = self.robot
        on_ground = r.mode is Mode.PARKED
        if self.flavour == "ardupilot" and on_ground and not self.took_off:
            return  # ArduCopter: a position target on the ground waits for NAV_TAKEOFF
        if r.flight is not self.target or r.mode not in (Mode.TAKEOFF, Mode.FLYING):
            r.fly(self.label, self.target)

    def control(self, t: float) -> None:
        """Mode logic that runs with time: PX4's offboard loss, disarm on touch-down."""
        r = self.robot
        # Retried every tick while a failed craft refuses HOLD: logged once it is in.
        if (self.flavour == "px4" and self.mode == "guided"
                and t - self.last_setpoint > OFFBOARD_TIMEOUT
                and self._enter("hold", t) == ACCEPTED):
            log.warning("robot %d: setpoints stopped: OFFBOARD -> HOLD", r.robot_id)
        if self.mode == "takeoff" and r.mode is Mode.FLYING and abs(
                r.position[2] - self.target.position[2]) < 0.2:
            self.mode = "hold"
        if self.armed and r.mode in (Mode.PARKED, Mode.CRASHED):
            if self._ground_since is None:
                self._ground_since = t
            elif t - self._ground_since > LANDED_DISARM and (self.took_off or r.mode is
                                                               Mode.CRASHED):
                self.armed, self.took_off = False, False
        else:
            self._ground_since = None


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, server: MavlinkAutopilot) -> None:
        self.server = server

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.server._datagram(data, (str(addr[0]), int(addr[1])))


class MavlinkAutopilot:
    """The simulated autopilot on its UDP port, over a real-time `QuadLink` (which steps
    the physics and writes the trajectory). See the module docstring."""

    def __init__(self, quad: QuadLink, flavour: Flavour, port: int, *, sysid: int | None = None,
                 host: str = "127.0.0.1", peers: Iterable[tuple[str, int]] = ()) -> None:
        self.quad = quad
        self.core = AutopilotCore(quad.robot, flavour, sysid or quad.robot_id)
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
        self.quad._catch_up()
        t = self.quad.robot.t
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.counters["bad"] += 1
                continue
            self.counters["received"] += 1
            self._flush(self.core.handle(msg, t))

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
            self.quad._catch_up()
            t = self.quad.robot.t
            self.core.control(t)
            self._flush(self.core.telemetry(t))


async def start_autopilot(quad: QuadLink, flavour: Flavour, port: int,
                          **kwargs: Any) -> MavlinkAutopilot:
    """Start `quad` (real-time physics) and its autopilot on UDP `port` of loopback."""
    if quad._task is None:
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
            self.autopilot.core.label = function  # the trajectory file's label only
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
