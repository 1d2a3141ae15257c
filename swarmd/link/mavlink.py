"""The `mavlink` robot link: the robot is a flight controller (PX4 or ArduPilot).

    link: {kind: mavlink, url: /dev/ttyAMA0, baud: 921600}
    link: {kind: mavlink, url: "udpin:0.0.0.0:14540"}

`url` takes pymavlink's `mavutil` forms, as MAVProxy does: `udpin:HOST:PORT` (listen),
`udpout:HOST:PORT` (send first), `tcp:HOST:PORT`, `tcpin:HOST:PORT`, or a serial device
(with `baud`). Paper Fig. 4 over MAVLink: the robot's health comes from the autopilot's
telemetry (`swarmd.link.mavlink_health`, the table in docs/mavlink.md), and the task
goes out as arm / mode / take-off commands and position setpoints
(`swarmd.link.mavlink_pilot`).

Threading: one I/O thread owns the connection and the `Pilot`; it reads with a short
timeout (`poll`), runs the pilot, writes what it says, and hands health to the event
loop with `call_soon_threadsafe`. The loop never blocks on the autopilot: `assign` and
`release` only put an order on a queue. Health goes to the daemon when it changes and at
least every `health_period` s.

Bursts never starve the daemon (the socket link's rule): health is handed to the loop
at most once every `HANDOVER_GAP` s (a change within it goes with the next one, the
latest value wins), the thread reads at most
`BURST` messages per `poll` window and then waits for the window's end (the loop gets
the interpreter), and health changes and bad data are logged at most once every 10 s
with their count (`CountedLog`).

Unplugged or rebooted: the autopilot's HEARTBEAT falls silent, health turns FAULTY after
`heartbeat_timeout`, and the thread keeps reading (UDP) or reopens the device or socket
every `reopen_interval` s (serial, TCP) until the autopilot is back; the daemon runs on
(DESIGN rule 7), as with a lost XBee.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from swarmd.core.roles import Health
from swarmd.link.base import CountedLog, HealthCallback
from swarmd.link.mavlink_health import Assessment, Thresholds
from swarmd.link.mavlink_pilot import Pilot, PilotConfig

# MAVLink 2 from the first frame (pymavlink reads this when mavutil is imported); a
# MAVLink 1 peer still works, pymavlink answers in the version it hears.
os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

log = logging.getLogger("swarmd.link.mavlink")

MAV_COMP_ID_ONBOARD_COMPUTER = 191
POLL = 0.02
"""s the I/O thread waits for a message before it runs the pilot's clock anyway."""
HEALTH_PERIOD = 0.5
"""s: longest time between two health reports to the daemon."""
HANDOVER_GAP = 0.01
"""s between two health hand-overs to the loop at least: a flapping burst costs the loop
at most 100 callbacks a second; a change waits at most this long (plus one `poll`)."""
BURST = 500
"""Messages the I/O thread reads per `poll` window at most (25,000 a second: an
autopilot streams a few hundred); more wait for the next window, and the counter
`bursts` says how often that happened."""
REOPEN_INTERVAL = 1.0
"""s between two attempts to reopen a connection that failed."""


class MavlinkLinkError(RuntimeError):
    """The link could not start (bad URL)."""


Opener = Callable[[], Any]
"""Returns a connection with pymavlink's `mavfile` interface (`recv_match`, `mav`, `close`)."""


