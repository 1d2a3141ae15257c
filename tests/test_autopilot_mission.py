"""The simulated autopilot's mission protocol and the missions it flies, its parameters
and its message rates, as PX4 and ArduPilot answer them (docs/mavlink.md, "What the
simulated autopilot answers"): its logic on virtual time over a point-mass craft, fed
messages that went through pymavlink's encoder and parser, as from a ground station.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest

pytest.importorskip("mujoco")

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from sim.physics.autopilot_core import AutopilotCore
from sim.physics.mavlink_defs import geodetic
from sim.physics.point import PointRobot
from sim.physics.robot import Mode
from swarmd.link.mavlink_modes import mode_number

NAN = math.nan
HOME = (2.0, -1.0, 0.0)
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED, FAILED = 0, 1, 2, 3, 4
both = pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
REL = 6  # MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


class Ground:
    """A ground station (system 255) and an `AutopilotCore` on virtual time; every
    message the autopilot sends (replies and telemetry) lands in `heard`."""

    def __init__(self, flavour: str) -> None:
        self.core = AutopilotCore(PointRobot(1, HOME), flavour, 1)  # type: ignore[arg-type]
        self.flavour = flavour
        self.gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = mavlink2.MAVLink(None)
        self.t = 0.0
        self.heard: list[Any] = []
        self.timed: list[tuple[float, Any]] = []
        """(virtual time, message) of what `run` heard."""

    def send(self, msg: Any) -> list[Any]:
        [decoded] = self.parser.parse_buffer(msg.pack(self.gcs))
        replies = self.core.handle(decoded, self.t)
        self.heard += replies
        return replies

    def command(self, command: int, *params: float) -> int:
        p = (*params, *([0.0] * (7 - len(params))))
        replies = self.send(self.gcs.command_long_encode(1, 1, command, 0, *p))
        assert replies[0].get_type() == "COMMAND_ACK" and replies[0].command == command
        return int(replies[0].result)

    def mode(self, name: str) -> int:
        main, sub = mode_number(self.core.flavour, name)
        return self.command(176, 1, main, sub)

    def run(self, seconds: float) -> None:
        end = self.t + seconds
        while self.t < end - 1e-9:
            self.t += 0.05
            self.core.robot.step_until(self.t)
            self.core.control(self.t)
            sent = self.core.mission.tick(self.t) + self.core.telemetry(self.t)
            self.heard += sent
            self.timed += [(self.t, m) for m in sent]

    def run_until(self, done: Any, limit: float) -> float:
        start = self.t
        while not done():
            self.run(0.05)
            assert self.t - start < limit, "timed out (virtual time)"
        return self.t - start

    def kinds(self, kind: str) -> list[Any]:
        return [m for m in self.heard if m.get_type() == kind]

    def height(self) -> float:
        return self.core.robot.position[2] - HOME[2]

    def latlon(self, east: float, north: float) -> tuple[int, int]:
        lat, lon, _ = geodetic(self.core.geo_origin, HOME[0] + east, HOME[1] + north, 0.0)
        return round(lat * 1e7), round(lon * 1e7)

    def item(self, seq: int, command: int, p: tuple[float, ...] = (0, 0, 0, 0),
             east: float = 0.0, north: float = 0.0, alt: float = 0.0,
             frame: int = REL) -> Any:
        x, y = self.latlon(east, north) if (east or north) else (0, 0)
        return self.gcs.mission_item_int_encode(1, 1, seq, frame, command, 0, 1, *p, x, y, alt)

    def upload(self, items: list[Any]) -> Any:
        """The upload as a ground station does it: MISSION_COUNT, then each item the
        autopilot asks for; the final MISSION_ACK."""
        [request] = self.send(self.gcs.mission_count_encode(1, 1, len(items)))
        while request.get_type() == "MISSION_REQUEST_INT":
            [request] = self.send(items[request.seq])
        return request

    def download(self) -> list[Any]:
        [count] = self.send(self.gcs.mission_request_list_encode(1, 1))
        got = [self.send(self.gcs.mission_request_int_encode(1, 1, s))[0]
               for s in range(count.count)]
        self.send(self.gcs.mission_ack_encode(1, 1, 0))
        return got

    def plan(self) -> list[Any]:
        """Six items: take-off to 3 m, speed 1.5 m/s, three waypoints (one held 1 s),
        land. ArduPilot's list starts with home."""
        body = [(22, (0, 0, 0, 0), 0.0, 0.0, 3.0), (178, (1, 1.5, -1, 0), 0.0, 0.0, 0.0),
                (16, (0, 0.5, 0, 0), 0.0, 4.0, 3.0), (16, (1, 0.5, 0, 0), 4.0, 4.0, 3.0),
                (16, (0, 0.5, 0, 0), 4.0, 0.0, 2.0), (21, (0, 0, 0, 0), 4.0, 0.0, 0.0)]
        lat, lon, alt = self.core.home_geo()
        head = [self.gcs.mission_item_int_encode(1, 1, 0, 0, 16, 0, 1, 0, 0, 0, 0,
                                                 round(lat * 1e7), round(lon * 1e7), alt)]
        first = head if self.flavour == "ardupilot" else []
        return first + [self.item(len(first) + i, c, p, e, n, a)
                        for i, (c, p, e, n, a) in enumerate(body)]


