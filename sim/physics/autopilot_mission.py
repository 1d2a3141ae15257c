"""The simulated autopilot's mission (`sim.physics.autopilot` has the whole picture): the
MAVLink mission protocol as PX4 (`modules/mavlink/mavlink_mission.cpp`) and ArduPilot
(`GCS_MAVLink/MissionItemProtocol.cpp`, `AP_Mission`) speak it, and the items it flies.

Protocol: upload (MISSION_COUNT, then the autopilot asks for every item with
MISSION_REQUEST_INT, ending with MISSION_ACK), download (MISSION_REQUEST_LIST, then
MISSION_REQUEST_INT / MISSION_REQUEST per item), ArduPilot's partial upload and download
(MISSION_WRITE_PARTIAL_LIST, MISSION_REQUEST_PARTIAL_LIST), MISSION_CLEAR_ALL and
MISSION_SET_CURRENT. An unanswered request is sent again every `RETRY` s; after
`TRIES` the transfer is given up as each firmware does: ArduPilot cancels it with
MISSION_ACK OPERATION_CANCELLED (`MissionItemProtocol.cpp` update), PX4 says only
"Operation timeout" in a critical STATUSTEXT and goes idle (`mavlink_mission.cpp` send:
no MISSION_ACK, the client learns it from that text or its own timeout). ArduPilot's mission
holds home as item 0 (a download returns home there whatever was uploaded); PX4's
starts at the first item.

Items flown (`MissionRunner`): NAV_WAYPOINT (param1 hold s; PX4 param2 acceptance
radius), NAV_LOITER_UNLIM, NAV_LOITER_TIME, NAV_RETURN_TO_LAUNCH, NAV_LAND, NAV_TAKEOFF,
DO_CHANGE_SPEED and DO_JUMP. Camera, gimbal, region-of-interest and yaw items are
stored and passed over: the simulation has no payload. Any other command, a geofence or
rally point list, or a terrain frame is refused at upload (MISSION_ACK UNSUPPORTED or
UNSUPPORTED_FRAME) as the firmware refuses what it cannot fly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from sim.physics.autopilot_nav import APM_ALT_RADIUS, Leg, Param, Speeds, rtl_legs
from sim.physics.mavlink_defs import FRAME_GLOBAL, FRAME_GLOBAL_RELATIVE_ALT
from swarmd.base.functions import Vec3
from swarmd.link.mavlink_modes import Flavour
from swarmd.link.mavlink_pilot import geodetic_offset

RETRY = 0.5
"""s before an unanswered item request is sent again."""
TRIES = 10
"""Requests of one item before the upload is cancelled (5 s, ArduPilot's upload
timeout is 8 s and PX4's 5 s)."""
MAX_ITEMS: dict[Flavour, int] = {"px4": 2000, "ardupilot": 700}
"""Items the mission storage holds (PX4's dataman, ArduPilot SITL's storage)."""
# MAV_MISSION_RESULT
OK, ERROR, UNSUPPORTED_FRAME, UNSUPPORTED, NO_SPACE = 0, 1, 2, 3, 4
INVALID_SEQUENCE, DENIED, CANCELLED = 13, 14, 15
# MISSION_STATE of MISSION_CURRENT
NO_MISSION, NOT_STARTED, ACTIVE, COMPLETE = 1, 2, 3, 5

NAV = {16, 17, 19, 20, 21, 22}
"""NAV_WAYPOINT, LOITER_UNLIM, LOITER_TIME, RETURN_TO_LAUNCH, LAND, TAKEOFF."""
DO_FLOWN = {177, 178}
"""DO_JUMP, DO_CHANGE_SPEED."""
PAYLOAD = {115, 195, 197, 201, 203, 205, 206, 530, 1000, 2000, 2001, 2500, 2501}
"""CONDITION_YAW, ROI, camera and gimbal commands: stored, passed over when flown."""
FRAMES = {FRAME_GLOBAL, 2, FRAME_GLOBAL_RELATIVE_ALT, 5, 6}
"""GLOBAL, MISSION, GLOBAL_RELATIVE_ALT and their _INT forms."""


@dataclass(frozen=True)
class Item:
    """One mission item as MISSION_ITEM_INT carries it (x, y: degrees * 1e7)."""

    frame: int
    command: int
    autocontinue: int
    params: tuple[float, float, float, float]
    x: int
    y: int
    z: float

    @classmethod
    def of(cls, msg: Any) -> Item:
        x, y = msg.x, msg.y
        if msg.get_type() == "MISSION_ITEM":  # the float form: degrees
            x, y = (round(v * 1e7) if math.isfinite(v) else 0 for v in (x, y))
        return cls(msg.frame, msg.command, msg.autocontinue,
                   (msg.param1, msg.param2, msg.param3, msg.param4), int(x), int(y), msg.z)

    def check(self) -> int:
        """The MAV_MISSION_RESULT of accepting it."""
        if self.command not in NAV | DO_FLOWN | PAYLOAD:
            return UNSUPPORTED
        if self.frame not in FRAMES:
            return UNSUPPORTED_FRAME
        return OK


class _Upload:
    def __init__(self, peer: tuple[int, int], first: int, last: int, t: float) -> None:
        self.peer, self.next, self.last = peer, first, last
        self.items: dict[int, Item] = {}
        self.sent_at, self.tries = t, 1


class MissionStore:
    """The mission list and its transfer protocol, sans-I/O: each method takes a
    message and returns the replies (pymavlink messages built with `mav`)."""

    def __init__(self, flavour: Flavour, mav: Any, home_item: Any) -> None:
        self.flavour, self.mav = flavour, mav
        self._home_item = home_item
        """() -> Item: ArduPilot's item 0, home as it is now."""
        self.items: list[Item] = []
        self.current = self.first
        self.version = 0
        """Counts uploads and clears (the runner restarts on a new mission)."""
        self._upload: _Upload | None = None

    @property
    def first(self) -> int:
        """The first item flown: ArduPilot's item 0 is home."""
        return 1 if self.flavour == "ardupilot" else 0

    def listed(self) -> list[Item]:
        """The mission as a download returns it."""
        if self.flavour == "ardupilot":
            return [self._home_item(), *self.items[1:]]
        return list(self.items)

    def handle(self, msg: Any, t: float) -> list[Any]:
        kind = msg.get_type()
        peer = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = getattr(msg, "mission_type", 0)
        if mtype != 0 and kind in ("MISSION_COUNT", "MISSION_WRITE_PARTIAL_LIST"):
            return [self._ack(peer, UNSUPPORTED, mtype)]  # no geofence or rally points
        if kind == "MISSION_REQUEST_LIST":
            count = len(self.listed()) if mtype == 0 else 0
            return [self.mav.mission_count_encode(*peer, count, mtype)]
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            return self._send_item(msg, peer, mtype, kind == "MISSION_REQUEST_INT")
        if kind == "MISSION_COUNT":
            return self._start(peer, 0, msg.count - 1, msg.count, t)
        if kind == "MISSION_WRITE_PARTIAL_LIST":
            return self._partial(msg, peer, t)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._receive(msg, peer, t)
        if kind == "MISSION_REQUEST_PARTIAL_LIST":
            return self._partial_list(msg, peer)
        if kind == "MISSION_CLEAR_ALL":
            self._upload = None
            if mtype == 0:
                self._replace([])
            return [self._ack(peer, OK, mtype)]
        if kind == "MISSION_ACK" and self._upload is not None and self._upload.peer == peer:
            self._upload = None  # the client gave up (or cancels)
        return []

    def _ack(self, peer: tuple[int, int], result: int, mtype: int = 0) -> Any:
        return self.mav.mission_ack_encode(peer[0], peer[1], result, mtype)

    def _replace(self, items: list[Item]) -> None:
        self.items = items
        self.current = self.first
        self.version += 1

    # -- download ---------------------------------------------------------------------
    def _send_item(self, msg: Any, peer: tuple[int, int], mtype: int, as_int: bool) -> list[Any]:
        items = self.listed() if mtype == 0 else []
        if not 0 <= msg.seq < len(items):
            return [self._ack(peer, INVALID_SEQUENCE, mtype)]
        it = items[msg.seq]
        current = int(msg.seq == self.current)
        if as_int:
            return [self.mav.mission_item_int_encode(
                *peer, msg.seq, it.frame, it.command, current, it.autocontinue, *it.params,
                it.x, it.y, it.z, mtype)]
        return [self.mav.mission_item_encode(
            *peer, msg.seq, it.frame, it.command, current, it.autocontinue, *it.params,
            it.x / 1e7, it.y / 1e7, it.z, mtype)]

    def _partial_list(self, msg: Any, peer: tuple[int, int]) -> list[Any]:
        """ArduPilot answers the items start..end one by one; PX4 has no handler (the
        simulation answers UNSUPPORTED rather than leave the client waiting)."""
        items = self.listed()
        end = len(items) - 1 if msg.end_index in (-1, len(items)) else msg.end_index
        if self.flavour == "px4":
            return [self._ack(peer, UNSUPPORTED)]
        if not 0 <= msg.start_index <= end < len(items):
            return [self._ack(peer, ERROR)]
        return [self.mav.mission_item_int_encode(
            *peer, s, it.frame, it.command, int(s == self.current), it.autocontinue,
            *it.params, it.x, it.y, it.z, 0) for s, it in enumerate(items)
            if msg.start_index <= s <= end]

    # -- upload -----------------------------------------------------------------------
    def _start(self, peer: tuple[int, int], first: int, last: int, count: int,
               t: float) -> list[Any]:
        if self._upload is not None and self._upload.peer != peer:
            return [self._ack(peer, DENIED)]  # another client is uploading
        if count > MAX_ITEMS[self.flavour]:
            return [self._ack(peer, NO_SPACE)]
        if count <= 0:  # an empty mission: cleared at once
            self._upload = None
            self._replace([])
            return [self._ack(peer, OK)]
        self._upload = _Upload(peer, first, last, t)
        return [self.mav.mission_request_int_encode(*peer, first, 0)]

    def _partial(self, msg: Any, peer: tuple[int, int], t: float) -> list[Any]:
        """ArduPilot replaces items start..end of the stored mission; PX4 has no handler."""
        end = msg.end_index if msg.end_index >= 0 else msg.start_index
        if self.flavour == "px4":
            return [self._ack(peer, UNSUPPORTED)]
        if not 0 <= msg.start_index <= end < len(self.items) + 1:
            return [self._ack(peer, ERROR)]
        return self._start(peer, msg.start_index, end, end - msg.start_index + 1, t)

    def _receive(self, msg: Any, peer: tuple[int, int], t: float) -> list[Any]:
        up = self._upload
        if up is None or up.peer != peer:
            return [self._ack(peer, ERROR)]  # no upload going on: both firmwares say so
        if msg.seq != up.next:  # a repeat or one too far: ask for the one expected
            return [self.mav.mission_request_int_encode(*peer, up.next, 0)]
        item = Item.of(msg)
        result = item.check()
        if result != OK:
            self._upload = None
            return [self._ack(peer, result)]
        up.items[msg.seq] = item
        up.next += 1
        up.sent_at, up.tries = t, 1
        if up.next <= up.last:
            return [self.mav.mission_request_int_encode(*peer, up.next, 0)]
        self._upload = None
        first = min(up.items)
        if first == 0:
            self._replace([up.items[s] for s in sorted(up.items)])
        else:  # a partial upload: the rest stays, growing the list if it ends past it
            merged = dict(enumerate(self.items)) | up.items
            self._replace([merged[s] for s in sorted(merged)])
        return [self._ack(peer, OK)]

    def tick(self, t: float) -> list[Any]:
        """Requests sent again, or what the firmware says when it gives the upload up
        (the module docstring)."""
        up = self._upload
        if up is None or t - up.sent_at < RETRY:
            return []
        if up.tries >= TRIES:
            self._upload = None
            if self.flavour == "px4":
                return [self.mav.statustext_encode(2, b"Operation timeout")]
            return [self._ack(up.peer, CANCELLED)]
        up.sent_at, up.tries = t, up.tries + 1
        return [self.mav.mission_request_int_encode(*up.peer, up.next, 0)]

    def set_current(self, seq: int) -> bool:
        if not self.first <= seq < len(self.listed()):
            return False
        self.current = seq
        return True


@dataclass
class Where:
    """What a mission item's legs need: the craft's position, its home, the geodetic
    origin of the world frame, the firmware, its parameters, and whether the craft is on
    the ground."""

    here: Vec3
    home: Vec3
    geo: Vec3
    flavour: Flavour
    p: Param
    landed: bool

    def point(self, it: Item) -> Vec3:
        """An item's position in the world frame; lat/lon 0 (or a DO item's frame) is
        where the craft is, altitude 0 in a relative frame where it flies now."""
        x, y, z = self.here
        if it.x or it.y:
            x, y, _ = geodetic_offset(self.geo, (it.x / 1e7, it.y / 1e7, 0.0))
        if it.frame in (FRAME_GLOBAL, 5):
            z = it.z - self.geo[2]
        elif math.isfinite(it.z) and (it.z or it.command == 16):
            z = self.home[2] + it.z
        return (x, y, z)


class MissionRunner:
    """Flies the stored mission from its current item: the legs of the next item that
    moves the craft, the DO items before it taken on the way. `reached` collects the
    items done since last read (MISSION_ITEM_REACHED)."""

    def __init__(self, store: MissionStore) -> None:
        self.store = store
        self.state = NOT_STARTED
        self.speed: float | None = None
        """m/s of the last DO_CHANGE_SPEED (None: the firmware's cruise speed)."""
        self.reached: list[int] = []
        self._jumps: dict[int, int] = {}
        self._version = store.version

    def start(self) -> None:
        """Enter the mission: from the current item, or from the first once flown to
        the end or replaced by an upload (MIS_RESTART 0: ArduPilot resumes)."""
        s = self.store
        if self.state == COMPLETE or self._version != s.version or s.current >= len(
                s.listed()):
            s.current = s.first
            self._jumps.clear()
            self._version = s.version
        self.state, self.speed = ACTIVE, None

    def flyable(self) -> bool:
        return any(it.command in NAV for it in self.store.listed()[self.store.first:])

    def done(self, leg: Leg, report: bool = True) -> None:
        """`leg` ended: its item is reached (`report`: not said yet), the next one is
        current."""
        if leg.seq is not None:
            if report:
                self.reached.append(leg.seq)
            self.store.current = leg.seq + 1
            if self.store.current >= len(self.store.listed()):
                self.state = COMPLETE  # the last item (a landing may disarm at once)

    def legs(self, w: Where) -> list[Leg]:
        """The legs to the next item that flies somewhere ([] at the end)."""
        s = self.store
        items = s.listed()
        for _ in range(10 * len(items) + 1):  # a DO_JUMP loop without a NAV item ends
            if s.current >= len(items):
                break
            seq, it = s.current, items[s.current]
            if it.command in NAV:
                return self._nav(seq, it, w)
            s.current = self._do(seq, it, len(items))
        self.state = COMPLETE
        return []

    def _do(self, seq: int, it: Item, count: int) -> int:
        """A DO item taken: the item next."""
        if it.command == 178 and it.params[1] > 0:  # DO_CHANGE_SPEED param2 m/s
            self.speed = it.params[1]
        if it.command == 177:  # DO_JUMP to param1, param2 times (-1: for ever)
            target = int(it.params[0]) if math.isfinite(it.params[0]) else -1
            left = self._jumps.setdefault(seq, int(it.params[1]) if math.isfinite(
                it.params[1]) else 0)
            if left != 0 and self.store.first <= target < count:
                self._jumps[seq] = left - 1 if left > 0 else left
                return target
        self.reached.append(seq)
        return seq + 1

    def _nav(self, seq: int, it: Item, w: Where) -> list[Leg]:
        speeds = Speeds.auto(w.flavour, w.p, self.speed)
        if w.flavour == "px4":
            across = it.params[1] if it.command == 16 and it.params[1] > 0 else w.p(
                "NAV_ACC_RAD")
            radius = (across, w.p("NAV_MC_ALT_RAD"))
        else:
            radius = (w.p("WPNAV_RADIUS") / 100, APM_ALT_RADIUS)
        x, y, z = w.point(it)
        hold = max(it.params[0], 0.0) if math.isfinite(it.params[0]) else 0.0
        match it.command:
            case 22:  # NAV_TAKEOFF: straight up (PX4: to MIS_TAKEOFF_ALT at least)
                if w.flavour == "px4":
                    z = max(z, w.home[2] + w.p("MIS_TAKEOFF_ALT"))
                hx, hy, hz = w.here
                return [Leg((hx, hy, max(z, hz)), speeds, (math.inf, radius[1]), seq=seq)]
            case 20:
                legs = rtl_legs(w.flavour, w.here, w.home, w.p)
                return [*legs[:-1], Leg(legs[-1].goal, speeds, legs[-1].radius,
                                        legs[-1].hold, seq)]
            case 21:  # NAV_LAND: there at the present height, then down
                return [Leg((x, y, w.here[2]), speeds, (0.5, radius[1])),
                        Leg(None, speeds, seq=seq)]
            case 17:
                hold = math.inf
            case 19 | 16:
                pass
        legs = [Leg((x, y, z), speeds, radius, hold, seq)]
        if w.flavour == "px4" and w.landed:  # PX4 takes off by itself to fly a mission
            climb = max(z, w.home[2] + w.p("MIS_TAKEOFF_ALT"))
            legs.insert(0, Leg((w.here[0], w.here[1], climb), speeds, (math.inf, radius[1])))
        return legs
