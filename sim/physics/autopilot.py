"""A simulated flight controller that speaks MAVLink over a MuJoCo quadrotor (or, without
physics, a point mass: sim/physics/point.py).

As PX4 SITL does, each simulated robot's autopilot listens on its own UDP port on
loopback (one MAVLink system id per robot) and sends its telemetry to every peer it has
heard from in the last `PEER_TIMEOUT` s (and to fixed `peers`, e.g. a ground station's
14550), so the daemon's `mavlink` link and any ground station or SDK can talk to it at
once. `flavour` is `px4` or `ardupilot`: the autopilot answers as that firmware answers
(its HEARTBEAT fields, mode encodings, MAV_RESULT codes, parameters, take-off rules).
docs/mavlink.md tabulates each answer with the firmware source it follows.

Sent (`autopilot_rates`, at each firmware's start-up rates until a client changes them
with SET_MESSAGE_INTERVAL or, on ArduPilot, REQUEST_DATA_STREAM): HEARTBEAT 1 Hz,
SYS_STATUS 2 Hz, BATTERY_STATUS 1 Hz, LOCAL_POSITION_NED and ATTITUDE 10 Hz,
GLOBAL_POSITION_INT 5 Hz (ArduPilot 10), GPS_RAW_INT 2 Hz, EXTENDED_SYS_STATE 1 Hz,
HOME_POSITION 0.5 Hz, MISSION_CURRENT 1 Hz (ArduPilot 2), VFR_HUD 4 Hz,
EKF_STATUS_REPORT (ArduPilot) or ESTIMATOR_STATUS (PX4) 1 Hz; STATUSTEXT, MISSION_CURRENT
and MISSION_ITEM_REACHED as things happen. A change of system_status or sensor health
sends HEARTBEAT and SYS_STATUS at once. Latitude, longitude and altitude are the swarm
frame's position around `geo_origin` (default: each firmware's SITL home), flat earth.

Answered: COMMAND_LONG and COMMAND_INT (arm / disarm, DO_SET_MODE, NAV_TAKEOFF, NAV_LAND,
RETURN_TO_LAUNCH, DO_REPOSITION, MISSION_START, DO_SET_MISSION_CURRENT, DO_CHANGE_SPEED,
DO_PAUSE_CONTINUE, SET / GET_MESSAGE_INTERVAL, REQUEST_MESSAGE,
REQUEST_AUTOPILOT_CAPABILITIES, REQUEST_PROTOCOL_VERSION), SET_MODE, the parameter
protocol (`autopilot_params`), the mission protocol (`autopilot_mission`), PING (PX4) and
TIMESYNC, REQUEST_DATA_STREAM (ArduPilot), SET_POSITION_TARGET_LOCAL_NED and
_GLOBAL_INT in GUIDED / OFFBOARD. Modes: `guided` follows the setpoints (PX4 OFFBOARD
needs a setpoint stream to enter and falls back to HOLD when it stops for COM_OF_LOSS_T;
ArduCopter needs NAV_TAKEOFF before it leaves the ground), `hold` (and ArduPilot's
`brake`) stops where it is, `land` lands where it is, `rtl` returns as each firmware does
(`autopilot_nav`), `mission` / `auto` flies the mission, PX4's `takeoff` climbs,
ArduCopter boots in `stabilize`. On the ground it disarms by itself as each firmware
does. A ground station's lost data link triggers the firmware's failsafe when its
parameter asks for one.

Faults: a failed motor (`fail_motor`, the simulator's `motor` fault) clears the motor
outputs' health bit in SYS_STATUS and the HEARTBEAT says EMERGENCY while the craft falls
(and after it crashed), as a real autopilot shows a lost motor; `refuse_arm` fails the
arming checks (the SYS_STATUS pre-arm bit clears, arming is refused).

The local NED frame's origin is the robot's home (where the craft powered up); the
simulator's world frame is the swarm frame (x east, y north, z up).

Modules, each importing only those before it: `sim.physics.mavlink_defs` (the MAVLink
numbers, firmware identities), `autopilot_params` (each firmware's parameters),
`autopilot_rates` (the streams and their rates), `autopilot_nav` (legs, speeds, each
firmware's Return), `autopilot_mission` (the mission protocol and the items flown),
`autopilot_state` (the state and what it says), `autopilot_flight` (modes and what
happens with time), `autopilot_core` (what it does when told: `AutopilotCore`,
sans-I/O), and this one (the UDP endpoint `MavlinkAutopilot` and the daemon's
`SimMavlinkLink` to it).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Iterable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.autopilot_core import AutopilotCore
from sim.physics.link import QuadLink
from sim.physics.point import PointLink
from swarmd.base.functions import Vec3
from swarmd.core.roles import Health
from swarmd.link.base import HealthCallback
from swarmd.link.mavlink import MavlinkLink
from swarmd.link.mavlink_modes import Flavour
from swarmd.link.mavlink_pilot import PilotConfig, Release

log = logging.getLogger("swarmd.sim.autopilot")

PEER_TIMEOUT = 10.0
"""s: a peer not heard from for this long gets no more telemetry."""
TICK = 0.05
"""s at most between two passes of the mode logic and telemetry."""
MIN_TICK = 0.005
"""s at least between two passes (the fastest stream: 200 Hz)."""


class _Udp(asyncio.DatagramProtocol):
    def __init__(self, server: MavlinkAutopilot) -> None:
        self.server = server

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.server._datagram(data, (str(addr[0]), int(addr[1])))


class MavlinkAutopilot:
    """The simulated autopilot on its UDP port, over a real-time `QuadLink` (which steps
    the physics and writes the trajectory) or a `PointLink` (no physics). See the module
    docstring."""

    def __init__(self, quad: QuadLink | PointLink, flavour: Flavour, port: int, *,
                 sysid: int | None = None, host: str = "127.0.0.1",
                 peers: Iterable[tuple[str, int]] = (), geo_origin: Vec3 | None = None) -> None:
        self.quad = quad
        self.core = AutopilotCore(quad.robot, flavour, sysid or quad.robot_id,
                                  geo_origin=geo_origin)
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

    def set_label(self, function: str) -> None:
        """Name the function the craft flies in its trajectory file (MAVLink has none)."""
        self.core.label = function

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        transport, _ = await loop.create_datagram_endpoint(
            lambda: _Udp(self), local_addr=(self.host, self.port))
        # Port 0 asks the kernel for a free one at the bind itself: nothing else can take
        # it between a probe and the bind, as a port probed free and closed again can.
        self.port = transport.get_extra_info("sockname")[1]
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
        self.quad.catch_up()
        t = self.quad.robot.t
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.counters["bad"] += 1
                continue
            self.counters["received"] += 1
            try:
                replies = self.core.handle(msg, t)
            except Exception as exc:  # one odd message must not stop the autopilot
                self.counters["bad"] += 1
                log.warning("autopilot %d: %s from %s:%d not handled: %r", self.core.sysid,
                            msg.get_type(), addr[0], addr[1], exc)
                continue
            self._flush(replies)

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
            # Until the next message is due (a client may ask for 50 Hz), at most TICK.
            wait = self.core.streams.next_due() - self.quad.robot.t
            await asyncio.sleep(min(TICK, max(MIN_TICK, wait)))
            self.quad.catch_up()
            t = self.quad.robot.t
            self.core.control(t)
            self._flush(self.core.mission.tick(t) + self.core.telemetry(t))


async def start_autopilot(quad: QuadLink | PointLink, flavour: Flavour, port: int,
                          **kwargs: Any) -> MavlinkAutopilot:
    """Start `quad` (real-time physics) and its autopilot on UDP `port` of loopback."""
    if not quad.running:
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

    def __init__(self, quad: QuadLink, flavour: Flavour, port: int = 0, *,
                 release: Release = "rtl", refuse_arm: bool = False,
                 heartbeat_timeout: float = 3.0,
                 wall: Callable[[], float] = time.time) -> None:
        self.quad = quad
        self.flavour = flavour
        self.port = port
        """The autopilot's UDP port on loopback. 0 (the default): the one the kernel gives
        it when it binds (`start`), which the daemon's link then talks to."""
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
        self.port = self.autopilot.port
        self.link.url = f"udpout:127.0.0.1:{self.port}"  # bound now: the link opens it
        await self.link.start(on_health)

    def assign(self, function: str, epoch: int, params: Any) -> None:
        if self.autopilot is not None:
            self.autopilot.set_label(function)  # the trajectory file's label only
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