def fields(item: Any) -> tuple[Any, ...]:
    return (item.seq, item.frame, item.command, item.autocontinue, item.param1, item.param2,
            item.param3, item.param4, item.x, item.y, item.z)


@both
def test_a_mission_uploads_and_reads_back_identical(flavour: str) -> None:
    g = Ground(flavour)
    items = g.plan()
    ack = g.upload(items)
    assert ack.get_type() == "MISSION_ACK" and ack.type == 0
    back = g.download()
    assert [fields(m) for m in back] == [fields(m) for m in items]
    # The float form too (MISSION_REQUEST -> MISSION_ITEM, degrees).
    [first] = g.send(g.gcs.mission_request_encode(1, 1, 2))
    assert first.get_type() == "MISSION_ITEM" and first.x == pytest.approx(items[2].x / 1e7)


@both
def test_clear_and_refusals_are_answered(flavour: str) -> None:
    g = Ground(flavour)
    assert g.upload(g.plan()).type == 0
    [ack] = g.send(g.gcs.mission_clear_all_encode(1, 1))
    assert ack.get_type() == "MISSION_ACK" and ack.type == 0
    [count] = g.send(g.gcs.mission_request_list_encode(1, 1))
    assert count.count == (1 if flavour == "ardupilot" else 0)  # ArduPilot keeps home
    # A command it does not fly: MAV_MISSION_UNSUPPORTED, the upload ends.
    odd = [g.item(0, 31000), g.item(1, 16, alt=2.0)]
    assert g.upload(odd).type == 3
    # A terrain frame: UNSUPPORTED_FRAME.
    assert g.upload([g.item(0, 16, alt=2.0, frame=11)]).type == 2
    # Too many items: NO_SPACE.
    [nak] = g.send(g.gcs.mission_count_encode(1, 1, 5000))
    assert nak.type == 4
    # An item with no upload going on: ERROR; a geofence upload: UNSUPPORTED.
    [nak] = g.send(g.item(0, 16, alt=2.0))
    assert nak.get_type() == "MISSION_ACK" and nak.type == 1
    [nak] = g.send(g.gcs.mission_count_encode(1, 1, 3, 1))
    assert nak.type == 3 and nak.mission_type == 1


@both
def test_an_unanswered_request_is_repeated_then_the_upload_given_up(flavour: str) -> None:
    """ArduPilot cancels with MISSION_ACK OPERATION_CANCELLED; PX4 sends no MISSION_ACK,
    only its critical "Operation timeout" text (`mavlink_mission.cpp`)."""
    g = Ground(flavour)
    [request] = g.send(g.gcs.mission_count_encode(1, 1, 2))
    assert request.seq == 0
    g.run(1.2)
    assert [m.seq for m in g.kinds("MISSION_REQUEST_INT")] == [0, 0, 0]  # asked again
    g.run(6.0)
    texts = [(m.severity, m.text) for m in g.kinds("STATUSTEXT")]
    if flavour == "px4":
        assert g.kinds("MISSION_ACK") == [] and (2, "Operation timeout") in texts
    else:
        [cancel] = g.kinds("MISSION_ACK")
        assert cancel.type == 15  # OPERATION_CANCELLED
    [nak] = g.send(g.item(0, 16, alt=3.0))  # too late: no upload going on
    assert nak.get_type() == "MISSION_ACK" and nak.type == 1


