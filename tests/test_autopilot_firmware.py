"""The simulated autopilot answers as PX4 and ArduPilot answer (docs/mavlink.md, the
table "What the simulated autopilot answers"): its logic on virtual time over a point-mass
craft, fed messages that went through pymavlink's encoder and parser, as from a peer.
"""

from __future__ import annotations

import math
from typing import Any

import pytest

pytest.importorskip("mujoco")

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.autopilot_core import AutopilotCore
from sim.physics.mavlink_defs import PREARM, geodetic
from sim.physics.point import PointRobot
from sim.physics.robot import Mode
from swarmd.link.mavlink_modes import custom_mode, mode_number

NAN = math.nan
HOME = (2.0, -1.0, 0.0)
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
REFUSED = {"px4": TEMPORARILY_REJECTED, "ardupilot": FAILED}
both = pytest.mark.parametrize("flavour", ["px4", "ardupilot"])


class Vehicle:
    """An `AutopilotCore` and a ground station (system 255) on virtual time."""

    def __init__(self, flavour: str) -> None:
        self.core = AutopilotCore(PointRobot(1, HOME), flavour, 1)  # type: ignore[arg-type]
        self.flavour = flavour
        self.gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = mavlink2.MAVLink(None)
        self.t = 0.0

    def send(self, msg: Any) -> list[Any]:
        [decoded] = self.parser.parse_buffer(msg.pack(self.gcs))
        return self.core.handle(decoded, self.t)

    def command(self, command: int, *params: float) -> int:
        p = (*params, *([0.0] * (7 - len(params))))
        replies = self.send(self.gcs.command_long_encode(1, 1, command, 0, *p))
        assert replies[0].get_type() == "COMMAND_ACK" and replies[0].command == command
        return int(replies[0].result)

    def command_int(self, command: int, frame: int, p1: float, p2: float, p3: float,
                    p4: float, x: int, y: int, z: float) -> int:
        replies = self.send(self.gcs.command_int_encode(1, 1, frame, command, 0, 0, p1, p2, p3,
                                                        p4, x, y, z))
        return int(replies[0].result)

    def mode(self, name: str) -> int:
        main, sub = mode_number(self.core.flavour, name)
        return self.command(176, 1, main, sub)

    def arm(self) -> int:
        return self.command(400, 1)

    def setpoint(self, north: float, east: float, down: float) -> None:
        self.send(self.gcs.set_position_target_local_ned_encode(
            0, 1, 1, 1, 0b110111111000, north, east, down, 0, 0, 0, 0, 0, 0, 0, 0))

    def run(self, seconds: float, *, setpoint: tuple[float, float, float] | None = None) -> None:
        end = self.t + seconds
        while self.t < end - 1e-9:
            self.t += 0.05
            if setpoint is not None:
                self.setpoint(*setpoint)
            self.core.robot.step_until(self.t)
            self.core.control(self.t)

    def height(self) -> float:
        return self.core.robot.position[2] - HOME[2]

    def take_off(self, height: float = 2.0) -> None:
        """Into the air the way each firmware's SDKs do it."""
        if self.flavour == "px4":
            assert self.arm() == ACCEPTED
            assert self.command(22, 0, 0, 0, NAN, NAN, NAN, NAN) == ACCEPTED
        else:
            assert self.mode("guided") == ACCEPTED and self.arm() == ACCEPTED
            assert self.command(22, 0, 0, 0, 0, 0, 0, height) == ACCEPTED
        self.run(6.0)


def test_px4_takeoff_without_an_altitude_climbs_to_mis_takeoff_alt() -> None:
    v = Vehicle("px4")
    assert v.arm() == ACCEPTED
    assert v.command(22, 0, 0, 0, NAN, NAN, NAN, NAN) == ACCEPTED
    assert v.core.mode == "takeoff"
    v.run(6.0)
    assert v.height() == pytest.approx(2.5, abs=0.1)  # MIS_TAKEOFF_ALT's default
    assert v.core.mode == "hold" and v.core.armed and v.core.robot.mode is Mode.FLYING