class MavlinkLink:
    """A flight controller behind the robot-link interface (see the module docstring)."""

    def __init__(
        self,
        url: str,
        *,
        baud: int = 57600,
        source_system: int = 1,
        source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
        pilot: PilotConfig | None = None,
        health_period: float = HEALTH_PERIOD,
        poll: float = POLL,
        reopen_interval: float = REOPEN_INTERVAL,
        opener: Opener | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        if not url:
            raise MavlinkLinkError("link url is empty")
        self.url = url
        self.baud = baud
        self.source_system = source_system
        self.source_component = source_component
        self.cfg = pilot or PilotConfig()
        self.health_period = health_period
        self.poll = poll
        self.reopen_interval = reopen_interval
        self._opener = opener or self._open
        self._clock = clock
        self._wall = wall
        self._orders: queue.SimpleQueue[tuple[str, str | None, Mapping[str, Any]]] = (
            queue.SimpleQueue())
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._on_health: HealthCallback | None = None
        self.pilot: Pilot | None = None
        self.last: Assessment | None = None
        self.counters: dict[str, int] = {"opens": 0, "open_errors": 0, "io_errors": 0,
                                         "bad_data": 0, "bursts": 0}
        self._init_reporting()

    def _init_reporting(self) -> None:
        """The health not yet handed to the daemon, and the logs of changes and bad data."""
        self._latest: Health | None = None
        self._handed_at = float("-inf")  # thread time of the last hand-over (`_report`)
        self._dirty = False  # a health not yet handed over
        self._health_log = CountedLog(log, "robot health from the autopilot changed")
        self._bad_log = CountedLog(log, "bad MAVLink data from the autopilot")

    # -- RobotLink -----------------------------------------------------------------------
    async def start(self, on_health: HealthCallback) -> None:
        self._loop = asyncio.get_running_loop()
        self._on_health = on_health
        self._stop.clear()
        now = self._clock()
        encoder = mavutil.mavlink.MAVLink(None, srcSystem=self.source_system,
                                          srcComponent=self.source_component)
        self.pilot = Pilot(encoder, self.cfg, now=now, wall0=self._wall() - now)
        self._thread = threading.Thread(target=self._run, name="mavlink", daemon=True)
        self._thread.start()

    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        self._orders.put(("assign", function, dict(params)))

    def release(self, function: str) -> None:
        self._orders.put(("release", function, {}))

    async def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join, 5.0)
            self._thread = None
        self._on_health = None

    # -- the I/O thread ------------------------------------------------------------------
    def _open(self) -> Any:
        return mavutil.mavlink_connection(
            self.url, baud=self.baud, source_system=self.source_system,
            source_component=self.source_component, autoreconnect=True)

    def _run(self) -> None:
        conn: Any = None
        next_open = self._clock()
        last_report = float("-inf")
        window, read = self._clock(), 0
        while not self._stop.is_set():
            now = self._clock()
            self._health_log.tick(now)
            self._bad_log.tick(now)
            self._hand_over(now)  # a change held back by the gap
            if now - window >= self.poll:
                window, read = now, 0
            elif read >= BURST:  # the rest of a burst waits: the loop gets its turn
                self.counters["bursts"] += 1
                self._stop.wait(self.poll - (now - window))
                continue
            if conn is None:
                if now < next_open:
                    self._stop.wait(min(self.poll, next_open - now))
                    now = self._clock()
                    self._tick(None, now)
                    last_report = self._report(now, last_report)
                    continue
                try:
                    conn = self._opener()
                    self.counters["opens"] += 1
                except Exception as exc:
                    self.counters["open_errors"] += 1
                    next_open = now + self.reopen_interval
                    log.warning("cannot open MAVLink %s: %s (retrying)", self.url, exc)
                    continue
            conn, got = self._exchange(conn)
            read += got
            if conn is None:
                next_open = self._clock() + self.reopen_interval
            last_report = self._report(self._clock(), last_report)
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close()

    def _exchange(self, conn: Any) -> tuple[Any, bool]:
        """Read a message (or time out), tick the pilot and send what it answers: the
        connection (None once it failed and was closed) and whether a message came."""
        got = False
        try:
            msg = conn.recv_match(blocking=True, timeout=self.poll)
            got = msg is not None
            now = self._clock()
            out = self._tick(msg, now)
            for m in out:
                conn.mav.send(m)
        except Exception as exc:  # unplugged serial, reset TCP, a pymavlink bug
            self.counters["io_errors"] += 1
            log.warning("MAVLink %s failed: %s (reopening)", self.url, exc)
            with contextlib.suppress(Exception):
                conn.close()
            return None, got
        return conn, got

    def _tick(self, msg: Any, now: float) -> list[Any]:
        pilot = self.pilot
        if pilot is None:
            return []
        while True:
            try:
                order, function, params = self._orders.get_nowait()
            except queue.Empty:
                break
            if order == "assign" and function is not None:
                pilot.assign(function, params, now)
            else:
                pilot.release(function, now)
        if msg is not None:
            if msg.get_type() == "BAD_DATA":
                self.counters["bad_data"] += 1
                self._bad_log.hit("not a MAVLink message", now)
            else:
                pilot.on_message(msg, now)
        return pilot.tick(now)

    def _report(self, now: float, last: float) -> float:
        pilot = self.pilot
        if pilot is None:
            return last
        a = pilot.health(now)
        if a.health is Health.OK and pilot.view.last_heartbeat is None:
            return last  # nothing heard yet and not yet timed out: nothing to say
        changed = self.last is None or a.health != self.last.health
        if not changed and now - last < self.health_period:
            return last
        if changed:
            self._health_log.hit(f"{a.health.name.lower()}: {'; '.join(a.reasons)}"
                                 if a.health is not Health.OK else "ok", now)
        self.last = a
        self._latest, self._dirty = a.health, True
        self._hand_over(now)
        return now

    def _hand_over(self, now: float) -> None:
        """Hand the latest health to the loop, at most once every `HANDOVER_GAP` s."""
        loop = self._loop
        if not self._dirty or now - self._handed_at < HANDOVER_GAP \
                or loop is None or self._on_health is None:
            return
        self._dirty, self._handed_at = False, now
        with contextlib.suppress(RuntimeError):  # the loop closed under us
            loop.call_soon_threadsafe(self._deliver, self._latest)

    def _deliver(self, health: Health | None) -> None:
        if self._on_health is not None and health is not None:
            self._on_health(health)


_HEALTH = {"ok": Health.OK, "degraded": Health.DEGRADED, "faulty": Health.FAULTY}


def pilot_config(cfg: Any) -> PilotConfig:
    """The pilot's settings from a robot file's `link: {kind: mavlink, ...}` model
    (`swarmd.config.robot.MavlinkLinkConfig`)."""
    h = cfg.health
    defaults = Thresholds()
    sensors = dict(defaults.sensors)
    sensors.update({name: _HEALTH[v] for name, v in h.sensors.items()})
    thresholds = Thresholds(
        heartbeat_timeout=h.heartbeat_timeout, battery_degraded=h.battery_degraded,
        battery_faulty=h.battery_faulty, estimator_degraded=h.estimator_degraded,
        estimator_faulty=h.estimator_faulty, critical=_HEALTH[h.critical],
        not_ready=_HEALTH[h.not_ready], failsafe_mode=_HEALTH[h.failsafe_mode],
        command_refused=_HEALTH[h.command_refused], refused_hold=h.refused_hold,
        sensors=sensors)
    geo = tuple(cfg.geo_origin) if cfg.geo_origin is not None else None
    return PilotConfig(
        flavour=None if cfg.autopilot == "auto" else cfg.autopilot,
        target_system=cfg.target_system, target_component=cfg.target_component,
        takeoff_altitude=cfg.takeoff_altitude, setpoint_rate=cfg.setpoint_rate,
        release=cfg.release, command_timeout=cfg.command_timeout,
        command_retries=cfg.command_retries,
        origin=(float(cfg.origin[0]), float(cfg.origin[1]), float(cfg.origin[2])),
        geo_origin=(float(geo[0]), float(geo[1]), float(geo[2])) if geo else None,
        health=thresholds)