def test_ardupilot_partial_upload_and_download() -> None:
    g = Ground("ardupilot")
    items = g.plan()
    assert g.upload(items).type == 0
    [request] = g.send(g.gcs.mission_write_partial_list_encode(1, 1, 3, 3))
    assert request.seq == 3
    [ack] = g.send(g.item(3, 16, (0, 0, 0, 0), 6.0, 6.0, 5.0))
    assert ack.type == 0
    got = g.send(g.gcs.mission_request_partial_list_encode(1, 1, 2, 4))
    assert [m.seq for m in got] == [2, 3, 4] and got[1].z == 5.0
    px4 = Ground("px4")
    [nak] = px4.send(px4.gcs.mission_write_partial_list_encode(1, 1, 0, 0))
    assert nak.type == 3  # PX4 has no partial upload


@both
def test_the_mission_is_flown_with_progress_to_touch_down(flavour: str) -> None:
    g = Ground(flavour)
    items = g.plan()
    assert g.upload(items).type == 0
    first = 1 if flavour == "ardupilot" else 0
    if flavour == "px4":
        assert g.mode("mission") == ACCEPTED and g.command(400, 1) == ACCEPTED
    else:
        assert g.mode("auto") == ACCEPTED
        assert g.command(400, 1) == FAILED  # ArduCopter does not arm in AUTO
        assert g.mode("guided") == ACCEPTED and g.command(400, 1) == ACCEPTED
        assert g.command(300, 0, 0) == ACCEPTED  # MISSION_START: AUTO, from the take-off
    seconds = g.run_until(lambda: not g.core.armed, 60.0)
    reached = [m.seq for m in g.kinds("MISSION_ITEM_REACHED")]
    assert reached == list(range(first, len(items)))
    currents = [m.seq for m in g.kinds("MISSION_CURRENT")]
    assert currents[0] == first and max(currents) == len(items) - 1
    x, y, _ = g.core.robot.position
    assert math.hypot(x - HOME[0] - 4.0, y - HOME[1]) < 0.6  # landed at the last item
    assert g.core.robot.mode is Mode.PARKED and g.core.runner.state == 5
    # 4 m at 1.5 m/s (the DO_CHANGE_SPEED) and a 1 s hold are in it: no cutting short.
    assert seconds > 3 * 4.0 / 1.5 + 1.0
    assert g.core.mission_current().mission_state == 5  # MISSION_STATE_COMPLETE
    # The waypoint held 1 s: ArduCopter says it is reached on arrival, a second before
    # the next item is current; PX4 once the hold is over, the next item current at once.
    held = first + 3
    reached_at = next(t for t, m in g.timed if m.get_type() == "MISSION_ITEM_REACHED"
                      and m.seq == held)
    next_at = next(t for t, m in g.timed if m.get_type() == "MISSION_CURRENT"
                   and m.seq == held + 1)
    assert next_at - reached_at == pytest.approx(1.0 if flavour == "ardupilot" else 0.0,
                                                 abs=0.11)


@both
def test_set_current_and_jump(flavour: str) -> None:
    g = Ground(flavour)
    first = 1 if flavour == "ardupilot" else 0
    items = g.plan()[: first + 3]  # take-off, speed, one waypoint
    items.append(g.item(first + 3, 177, (first + 2, 1, 0, 0)))  # jump back once
    assert g.upload(items).type == 0
    [current] = g.send(g.gcs.mission_set_current_encode(1, 1, first + 2))
    assert current.get_type() == "MISSION_CURRENT" and current.seq == first + 2
    [current] = g.send(g.gcs.mission_set_current_encode(1, 1, 99))
    assert current.seq == first + 2  # out of range: unchanged
    assert g.command(224, first) == ACCEPTED and g.command(224, 99) == DENIED
    g.mode("guided")
    g.command(400, 1)
    if flavour == "px4":
        assert g.mode("mission") == ACCEPTED
    else:
        assert g.command(300, 0, 0) == ACCEPTED
    g.run_until(lambda: g.core.runner.state == 5, 40.0)
    reached = [m.seq for m in g.kinds("MISSION_ITEM_REACHED")]
    assert reached.count(first + 2) == 2  # the waypoint twice: DO_JUMP repeated it once
    # Done, still in the mission mode: a new current item is flown from there.
    g.send(g.gcs.mission_set_current_encode(1, 1, first + 2))
    g.run_until(lambda: g.core.runner.state == 5, 40.0)
    reached = [m.seq for m in g.kinds("MISSION_ITEM_REACHED")]
    # Once more: the DO_JUMP's repeat is spent (both firmwares reset it only when the
    # mission restarts from its start or is replaced).
    assert reached.count(first + 2) == 3