def test_px4_takeoff_follows_mis_takeoff_alt_and_waits_for_arming() -> None:
    v = Vehicle("px4")
    v.send(v.gcs.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 4.0, 9))
    assert v.command(22, 0, 0, 0, NAN, NAN, NAN, NAN) == ACCEPTED  # a mode change
    v.run(1.0)
    assert v.height() < 0.05  # disarmed: it waits in Takeoff mode
    assert v.arm() == ACCEPTED
    v.run(8.0)
    assert v.height() == pytest.approx(4.0, abs=0.1)


def test_px4_takeoff_altitude_is_amsl_and_never_down() -> None:
    v = Vehicle("px4")
    amsl = v.core.home_geo()[2]
    assert v.arm() == ACCEPTED
    assert v.command(22, 0, 0, 0, NAN, NAN, NAN, amsl + 3.0) == ACCEPTED
    v.run(6.0)
    assert v.height() == pytest.approx(3.0, abs=0.1)
    assert v.command(22, 0, 0, 0, NAN, NAN, NAN, amsl + 1.0) == ACCEPTED
    v.run(3.0)
    assert v.height() == pytest.approx(3.0, abs=0.1)  # lower than it is: it stays


def test_ardupilot_takeoff_needs_guided_armed_and_a_height() -> None:
    v = Vehicle("ardupilot")
    assert v.command(22, 0, 0, 0, 0, 0, 0, 2.0) == FAILED  # not GUIDED
    assert v.mode("guided") == ACCEPTED
    assert v.command(22, 0, 0, 0, 0, 0, 0, 2.0) == FAILED  # not armed
    assert v.arm() == ACCEPTED
    assert v.command(22, 0, 0, 0, 0, 0, 0, NAN) == FAILED  # no height
    assert v.command_int(22, 0, 0, 0, 0, 0, 0, 0, 2.0) == DENIED  # frame not relative
    assert v.command_int(22, 3, 0, 0, 0, 0, 0, 0, 3.0) == ACCEPTED
    v.run(5.0)
    assert v.height() == pytest.approx(3.0, abs=0.1)


@both
def test_goto_is_a_do_reposition_by_command_int(flavour: str) -> None:
    v = Vehicle(flavour)
    v.take_off()
    lat, lon, _ = geodetic(v.core.geo_origin, HOME[0] + 3.0, HOME[1] + 4.0, 0.0)
    home_amsl = v.core.home_geo()[2]
    x, y = round(lat * 1e7), round(lon * 1e7)
    # MAVSDK's goto_location: MAV_FRAME_GLOBAL_INT, altitude AMSL, change-mode flag.
    assert v.command_int(192, 5, -1, 1, 0, NAN, x, y, home_amsl + 3.0) == ACCEPTED
    assert v.core.mode == ("hold" if flavour == "px4" else "guided")
    v.run(6.0)
    assert math.dist(v.core.robot.position, (HOME[0] + 3.0, HOME[1] + 4.0, 3.0)) < 0.2
    # Relative-altitude frame: metres above home.
    assert v.command_int(192, 6, -1, 1, 0, NAN, x, y, 1.5) == ACCEPTED
    v.run(3.0)
    assert v.height() == pytest.approx(1.5, abs=0.1)


def test_reposition_without_the_change_mode_flag() -> None:
    px4, apm = Vehicle("px4"), Vehicle("ardupilot")
    lat, lon, _ = geodetic(px4.core.geo_origin, 0.0, 0.0, 0.0)
    args = (192, 5, -1, 0, 0, NAN, round(lat * 1e7), round(lon * 1e7), 500.0)
    assert px4.command_int(*args) == UNSUPPORTED  # PX4: only with the flag
    assert apm.command_int(*args) == DENIED  # ArduPilot: only in GUIDED without it
    assert apm.mode("guided") == ACCEPTED
    assert apm.command_int(*args) == ACCEPTED


def test_ardupilot_brake_stops_the_craft_where_it_is() -> None:
    v = Vehicle("ardupilot")
    v.take_off()
    v.run(1.0, setpoint=(20.0, 0.0, -2.0))  # heading 20 m north
    assert mode_number("ardupilot", "brake") == (17, 0)
    assert v.mode("brake") == ACCEPTED
    here = v.core.robot.position
    v.run(3.0)
    assert math.dist(v.core.robot.position, here) < 0.5  # stopped, not 20 m on
    assert v.core.heartbeat().custom_mode == 17


