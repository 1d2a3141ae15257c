"""The MAVLink robot link: health table, frames, flying sequences, reconnects.

Messages are real MAVLink byte streams: encoded with pymavlink's encoders as a PX4 or
ArduPilot autopilot (system 1, component 1) would send them, parsed back, and fed to the
link's pilot on virtual time. A few tests run the whole link over UDP loopback.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import socket
import time
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from swarms import unsigned_paper

from swarmd.core.roles import Health
from swarmd.link.mavlink_health import (
    RULES,
    AutopilotView,
    Thresholds,
    assess,
    health_table,
)
from swarmd.link.mavlink_modes import custom_mode, mode_name, mode_number
from swarmd.link.mavlink_pilot import (
    MAV_CMD_COMPONENT_ARM_DISARM,
    MAV_CMD_DO_SET_MODE,
    MAV_CMD_NAV_TAKEOFF,
    Pilot,
    PilotConfig,
    geodetic_offset,
    ned_to_swarm,
    swarm_to_ned,
)

ROOT = Path(__file__).resolve().parent.parent
ARMED, CUSTOM = 128, 1
MAV_AUTOPILOT = {"px4": 12, "ardupilot": 3}
ALL_SENSORS = 1 | 2 | 4 | 32 | 32768


class Autopilot:
    """Encodes what an autopilot sends, as bytes, and parses them back (a byte stream)."""

    def __init__(self, flavour: str, sysid: int = 1) -> None:
        self.flavour = flavour
        self.enc = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
        self.rx = mavlink2.MAVLink(None, srcSystem=255, srcComponent=0)
        self.mode = "hold"
        self.armed = False
        self.status = 4  # MAV_STATE_ACTIVE

    def wire(self, msg: Any) -> Any:
        data = msg.pack(self.enc)
        out = self.rx.parse_buffer(data)
        assert out is not None and len(out) == 1
        return out[0]

    def heartbeat(self, status: int | None = None, mode: str | None = None) -> Any:
        fl = "px4" if self.flavour == "px4" else "ardupilot"
        return self.wire(self.enc.heartbeat_encode(
            2, MAV_AUTOPILOT[self.flavour], CUSTOM | (ARMED if self.armed else 0),
            custom_mode(fl, mode or self.mode),  # type: ignore[arg-type]
            self.status if status is None else status))

    def sys_status(self, healthy: int = ALL_SENSORS, battery: int = -1) -> Any:
        return self.wire(self.enc.sys_status_encode(ALL_SENSORS, ALL_SENSORS, healthy, 0,
                                                    12000, 0, battery, 0, 0, 0, 0, 0, 0))

    def battery(self, remaining: int) -> Any:
        return self.wire(self.enc.battery_status_encode(0, 0, 0, 0, [0] * 10, 0, 0, 0,
                                                        remaining))

    def estimator(self, flags: int = 1 | 2 | 8 | 32, worst: float = 0.1) -> Any:
        if self.flavour == "ardupilot":
            return self.wire(self.enc.ekf_status_report_encode(flags, worst, 0.1, 0.1, 0.1,
                                                               0.0))
        return self.wire(self.enc.estimator_status_encode(0, flags, worst, 0.1, 0.1, 0.1,
                                                          0, 0, 0, 0))

    def position(self, n: float, e: float, d: float, boot_ms: int = 1000) -> Any:
        return self.wire(self.enc.local_position_ned_encode(boot_ms, n, e, d, 0, 0, 0))

    def ack(self, command: int, result: int = 0) -> Any:
        return self.wire(self.enc.command_ack_encode(command, result))


FLAVOURS = ["px4", "ardupilot"]


def view_after(ap: Autopilot, msgs: list[Any], now: float = 1.0) -> AutopilotView:
    v = AutopilotView(started=0.0)
    v.observe(ap.heartbeat(), 0.5)
    for m in msgs:
        v.observe(m, now)
    return v


# -- the health table ---------------------------------------------------------------------

Case = tuple[str, Any, Health, str]


def cases(ap: Autopilot) -> list[Case]:
    """(row, messages-maker, health, reason fragment) for every row of the table."""
    fl = ap.flavour
    return [
        ("heartbeat", lambda: [], Health.OK, ""),
        ("emergency", lambda: [ap.heartbeat(status=6)], Health.FAULTY, "EMERGENCY"),
        ("emergency", lambda: [ap.heartbeat(status=8)], Health.FAULTY, "TERMINATION"),
        ("critical", lambda: [ap.heartbeat(status=5)], Health.DEGRADED, "CRITICAL"),
        ("not_ready", lambda: [ap.heartbeat(status=2)], Health.DEGRADED, "CALIBRATING"),
        ("sensor", lambda: [ap.sys_status(ALL_SENSORS & ~1)], Health.FAULTY, "gyro"),
        ("sensor", lambda: [ap.sys_status(ALL_SENSORS & ~2)], Health.FAULTY, "accel"),
        ("sensor", lambda: [ap.sys_status(ALL_SENSORS & ~4)], Health.DEGRADED, "mag"),
        ("sensor", lambda: [ap.sys_status(ALL_SENSORS & ~32)], Health.DEGRADED, "gps"),
        ("sensor", lambda: [ap.sys_status(ALL_SENSORS & ~32768)], Health.FAULTY, "motors"),
        ("battery_low", lambda: [ap.battery(29)], Health.DEGRADED, "battery 29%"),
        ("battery_low", lambda: [ap.battery(30)], Health.OK, ""),
        ("battery_low", lambda: [ap.sys_status(battery=20)], Health.DEGRADED, "battery"),
        ("battery_critical", lambda: [ap.battery(14)], Health.FAULTY, "battery 14%"),
        ("estimator_lost", lambda: [ap.estimator(flags=1 | 2 | 32)], Health.FAULTY,
         "no position"),
        ("estimator_variance", lambda: [ap.estimator(worst=0.6)], Health.DEGRADED,
         "variance"),
        ("estimator_variance", lambda: [ap.estimator(worst=0.9)], Health.FAULTY, "variance"),
        ("estimator_glitch",
         lambda: [ap.estimator(flags=(1 | 2 | 8 | 32) | (1024 if fl == "px4" else 128))],
         Health.DEGRADED, "GPS glitch" if fl == "px4" else "constant position"),
        ("failsafe_mode", lambda: [ap.heartbeat(mode="rtl")], Health.FAULTY, "RTL"),
        ("failsafe_mode", lambda: [ap.heartbeat(mode="land")], Health.FAULTY, "LAND"),
        ("failsafe_mode", lambda: [ap.heartbeat(mode="guided")], Health.OK, ""),
    ]


@pytest.mark.parametrize("flavour", FLAVOURS)
def test_every_row_of_the_health_table_maps_as_documented(flavour: str) -> None:
    ap = Autopilot(flavour)
    seen = set()
    for row, make, health, fragment in cases(ap):
        got = assess(view_after(ap, make()), 1.0, Thresholds())
        assert got.health is health, (row, got)
        assert fragment in " ".join(got.reasons), (row, got)
        seen.add(row)
    # The remaining rows are the link's own observations (silence, refusals): below.
    assert {r.name for r in RULES} - seen == {"battery_critical", "heartbeat",
                                             "command_refused"} - seen


def test_thresholds_are_configurable() -> None:
    ap = Autopilot("ardupilot")
    th = Thresholds(battery_degraded=50, battery_faulty=40, failsafe_mode=Health.DEGRADED,
                    critical=Health.FAULTY, estimator_degraded=0.2, estimator_faulty=0.3)
    assert assess(view_after(ap, [ap.battery(35)]), 1, th).health is Health.FAULTY
    assert assess(view_after(ap, [ap.battery(45)]), 1, th).health is Health.DEGRADED
    assert assess(view_after(ap, [ap.battery(55)]), 1, th).health is Health.OK
    assert assess(view_after(ap, [ap.heartbeat(mode="rtl")]), 1, th).health is Health.DEGRADED
    assert assess(view_after(ap, [ap.heartbeat(status=5)]), 1, th).health is Health.FAULTY
    assert assess(view_after(ap, [ap.estimator(worst=0.25)]), 1, th).health is Health.DEGRADED
    th2 = Thresholds(sensors={"gyro": Health.DEGRADED})
    assert assess(view_after(ap, [ap.sys_status(ALL_SENSORS & ~1)]), 1, th2).health is (
        Health.DEGRADED)


def test_a_commanded_land_is_no_failsafe() -> None:
    ap = Autopilot("px4")
    v = view_after(ap, [])
    v.commanded_mode = "land"
    v.observe(ap.heartbeat(mode="land"), 1.0)
    assert assess(v, 1.0, Thresholds()).health is Health.OK


def test_the_docs_show_the_table_the_code_runs() -> None:
    assert health_table() in (ROOT / "docs" / "mavlink.md").read_text()


@pytest.mark.parametrize("flavour", FLAVOURS)
def test_lost_heartbeat_is_faulty_within_the_timeout(flavour: str) -> None:
    ap = Autopilot(flavour)
    th = Thresholds(heartbeat_timeout=3.0)
    v = AutopilotView(started=0.0)
    assert assess(v, 2.9, th).health is Health.OK  # not heard yet, not yet late
    assert assess(v, 3.1, th).health is Health.FAULTY  # never heard
    for t in range(6):
        v.observe(ap.heartbeat(), float(t))
    assert assess(v, 7.9, th).health is Health.OK
    got = assess(v, 8.1, th)
    assert got.health is Health.FAULTY and "silent" in got.reasons[0]


# -- frames and modes ---------------------------------------------------------------------


def test_swarm_frame_is_enu_and_ned_is_north_east_down() -> None:
    # 1 m east, 2 m north, 3 m up of the autopilot's origin.
    assert swarm_to_ned((1.0, 2.0, 3.0), (0.0, 0.0, 0.0)) == (2.0, 1.0, -3.0)
    # The origin is the autopilot's origin in swarm coordinates.
    assert swarm_to_ned((1.0, 2.0, 3.0), (10.0, 20.0, 0.5)) == (-18.0, -9.0, -2.5)
    for p in [(1.5, -2.0, 4.0), (0.0, 0.0, 0.2)]:
        assert ned_to_swarm(swarm_to_ned(p, (3, 4, 1)), (3, 4, 1)) == pytest.approx(p)


def test_geodetic_origin() -> None:
    east, north, up = geodetic_offset((47.0, 8.0, 400.0), (47.001, 8.001, 405.0))
    assert north == pytest.approx(111.19, abs=0.05)
    assert east == pytest.approx(111.19 * math.cos(math.radians(47.0)), abs=0.05)
    assert up == pytest.approx(5.0)


def test_mode_encodings() -> None:
    assert mode_number("ardupilot", "guided") == (4, 0)
    assert mode_number("ardupilot", "land") == (9, 0)
    assert mode_number("ardupilot", "rtl") == (6, 0)
    assert mode_number("px4", "guided") == (6, 0)  # OFFBOARD
    assert mode_number("px4", "rtl") == (4, 5)  # AUTO.RTL
    assert mode_number("px4", "hold") == (4, 3)  # AUTO.LOITER
    assert custom_mode("px4", "land") == (4 << 16) | (6 << 24)
    for fl in ("px4", "ardupilot"):
        for name in ("guided", "hold", "land", "rtl"):
            assert mode_name(fl, custom_mode(fl, name)) == name


# -- flying -------------------------------------------------------------------------------


class Loop:
    """A pilot and a scripted autopilot on virtual time."""

    def __init__(self, flavour: str, **cfg: Any) -> None:
        self.ap = Autopilot(flavour)
        self.enc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
        self.rx = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.pilot = Pilot(self.enc, PilotConfig(**cfg), now=0.0, wall0=1000.0)
        self.now = 0.0
        self.sent: list[tuple[float, Any]] = []
        self.refuse: set[int] = set()
        self.silent_acks = False
        self.alt = 0.0

    def step(self, dt: float = 0.02, answer: bool = True) -> None:
        self.now += dt
        for m in self.pilot.tick(self.now):
            data = m.pack(self.enc)  # through bytes, as on the wire
            (msg,) = self.rx.parse_buffer(data)
            self.sent.append((self.now, msg))
            if answer and msg.get_type() == "COMMAND_LONG":
                self.answer(msg)

    def answer(self, cmd: Any) -> None:
        if self.silent_acks:
            return
        if cmd.command in self.refuse:
            self.feed(self.ap.ack(cmd.command, 2))  # DENIED
            return
        if cmd.command == MAV_CMD_DO_SET_MODE:
            fl = "px4" if self.ap.flavour == "px4" else "ardupilot"
            number = (int(cmd.param2) if fl == "ardupilot"
                      else (int(cmd.param2) << 16) | (int(cmd.param3) << 24))
            self.ap.mode = mode_name(fl, number)  # type: ignore[arg-type]
        elif cmd.command == MAV_CMD_COMPONENT_ARM_DISARM:
            self.ap.armed = cmd.param1 == 1
        elif cmd.command == MAV_CMD_NAV_TAKEOFF:
            self.alt = cmd.param7
        self.feed(self.ap.ack(cmd.command))

    def feed(self, msg: Any) -> None:
        self.pilot.on_message(msg, self.now)

    def run(self, seconds: float, answer: bool = True, heartbeats: bool = True) -> None:
        end = self.now + seconds
        next_hb = self.now
        while self.now < end:
            if heartbeats and self.now >= next_hb:
                self.feed(self.ap.heartbeat())
                self.feed(self.ap.position(0.0, 0.0, -self.alt))
                next_hb += 0.5
            self.step(answer=answer)

    def commands(self) -> list[Any]:
        return [m for _, m in self.sent if m.get_type() == "COMMAND_LONG"
                and m.command not in (511, 512)]  # not the stream requests

    def setpoints(self) -> list[tuple[float, Any]]:
        return [(t, m) for t, m in self.sent if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]


def test_ardupilot_guided_arm_takeoff_then_setpoints() -> None:
    lp = Loop("ardupilot", takeoff_altitude=2.0, origin=(10.0, 20.0, 0.0))
    lp.run(1.0)
    assert lp.pilot.connected and lp.pilot.target == 1
    lp.pilot.assign("f2", {"kind": "slot", "position": [11.0, 23.0, 4.0]}, lp.now)
    lp.run(6.0)
    cmds = [(c.command, c.param1, c.param2) for c in lp.commands()]
    assert cmds[:3] == [(MAV_CMD_DO_SET_MODE, 1, 4), (MAV_CMD_COMPONENT_ARM_DISARM, 1, 0),
                        (MAV_CMD_NAV_TAKEOFF, 0, 0)]
    assert lp.commands()[2].param7 == pytest.approx(2.0)
    sps = lp.setpoints()
    assert sps, "no setpoints after take-off"
    last = sps[-1][1]
    assert (last.x, last.y, last.z) == pytest.approx((3.0, 1.0, -4.0))  # N, E, D
    assert last.coordinate_frame == 1 and last.target_system == 1
    assert assess(lp.pilot.view, lp.now, Thresholds()).health is Health.OK


def test_px4_streams_setpoints_before_offboard_and_at_10_hz() -> None:
    lp = Loop("px4", takeoff_altitude=2.0)
    lp.run(1.0)
    lp.pilot.assign("f1", {"kind": "slot", "position": [0.0, 0.0, 3.0]}, lp.now)
    t_assign = lp.now
    lp.run(2.0)
    sps = lp.setpoints()
    mode_cmd = next(t for t, m in lp.sent if m.get_type() == "COMMAND_LONG"
                    and m.command == MAV_CMD_DO_SET_MODE)
    assert sps[0][0] < mode_cmd  # PX4 refuses OFFBOARD without a setpoint stream
    assert (lp.commands()[0].param2, lp.commands()[0].param3) == (6, 0)
    times = [t for t, _ in sps]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert max(gaps) <= 0.1 + 1e-9
    assert len(times) >= 10 * (lp.now - t_assign) - 1
    first = sps[0][1]
    assert first.z == pytest.approx(-2.0)  # straight up to take-off altitude first
    lp.alt = 3.0
    lp.run(1.0)
    last = lp.setpoints()[-1][1]
    assert (last.x, last.y, last.z) == pytest.approx((0.0, 0.0, -3.0))


@pytest.mark.parametrize("flavour", FLAVOURS)
def test_refused_arm_is_a_health_problem_and_is_retried(flavour: str) -> None:
    lp = Loop(flavour, retry_after=2.0)
    lp.refuse.add(MAV_CMD_COMPONENT_ARM_DISARM)
    lp.run(1.0)
    lp.pilot.assign("f1", {"kind": "slot", "position": [0.0, 0.0, 3.0]}, lp.now)
    lp.run(3.0)
    got = lp.pilot.health(lp.now)
    assert got.health is Health.FAULTY and "arm" in got.reasons[0]
    arms = [c for c in lp.commands() if c.command == MAV_CMD_COMPONENT_ARM_DISARM]
    lp.run(2.5)
    assert len([c for c in lp.commands() if c.command == MAV_CMD_COMPONENT_ARM_DISARM]) > len(
        arms)
    lp.refuse.clear()  # the pre-arm problem is fixed: the next try clears the health row
    lp.run(3.0)
    assert lp.ap.armed and lp.pilot.health(lp.now).health is Health.OK


def test_unanswered_command_is_retried_then_refused() -> None:
    lp = Loop("ardupilot", command_timeout=0.5, command_retries=2)
    lp.run(1.0)
    lp.silent_acks = True
    lp.pilot.assign("f1", {"kind": "slot", "position": [0.0, 0.0, 3.0]}, lp.now)
    lp.run(2.0)
    modes = [c for c in lp.commands() if c.command == MAV_CMD_DO_SET_MODE]
    assert len(modes) == 3 and [c.confirmation for c in modes] == [0, 1, 2]
    got = lp.pilot.health(lp.now)
    assert got.health is Health.FAULTY and "no COMMAND_ACK" in got.reasons[0]


@pytest.mark.parametrize(("release", "number"), [("land", 9), ("rtl", 6), ("hold", 5)])
def test_release_sets_the_configured_mode(release: str, number: int) -> None:
    lp = Loop("ardupilot", release=release)
    lp.run(1.0)
    lp.pilot.assign("f1", {"kind": "slot", "position": [0.0, 0.0, 3.0]}, lp.now)
    lp.run(5.0)
    n = len(lp.setpoints())
    lp.pilot.release("f1", lp.now)
    lp.run(3.0)
    last = lp.commands()[-1]
    assert (last.command, last.param2) == (MAV_CMD_DO_SET_MODE, number)
    assert len(lp.setpoints()) <= n + 1  # the stream stopped
    assert lp.pilot.health(lp.now).health is Health.OK  # a commanded LAND/RTL: no failsafe


def test_patrol_resumes_at_the_next_waypoint() -> None:
    lp = Loop("ardupilot", t0=1000.0)  # swarm clock 0 = the pilot's time 0
    lp.run(1.0)
    wps = [[0.0, 0.0, 2.0], [10.0, 0.0, 2.0], [10.0, 10.0, 2.0], [0.0, 10.0, 2.0]]
    lp.run(11.0)  # run time 12 s at speed 1: the holder is on leg 1 -> waypoint 2
    lp.pilot.assign("p1", {"kind": "patrol", "waypoints": wps, "speed": 1.0}, lp.now)
    lp.run(5.0)
    last = lp.setpoints()[-1][1]
    assert (last.x, last.y, last.z) == pytest.approx((10.0, 10.0, -2.0))  # N=y, E=x


def test_reconnect_after_a_reboot() -> None:
    lp = Loop("px4")
    lp.run(2.0)
    assert lp.pilot.connected
    lp.run(4.0, heartbeats=False)  # unplugged
    assert not lp.pilot.connected
    assert lp.pilot.health(lp.now).health is Health.FAULTY
    # Back, rebooted: its boot clock starts again.
    lp.feed(lp.ap.position(0, 0, 0, boot_ms=500_000))
    lp.feed(lp.ap.heartbeat())
    lp.feed(lp.ap.position(0, 0, 0, boot_ms=300))
    lp.run(1.0)
    assert lp.pilot.connected and lp.pilot.counters["reconnects"] == 1
    assert lp.pilot.counters["reboots"] == 1
    assert lp.pilot.health(lp.now).health is Health.OK
    intervals = [m for _, m in lp.sent if m.get_type() == "COMMAND_LONG" and m.command == 511]
    assert len(intervals) >= 2 * 6  # streams asked for again after the reboot


def test_geo_origin_waits_for_the_autopilots_origin() -> None:
    lp = Loop("ardupilot", geo_origin=(47.0, 8.0, 400.0))
    lp.run(1.0)
    lp.pilot.assign("f1", {"kind": "slot", "position": [0.0, 0.0, 3.0]}, lp.now)
    lp.run(2.0)
    assert lp.commands() == []  # no origin yet: no flying blind
    lp.feed(lp.ap.wire(lp.ap.enc.gps_global_origin_encode(470010000, 80000000, 400000)))
    lp.run(6.0)
    last = lp.setpoints()[-1][1]
    # The swarm's 0 is 111 m south of the autopilot's origin.
    assert last.x == pytest.approx(-111.19, abs=0.1) and last.y == pytest.approx(0, abs=0.01)


# -- config -------------------------------------------------------------------------------


def test_robot_file_mavlink_link(tmp_path: Path) -> None:
    from swarmd.config import parse_robot
    from swarmd.config.errors import ConfigError
    from swarmd.link.factory import make_link
    from swarmd.link.mavlink import MavlinkLink

    swarm = unsigned_paper(tmp_path)
    text = (f"robot: 2\nswarm: {swarm}\nlink: {{kind: mavlink, url: 'udpin:127.0.0.1:14540',"
            " autopilot: ardupilot, release: land, health: {battery_faulty: 20,"
            " sensors: {mag: faulty}}}\n")
    cfg = parse_robot(text, "robot.yaml", tmp_path / "robot.yaml")
    link = make_link(cfg.link)
    assert isinstance(link, MavlinkLink)
    assert link.url == "udpin:127.0.0.1:14540"
    assert link.cfg.flavour == "ardupilot" and link.cfg.release == "land"
    assert link.cfg.health.battery_faulty == 20
    assert link.cfg.health.sensors["mag"] is Health.FAULTY
    assert link.cfg.health.sensors["gyro"] is Health.FAULTY
    with pytest.raises(ConfigError):
        parse_robot(text.replace("udpin:127.0.0.1:14540", ""), "robot.yaml", tmp_path)
    with pytest.raises(ConfigError):
        parse_robot(text.replace("release: land", "release: crash"), "robot.yaml", tmp_path)


# -- the whole link over UDP loopback -----------------------------------------------------


class UdpAutopilot:
    """An autopilot on a UDP socket: heartbeats to the link's port while `beating`."""

    def __init__(self, port: int) -> None:
        self.ap = Autopilot("ardupilot")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = port

    def beat(self) -> None:
        self.sock.sendto(self.ap.enc.heartbeat_encode(2, 3, 1, 4, 4).pack(self.ap.enc),
                         ("127.0.0.1", self.port))