def test_mission_mode_needs_a_mission_and_arducopter_a_takeoff_first() -> None:
    px4 = Ground("px4")
    assert px4.mode("mission") == TEMPORARILY_REJECTED
    apm = Ground("ardupilot")
    assert apm.command(300, 0, 0) == FAILED  # disarmed, and no mission
    home = apm.plan()[0]
    assert apm.upload([home, apm.item(1, 16, alt=3.0, east=2.0)]).type == 0
    assert apm.mode("guided") == ACCEPTED and apm.command(400, 1) == ACCEPTED
    assert apm.command(300, 0, 0) == FAILED  # armed on the ground, no NAV_TAKEOFF first
    assert apm.command(300, 1, 0) == DENIED  # ArduPilot takes no first / last item
    assert any(b"Missing Takeoff" in m.text.encode() for m in apm.core.outbox)


def said(g: Ground) -> list[str]:
    return [m.text for m in g.core.outbox if m.get_type() == "STATUSTEXT"]


def test_px4_mission_start_arms_and_flies_from_the_ground() -> None:
    """PX4's Commander takes MISSION_START as Mission mode and arming at once: a ground
    station (MAVProxy's `long MISSION_START`) starts a mission with it alone."""
    g = Ground("px4")
    assert g.command(300, 0, 0) == DENIED  # no mission
    assert "Mission start denied! No valid mission" in said(g)
    items = g.plan()
    assert g.upload(items).type == 0
    assert g.command(300, len(items), 0) == DENIED  # no such item
    assert g.command(300, NAN, 0) == DENIED
    assert not g.core.armed and g.core.mode != "mission"
    g.core.refuse_arm = True
    assert g.command(300, 0, 0) == TEMPORARILY_REJECTED  # arming checks failed
    assert not g.core.armed and g.core.mode == "mission"  # the mode changed all the same
    g.core.refuse_arm = False
    assert g.command(300, 0, 0) == ACCEPTED
    assert g.core.armed and g.core.mode == "mission"
    g.run_until(lambda: not g.core.armed, 60.0)
    assert [m.seq for m in g.kinds("MISSION_ITEM_REACHED")] == list(range(len(items)))
    assert g.core.robot.mode is Mode.PARKED


# -- parameters ---------------------------------------------------------------------------
@pytest.mark.parametrize(("flavour", "names"), [
    ("px4", ["MPC_XY_VEL_MAX", "MPC_XY_CRUISE", "RTL_RETURN_ALT", "NAV_DLL_ACT",
             "MIS_TAKEOFF_ALT", "COM_DISARM_LAND", "NAV_ACC_RAD"]),
    ("ardupilot", ["WPNAV_SPEED", "RTL_ALT", "PILOT_TKOFF_ALT", "ARMING_CHECK",
                   "FS_GCS_ENABLE", "DISARM_DELAY", "SR0_POSITION"])])
def test_the_parameters_a_ground_station_reads(flavour: str, names: list[str]) -> None:
    g = Ground(flavour)
    listed = {m.param_id: m for m in g.send(g.gcs.param_request_list_encode(1, 1))}
    assert set(names) <= set(listed)
    name = names[0]
    value = 3.0 if flavour == "px4" else 300.0
    [echo] = g.send(g.gcs.param_set_encode(1, 1, name.encode(), value, 9))
    assert echo.param_id == name and echo.param_value == value
    [read] = g.send(g.gcs.param_request_read_encode(1, 1, name.encode(), -1))
    assert read.param_value == value