@both
def test_hold_stops_the_craft(flavour: str) -> None:
    v = Vehicle(flavour)
    v.take_off()
    if flavour == "px4":
        v.run(0.5, setpoint=(20.0, 0.0, -2.0))
        assert v.mode("guided") == ACCEPTED  # OFFBOARD after a setpoint stream
    v.run(1.0, setpoint=(20.0, 0.0, -2.0))
    assert v.mode("hold") == ACCEPTED  # AUTO.LOITER / LOITER: MAVSDK's hold
    here = v.core.robot.position
    v.run(3.0)
    assert math.dist(v.core.robot.position, here) < 0.5


@both
def test_refusals_carry_the_firmwares_mav_result(flavour: str) -> None:
    v = Vehicle(flavour)
    refused = REFUSED[flavour]
    v.core.refuse_arm = True
    assert v.arm() == refused  # a failing arming check
    # Forced: ArduPilot skips its checks, PX4 runs them for a command over MAVLink.
    assert v.command(400, 1, 21196) == (refused if flavour == "px4" else ACCEPTED)
    v.core.refuse_arm = False
    assert v.command(400, 0) == ACCEPTED
    assert v.command(400, 0.5) == UNSUPPORTED
    if flavour == "px4":
        assert v.mode("guided") == TEMPORARILY_REJECTED  # OFFBOARD without setpoints
        assert v.command(176, 1, 3, 0) == TEMPORARILY_REJECTED  # POSCTL: not flown here
    else:
        assert v.command(176, 1, 1, 0) == FAILED  # ACRO: not flown here (no RC)
    assert v.command(176, 0, 4, 0) == UNSUPPORTED  # no custom-mode flag
    v.take_off()
    assert v.command(400, 0) == refused  # disarm in the air
    assert v.command(31000) == UNSUPPORTED  # a command it does not know
    v.core.robot.fail_motor(1)
    assert v.mode("hold") == refused


@both
def test_parameters_list_read_and_set_in_the_firmwares_encoding(flavour: str) -> None:
    v = Vehicle(flavour)
    values = v.send(v.gcs.param_request_list_encode(1, 1))
    names = [m.param_id for m in values]
    assert len(names) == values[0].param_count == len(set(names))
    assert [m.param_index for m in values] == list(range(len(names)))
    integer = "MAV_SYS_ID" if flavour == "px4" else "SYSID_THISMAV"
    [sysid] = [m for m in values if m.param_id == integer]
    if flavour == "px4":  # PX4 copies an int32's bytes into the float
        assert sysid.param_type == 6 and sysid.param_value == pytest.approx(1.4e-45, rel=0.1)
    else:  # ArduPilot casts it
        assert sysid.param_type == 4 and sysid.param_value == 1.0
    name = "COM_DISARM_LAND" if flavour == "px4" else "DISARM_DELAY"
    [read] = v.send(v.gcs.param_request_read_encode(1, 1, name.encode(), -1))
    assert read.param_id == name
    [by_index] = v.send(v.gcs.param_request_read_encode(1, 1, b"", read.param_index))
    assert by_index.param_id == name
    wire = 1.0 if flavour == "px4" else 5.0
    [echo] = v.send(v.gcs.param_set_encode(1, 1, name.encode(), wire, read.param_type))
    assert echo.param_value == wire and v.core.param(name) == wire
    assert v.send(v.gcs.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1)) == []
    assert v.send(v.gcs.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, 9)) == []


@both
def test_autopilot_version_on_request_message(flavour: str) -> None:
    v = Vehicle(flavour)
    replies = v.send(v.gcs.command_long_encode(1, 1, 512, 0, 148, 0, 0, 0, 0, 0, 0))
    assert [m.get_type() for m in replies] == ["COMMAND_ACK", "AUTOPILOT_VERSION"]
    version = replies[1]
    assert version.flight_sw_version >> 24 == (1 if flavour == "px4" else 4)
    assert version.capabilities & 8 and version.capabilities & 8192  # COMMAND_INT, MAVLINK2
    encoding = 16 if flavour == "px4" else 1 << 17  # PARAM_ENCODE_BYTEWISE / _C_CAST
    assert version.capabilities & encoding
    assert [m.get_type() for m in v.send(v.gcs.command_long_encode(
        1, 1, 520, 0, 1, 0, 0, 0, 0, 0, 0))] == ["COMMAND_ACK", "AUTOPILOT_VERSION"]
    assert v.command(512, 9999) == (DENIED if flavour == "px4" else FAILED)