async def _until(cond: Any, timeout: float, ap: UdpAutopilot | None = None) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, "timed out"
        if ap is not None:
            ap.beat()
        await asyncio.sleep(0.1)


@pytest.mark.slow
async def test_udp_link_reports_health_loses_and_regains_the_autopilot() -> None:
    from swarmd.link.mavlink import MavlinkLink

    class KernelPortLink(MavlinkLink):
        """The link listening on port 0: its socket gets a port from the kernel at the
        bind itself, which `port` tells once the I/O thread opened it. A port probed
        free before could be taken by another process before the link bound it."""

        port = 0

        def _open(self) -> Any:
            conn = super()._open()
            self.port = conn.port.getsockname()[1]
            return conn

    cfg = PilotConfig(health=Thresholds(heartbeat_timeout=0.6))
    link = KernelPortLink("udpin:127.0.0.1:0", pilot=cfg, health_period=0.1)
    got: list[Health] = []
    await link.start(got.append)
    ap = UdpAutopilot(0)  # sends to the link's port, once its I/O thread has bound it
    try:
        await _until(lambda: link.port != 0, 10.0)
        ap.port = link.port
        await _until(lambda: got and got[-1] is Health.OK, 10.0, ap)
        await _until(lambda: got[-1] is Health.FAULTY, 10.0)  # silent: faulty by itself
        assert link.pilot is not None and not link.pilot.connected
        await _until(lambda: got[-1] is Health.OK, 10.0, ap)  # back: reconnected
        assert link.pilot.counters["reconnects"] == 1
    finally:
        await link.close()
        ap.sock.close()


class FlakyConnection:
    """A connection whose reads fail once (a serial device unplugged)."""

    def __init__(self, fail: bool) -> None:
        self.fail = fail
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=191)
        self.closed = False

    def recv_match(self, blocking: bool, timeout: float) -> Any:
        if self.fail:
            raise OSError("device reports readiness to read but returned no data")
        time.sleep(min(timeout, 0.01))
        return None

    def close(self) -> None:
        self.closed = True


async def test_a_failed_device_is_reopened() -> None:
    from swarmd.link.mavlink import MavlinkLink

    conns: list[FlakyConnection] = []
    calls = 0

    def opener() -> FlakyConnection:
        nonlocal calls
        calls += 1
        if calls == 2:
            assert conns[0].closed  # closed before reopening
            raise OSError("no such device")  # still unplugged
        conns.append(FlakyConnection(fail=calls == 1))
        return conns[-1]

    link = MavlinkLink("/dev/ttyFAKE", opener=opener, reopen_interval=0.05)
    await link.start(lambda h: None)
    try:
        await _until(lambda: link.counters["opens"] >= 2, 5.0)
        assert link.counters["io_errors"] == 1 and link.counters["open_errors"] == 1
        assert conns[0].closed
    finally:
        await link.close()