@both
def test_the_cruise_speed_parameter_slows_a_goto(flavour: str) -> None:
    def goto_time(speed: float | None) -> float:
        g = Ground(flavour)
        if speed is not None:
            name, value = ("MPC_XY_CRUISE", speed) if flavour == "px4" else (
                "WPNAV_SPEED", speed * 100)
            g.send(g.gcs.param_set_encode(1, 1, name.encode(), value, 9))
        g.mode("guided")
        g.command(400, 1)
        g.command(22, 0, 0, 0, NAN, NAN, NAN, g.core.home_geo()[2] + 2.0
                  if flavour == "px4" else 2.0)
        g.run(5.0)
        x, y = g.latlon(0.0, 8.0)
        g.send(g.gcs.command_int_encode(1, 1, 6, 192, 0, 0, -1, 1, 0, NAN, x, y, 2.5))
        return g.run_until(lambda: abs(g.core.robot.position[1] - HOME[1] - 8.0) < 0.2, 30)

    fast, slow = goto_time(None), goto_time(1.0)
    assert slow > 7.0 and fast < 6.0  # 8 m at 1 m/s; at the craft's own 2.25 m/s


def test_ardupilot_rtl_climbs_to_rtl_alt_then_returns_and_lands() -> None:
    g = Ground("ardupilot")
    g.mode("guided")
    g.command(400, 1)
    g.command(22, 0, 0, 0, 0, 0, 0, 2.0)
    g.run(4.0)
    x, y = g.latlon(0.0, 10.0)
    g.send(g.gcs.command_int_encode(1, 1, 6, 192, 0, 0, -1, 1, 0, NAN, x, y, 2.0))
    g.run(8.0)
    assert g.mode("rtl") == ACCEPTED
    top = 0.0
    while g.core.armed:
        g.run(0.1)
        top = max(top, g.height())
        assert g.t < 120
    # RTL_ALT 15 m, lowered by the cone (3 x 10 m = 30 m: not lowered).
    assert top == pytest.approx(15.0, abs=0.5)
    assert math.dist(g.core.robot.position[:2], HOME[:2]) < 0.6


def test_px4_rtl_follows_its_return_altitude_parameter() -> None:
    g = Ground("px4")
    g.send(g.gcs.param_set_encode(1, 1, b"RTL_RETURN_ALT", 6.0, 9))
    g.command(400, 1)
    g.command(22, 0, 0, 0, NAN, NAN, NAN, NAN)
    g.run(4.0)
    x, y = g.latlon(0.0, 15.0)
    g.send(g.gcs.command_int_encode(1, 1, 6, 192, 0, 0, -1, 1, 0, NAN, x, y, 2.5))
    g.run(9.0)
    assert g.mode("rtl") == ACCEPTED
    top = 0.0
    while g.core.robot.mode is not Mode.PARKED:
        g.run(0.1)
        top = max(top, g.height())
        assert g.t < 120
    # 15 m away (beyond NAV_ACC_RAD and RTL_MIN_DIST): up to 2 x NAV_ACC_RAD = 20 m at
    # least, RTL_RETURN_ALT being lower.
    assert top == pytest.approx(20.0, abs=0.5)


@both
def test_gcs_link_loss_failsafe_follows_its_parameter(flavour: str) -> None:
    g = Ground(flavour)
    name, value = ("NAV_DLL_ACT", 3) if flavour == "px4" else ("FS_GCS_ENABLE", 5)
    # PX4 takes an integer's bytes in the float (PARAM_ENCODE_BYTEWISE), ArduPilot casts.
    wire = struct.unpack("<f", struct.pack("<i", value))[0] if flavour == "px4" else value
    g.send(g.gcs.param_set_encode(1, 1, name.encode(), wire, 6 if flavour == "px4" else 2))
    assert g.core.param(name) == value
    g.mode("guided")
    g.command(400, 1)
    g.command(22, 0, 0, 0, NAN, NAN, NAN, NAN if flavour == "px4" else 2.0)
    g.send(g.gcs.heartbeat_encode(6, 8, 0, 0, 4))  # a ground station, then silence
    g.run(4.0)
    assert g.core.mode != "land"
    g.run(12.0)
    assert g.core.mode == "land"  # COM_DL_LOSS_T 10 s / FS_GCS_TIMEOUT 5 s, then LAND