@both
def test_global_position_gps_and_home_from_the_geodetic_origin(flavour: str) -> None:
    v = Vehicle(flavour)
    v.take_off()
    if flavour == "px4":  # OFFBOARD after a setpoint stream
        v.run(0.5, setpoint=(4.0, 3.0, -2.0))
        assert v.mode("guided") == ACCEPTED
    v.run(4.0, setpoint=(4.0, 3.0, -2.0))
    sent = {m.get_type(): m for m in v.core.telemetry(v.t + 10.0)}
    lat0, lon0, alt0 = v.core.home_geo()
    assert (lat0, lon0, alt0) == pytest.approx(geodetic(v.core.geo_origin, *HOME))
    home = sent["HOME_POSITION"]
    assert (home.latitude, home.longitude) == (round(lat0 * 1e7), round(lon0 * 1e7))
    pos, gps = sent["GLOBAL_POSITION_INT"], sent["GPS_RAW_INT"]
    north = math.radians(pos.lat / 1e7 - lat0) * 6_371_000
    east = math.radians(pos.lon / 1e7 - lon0) * 6_371_000 * math.cos(math.radians(lat0))
    assert (north, east) == pytest.approx((4.0, 3.0), abs=0.05)
    assert pos.relative_alt == pytest.approx(2000, abs=50)
    assert pos.alt == pytest.approx(alt0 * 1000 + 2000, abs=50)
    assert gps.fix_type == 3 and (gps.lat, gps.lon) == (pos.lat, pos.lon)
    assert gps.satellites_visible > 5


def test_ping_is_answered_by_px4_and_timesync_by_both() -> None:
    px4, apm = Vehicle("px4"), Vehicle("ardupilot")
    [pong] = px4.send(px4.gcs.ping_encode(1234, 7, 0, 0))
    assert (pong.time_usec, pong.seq, pong.target_system, pong.target_component) == (
        1234, 7, 255, 190)
    assert apm.send(apm.gcs.ping_encode(1234, 7, 0, 0)) == []  # ArduPilot ignores PING
    for v in (px4, apm):
        [sync] = v.send(v.gcs.timesync_encode(0, 99))
        assert sync.tc1 >= 0 and sync.ts1 == 99


def test_the_mission_list_is_empty() -> None:
    px4, apm = Vehicle("px4"), Vehicle("ardupilot")
    [count] = px4.send(px4.gcs.mission_request_list_encode(1, 1, 0))
    assert count.count == 0 and (count.target_system, count.target_component) == (255, 190)
    # ArduPilot's mission holds home as item 0.
    [count] = apm.send(apm.gcs.mission_request_list_encode(1, 1, 0))
    assert count.count == 1
    [home] = apm.send(apm.gcs.mission_request_int_encode(1, 1, 0, 0))
    lat = apm.core.home_geo()[0]
    assert home.seq == 0 and home.command == 16 and home.x == round(lat * 1e7)
    [nak] = apm.send(apm.gcs.mission_request_int_encode(1, 1, 1, 0))
    assert nak.get_type() == "MISSION_ACK" and nak.type == 13  # INVALID_SEQUENCE
    [fence] = apm.send(apm.gcs.mission_request_list_encode(1, 1, 1))
    assert fence.count == 0


@both
def test_sys_status_pre_arm_bit(flavour: str) -> None:
    v = Vehicle(flavour)

    def status() -> Any:
        v.t += 100.0  # SYS_STATUS is due again
        return next(m for m in v.core.telemetry(v.t) if m.get_type() == "SYS_STATUS")

    s = status()
    assert s.onboard_control_sensors_present & PREARM and s.onboard_control_sensors_enabled & (
        PREARM)
    assert s.onboard_control_sensors_health & PREARM  # armable: MAVSDK's is_armable
    v.core.refuse_arm = True
    assert not status().onboard_control_sensors_health & PREARM