# -- rates --------------------------------------------------------------------------------
@both
def test_message_rates_set_read_back_and_off(flavour: str) -> None:
    g = Ground(flavour)
    g.run(1.0)

    def count(kind: str, seconds: float = 4.0) -> float:
        """Hz of `kind` over `seconds`, from the stamps of the first and last sent."""
        g.heard = []
        g.run(seconds)
        stamps = [m.time_boot_ms for m in g.kinds(kind)]
        return 0.0 if len(stamps) < 2 else 1000 * (len(stamps) - 1) / (
            stamps[-1] - stamps[0])

    assert count("ATTITUDE") == pytest.approx(10.0, rel=0.1)
    assert g.command(511, 30, 40000) == ACCEPTED  # ATTITUDE every 40 ms: 25 Hz
    assert count("ATTITUDE") == pytest.approx(20.0, rel=0.1)  # the 20 Hz tick here
    assert g.command(511, 33, 500000) == ACCEPTED  # GLOBAL_POSITION_INT at 2 Hz
    assert count("GLOBAL_POSITION_INT") == pytest.approx(2.0, rel=0.1)
    g.heard = []
    assert g.command(510, 33) == ACCEPTED
    [interval] = g.kinds("MESSAGE_INTERVAL")
    assert (interval.message_id, interval.interval_us) == (33, 500000)
    assert g.command(511, 33, -1) == ACCEPTED
    assert count("GLOBAL_POSITION_INT") == 0.0
    g.command(510, 33)
    assert g.kinds("MESSAGE_INTERVAL")[-1].interval_us == -1
    assert g.command(511, 33, 0) == ACCEPTED  # back to the default
    assert count("GLOBAL_POSITION_INT") == pytest.approx(
        5.0 if flavour == "px4" else 10.0, rel=0.1)  # ArduPilot: SR0_POSITION
    # A message it cannot stream: each firmware's refusal; "not available" when asked.
    assert g.command(511, 9999, 100000) == (FAILED if flavour == "px4" else DENIED)
    assert g.command(510, 9999) == (ACCEPTED if flavour == "px4" else FAILED)
    assert g.command(511, 0, 500000) == (FAILED if flavour == "px4" else ACCEPTED)  # HEARTBEAT
    assert g.kinds("MESSAGE_INTERVAL")[-1].interval_us == 0


def test_ardupilot_stream_groups() -> None:
    g = Ground("ardupilot")
    g.send(g.gcs.request_data_stream_encode(1, 1, 10, 4, 1))  # EXTRA1 (ATTITUDE) 4 Hz
    assert g.core.param("SR0_EXTRA1") == 4
    g.run(1.0)
    g.heard = []
    g.run(5.0)
    stamps = [m.time_boot_ms for m in g.kinds("ATTITUDE")]
    assert 1000 * (len(stamps) - 1) / (stamps[-1] - stamps[0]) == pytest.approx(4.0, rel=0.1)
    g.send(g.gcs.request_data_stream_encode(1, 1, 0, 0, 0))  # every group off
    g.heard = []
    g.run(3.0)
    assert {m.get_type() for m in g.heard} <= {"HEARTBEAT", "HOME_POSITION"}
    g.send(g.gcs.param_set_encode(1, 1, b"SR0_POSITION", 5, 4))  # the parameter too
    g.heard = []
    g.run(4.0)
    stamps = [m.time_boot_ms for m in g.kinds("GLOBAL_POSITION_INT")]
    assert 1000 * (len(stamps) - 1) / (stamps[-1] - stamps[0]) == pytest.approx(5.0, rel=0.1)


# -- details a ground station shows -------------------------------------------------------
@both
def test_capabilities_and_protocol_version(flavour: str) -> None:
    g = Ground(flavour)
    replies = g.send(g.gcs.command_long_encode(1, 1, 520, 0, 1, 0, 0, 0, 0, 0, 0))
    caps = replies[1].capabilities
    assert caps & 128 and caps & 256  # SET_POSITION_TARGET_LOCAL_NED, _GLOBAL_INT
    assert not caps & (512 | 32)  # no terrain, no FTP: not simulated
    replies = g.send(g.gcs.command_long_encode(1, 1, 519, 0, 0, 0, 0, 0, 0, 0, 0))
    if flavour == "px4":
        assert replies[0].result == ACCEPTED
        data = replies[1].pack(g.core.mav)
        assert data[7:10] == bytes([44, 1, 0]) and data[10:12] == (200).to_bytes(2, "little")
    else:
        assert [r.result for r in replies] == [UNSUPPORTED]


def test_px4_takeoff_below_mis_takeoff_alt_climbs_to_it() -> None:
    g = Ground("px4")
    g.command(400, 1)
    assert g.command(22, 0, 0, 0, NAN, NAN, NAN, g.core.home_geo()[2] + 1.0) == ACCEPTED
    g.run(6.0)
    assert g.height() == pytest.approx(2.5, abs=0.1)
    assert any(b"minimum takeoff" in m.text.encode() for m in g.kinds("STATUSTEXT"))


def test_px4_pause_and_change_altitude_by_reposition() -> None:
    g = Ground("px4")
    g.command(400, 1)
    g.command(22, 0, 0, 0, NAN, NAN, NAN, NAN)
    g.run(5.0)
    here = g.core.robot.position
    # QGroundControl's "change altitude": DO_REPOSITION, lat/lon NaN, a new altitude.
    assert g.command(192, -1, 1, 0, NAN, NAN, NAN, g.core.home_geo()[2] + 5.0) == ACCEPTED
    g.run(5.0)
    assert g.height() == pytest.approx(5.0, abs=0.2)
    assert math.dist(g.core.robot.position[:2], here[:2]) < 0.1
    assert g.command(192, -1, 1, 0, NAN, NAN, NAN, NAN) == ACCEPTED  # "pause"
    assert g.command(192, -1, 1, 0, NAN, 500.0, 0.0, 10.0) == DENIED


def test_ardupilot_offset_and_global_setpoints_and_bad_reposition() -> None:
    g = Ground("ardupilot")
    assert g.core.heartbeat().custom_mode == 0  # boots in STABILIZE
    assert g.mode("stabilize") == ACCEPTED
    g.mode("guided")
    g.command(400, 1)
    g.command(22, 0, 0, 0, 0, 0, 0, 2.0)
    g.run(4.0)
    # QGroundControl's "change altitude": LOCAL_OFFSET_NED, z only.
    g.send(g.gcs.set_position_target_local_ned_encode(0, 1, 1, 7, 0b110111111000, 0, 0, -3,
                                                      0, 0, 0, 0, 0, 0, 0, 0))
    g.run(4.0)
    assert g.height() == pytest.approx(5.0, abs=0.2)
    x, y = g.latlon(3.0, 0.0)
    g.send(g.gcs.set_position_target_global_int_encode(0, 1, 1, 6, 0b110111111000, x, y,
                                                       4.0, 0, 0, 0, 0, 0, 0, 0, 0))
    g.run(5.0)
    assert math.dist(g.core.robot.position, (HOME[0] + 3.0, HOME[1], 4.0)) < 0.2
    assert g.command(192, -1, 1, 0, NAN, 0.0, 0.0, 10.0) == DENIED  # 0, 0 is no place


@both
def test_the_mujoco_quadrotor_flies_the_mission_too(flavour: str) -> None:
    """The same mission over the MuJoCo quadrotor: its controller follows the legs (at
    the 1.5 m/s of the DO_CHANGE_SPEED, below its own cruise) to touch-down."""
    from sim.physics.robot import QuadRobot

    g = Ground(flavour)
    g.core = AutopilotCore(QuadRobot(1, HOME), flavour, 1)  # type: ignore[arg-type]
    items = g.plan()
    assert g.upload(items).type == 0
    first = 1 if flavour == "ardupilot" else 0
    if flavour == "px4":
        assert g.mode("mission") == ACCEPTED and g.command(400, 1) == ACCEPTED
    else:
        assert g.mode("guided") == ACCEPTED and g.command(400, 1) == ACCEPTED
        assert g.command(300, 0, 0) == ACCEPTED
    g.run_until(lambda: not g.core.armed, 60.0)
    assert [m.seq for m in g.kinds("MISSION_ITEM_REACHED")] == list(range(first, len(items)))
    x, y, z = g.core.robot.position
    assert math.hypot(x - HOME[0] - 4.0, y - HOME[1]) < 0.6 and z - HOME[2] < 0.1
    assert g.core.robot.mode is Mode.PARKED