@pytest.mark.parametrize(("flavour", "mode", "base"), [
    ("px4", "hold", 1 | 4 | 8 | 16), ("px4", "guided", 1 | 4 | 8 | 16),
    ("ardupilot", "guided", 1 | 8 | 16 | 64), ("ardupilot", "land", 1 | 16 | 64),
    ("ardupilot", "brake", 1 | 8 | 16 | 64)])
def test_heartbeat_base_mode_as_the_firmware_sets_it(flavour: str, mode: str,
                                                    base: int) -> None:
    v = Vehicle(flavour)
    v.core.mode = mode
    hb = v.core.heartbeat()
    assert hb.base_mode == base and hb.custom_mode == custom_mode(flavour, mode)  # type: ignore[arg-type]
    v.core.armed = True
    assert v.core.heartbeat().base_mode == base | 128


def test_px4_disarms_after_an_offboard_flight_and_a_landing() -> None:
    v = Vehicle("px4")
    v.run(0.5, setpoint=(0.0, 0.0, -2.0))
    assert v.mode("guided") == ACCEPTED and v.arm() == ACCEPTED
    v.run(4.0, setpoint=(0.0, 0.0, -2.0))
    assert v.height() > 1.8
    assert v.command(21, 0, 0, 0, NAN, NAN, NAN, NAN) == ACCEPTED
    while v.core.robot.mode is not Mode.PARKED:
        v.run(0.05)
        assert v.t < 20.0
    v.run(1.5)
    assert v.core.armed  # COM_DISARM_LAND is 2 s ...
    v.run(1.0)
    assert not v.core.armed  # ... then it disarms by itself


def test_px4_disarms_when_armed_without_taking_off() -> None:
    v = Vehicle("px4")
    assert v.arm() == ACCEPTED
    v.run(9.5)
    assert v.core.armed  # COM_DISARM_PRFLT is 10 s
    v.run(1.0)
    assert not v.core.armed


def test_ardupilot_disarms_on_touch_down_in_land_and_after_disarm_delay_otherwise() -> None:
    v = Vehicle("ardupilot")
    v.take_off()
    assert v.mode("land") == ACCEPTED
    while v.core.robot.mode is not Mode.PARKED:
        v.run(0.05)
        assert v.t < 20.0
    v.run(0.1)
    assert not v.core.armed  # LAND disarms on touch-down
    assert v.mode("guided") == ACCEPTED and v.arm() == ACCEPTED
    v.run(9.5)
    assert v.core.armed  # DISARM_DELAY is 10 s
    v.run(1.0)
    assert not v.core.armed


def test_set_mode_message_is_acked_as_each_firmware_does() -> None:
    for flavour, acked in (("px4", 176), ("ardupilot", 11)):
        v = Vehicle(flavour)
        number = custom_mode(flavour, "land")  # type: ignore[arg-type]
        [ack] = v.send(v.gcs.set_mode_encode(1, 1, number))
        assert (ack.command, ack.result) == (acked, ACCEPTED) and v.core.mode == "land"


@both
def test_nan_and_out_of_range_parameters_are_answered_not_raised(flavour: str) -> None:
    v = Vehicle(flavour)
    for command in (400, 176, 22, 21, 20, 192, 511, 512, 520):
        assert v.command(command, NAN, NAN, NAN, NAN, NAN, NAN, NAN) in range(5)
        assert v.command(command, 1e30, -1e30, 1e30, 1e30, 1e30, 1e30, 1e30) in range(5)
    # A setpoint of NaNs is not flown: the craft stays where it was told to be.
    v.take_off()
    if flavour == "px4":
        v.run(0.5, setpoint=(1.0, 1.0, -2.0))
        assert v.mode("guided") == ACCEPTED
    v.run(3.0, setpoint=(1.0, 1.0, -2.0))
    v.run(1.0, setpoint=(NAN, NAN, NAN))
    assert math.dist(v.core.robot.position, (HOME[0] + 1.0, HOME[1] + 1.0, 2.0)) < 0.2
