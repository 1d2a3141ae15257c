"""The asyncio runtime: the one owner of a core `Node` (DESIGN section 2, sans-IO driver).

Theory of operation. Everything that reaches the node goes through one step path, as in
aioquic's asyncio layer:

    input (frame / timer / robot health / stop)
      -> node.<entry>(..., now)            returns actions
      -> execute them in order             Broadcast -> transport, Assign/Release -> link,
                                           Event -> event sink
      -> re-arm ONE TimerHandle at node.next_deadline()

Time is `loop.time()` (monotonic), the same clock the node was built with. The node
schedules its heartbeats from the previous deadline, not from "now + period", so they
keep their period under load; the runtime's only job is to call `tick()` on time.

Receive path. A flood of frames must not delay our own heartbeats (a late heartbeat is a
false suspicion at the neighbours). A frame that arrives with nothing queued before it,
no timer due and fewer than `batch` frames fed this way since the last tick goes straight
to the node from the transport's callback: the common case of an idle robot (a few frames
a period), which so costs one turn of the event loop per frame, not two. Any other frame
(under a flood, all but those few) is appended to a bounded deque (drop-oldest, counted
as `queue_overflow`: under a flood the newest frames are the ones worth reading) and a
drain is scheduled. The drain feeds the node at most `batch` frames, then yields to the
loop with `call_soon`, so a due timer runs after at most one batch (~1 ms) however long
the queue is. Frames reach the node in the order they arrived either way.

Nothing raised by the transport, the link, the event sink or even the node propagates:
it is logged, counted in `counters`, and the daemon goes on (common rule: bad input never
takes the daemon down). A node exception is a bug; the timer is re-armed regardless so
heartbeats continue.

Duplicate robot id. The core drops every frame carrying our own id as `own`: on UDP
multicast those are our loopback echoes, where the transport cannot drop them in the
kernel first (swarmd/transport/udp.py). But a second daemon started with this robot's
id (a copied robot file) is dropped the same way, silently, and two robots may then
execute one function (DESIGN rule 2). The runtime remembers the digests of the last
`SENT_MEMORY` frames it sent; an `own` frame that is not one of them is an impostor's:
counted as `duplicate_id` (and in the metrics) and logged as an ERROR at most every
`DUPLICATE_REPORT_S`, in both daemons (each hears the other).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from enum import StrEnum
from typing import TYPE_CHECKING, Any

from swarmd.base.eventloop import timer_slack
from swarmd.base.notify import Notifier
from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Broadcast, Release
from swarmd.core.drops import DropReason
from swarmd.core.events import Event, RoleName, Started
from swarmd.core.node import Node, Snapshot
from swarmd.core.roles import Health, Role
from swarmd.link.base import RobotLink
from swarmd.transport.base import (
    ChannelError,
    ChannelEvent,
    ChannelUp,
    SendError,
    Transport,
    describe,
)

if TYPE_CHECKING:
    from swarmd.services.metrics import Metrics

# The name an operator filters the JSON logs on ("logger", docs/daemon.md): it names the
# component, not the file, so it stays when the module moves between folders.
log = logging.getLogger("swarmd.runtime")

ReceiveFilter = Callable[[bytes, float], bool]
"""(frame, loop time) -> False to drop the frame (the simulator's loss and partitions)."""
EventSink = Callable[[float, Event], None]
"""Receives each event the node emits, as the typed object it is, with its time `t`
(s since the time origin): the sink turns it into a record where it writes one out."""
StateWriter = Callable[[Snapshot], int]
"""Persists a snapshot (see swarmd/services/state.py); called on role / function / epoch change
and when the sequence number nears the reservation; returns the sequence number at which
the next write is due however nothing else changed."""

QUEUE_SIZE = 1024
BATCH = 64


class RuntimeDrop(StrEnum):
    """A frame the runtime threw away before the core saw it (the core's own refusals
    are `DropReason`s); reported and exported with them."""

    QUEUE_OVERFLOW = "queue_overflow"
    """The receive queue was full: its oldest frame made room (module docstring)."""


DROP_REPORT_S = 10.0
"""s. Frames dropped since the last report are logged at most this often: an operator
without a metrics endpoint still sees a robot with the wrong key (`auth`), another swarm
on the group (`swarm`) or garbage on the channel, without a line per frame."""
QUIET_DROPS = frozenset({DropReason.OWN, DropReason.IRRELEVANT})
"""Drop reasons never logged (metrics still count them): `own` is this robot's multicast
echo, every frame; `irrelevant` is the traffic of the rest of a large swarm (DESIGN
section 2, "What a robot hears")."""
SENT_MEMORY = 512
"""Frames whose digests are kept to recognise our own echoes: many seconds of our own
traffic, far more than can be in flight or queued (QUEUE_SIZE frames of all robots)."""
DUPLICATE_REPORT_S = 10.0
"""s. The duplicate-id ERROR is logged at most this often (counted every frame)."""
_RATE_LIMIT_S = 1.0  # per name, for channel condition reports (send errors can be per frame)


_COUNTERS: tuple[str, ...] = (
    "received", "filtered", RuntimeDrop.QUEUE_OVERFLOW, "sent", "ticks",
    "node_errors", "transport_errors", "link_errors", "sink_errors",
    "filter_errors", "persist_errors", "state_writes", "duplicate_id",
)
"""The runtime's counters (`Runtime.stats`), in the order they are reported."""


class Runtime:
    """Drives one `Node` with one transport and one robot link. See the module docstring."""

    def __init__(
        self,
        node: Node,
        transport: Transport,
        link: RobotLink,
        *,
        function_params: Callable[[str], Mapping[str, Any]] | None = None,
        event_sink: EventSink | None = None,
        receive_filter: ReceiveFilter | None = None,
        state_writer: StateWriter | None = None,
        persist_after: float = 0.0,
        seq_write_at: int = 0,
        metrics: Metrics | None = None,
        notifier: Notifier | None = None,
        time_origin: float = 0.0,
        wall_clock: Callable[[], float] = time.time,
        queue_size: int = QUEUE_SIZE,
        batch: int = BATCH,
    ) -> None:
        self._node = node
        self._drops = node.drops
        """The node's drop counts, a live view, taken once: `_feed` reads it every frame."""
        self._robot_id = node.robot_id
        self._transport = transport
        self._link = link
        self._function_params = function_params
        self._event_sink = event_sink
        self._receive_filter = receive_filter
        self._init_persistence(state_writer, persist_after, seq_write_at)
        self._metrics = metrics
        self._notifier = notifier
        self._time_origin = time_origin
        self._wall_clock = wall_clock
        self._batch = batch
        self._counters: dict[str, int] = dict.fromkeys(_COUNTERS, 0)
        self._raw_send_failed = False
        self._max_lateness = 0.0
        """s. Largest delay seen between a deadline and the tick that served it."""
        self._first_broadcast = asyncio.Event()
        """Set once the first frame (the first heartbeat) went out: READY (notify.py)."""
        self._init_scheduling(queue_size)
        self._init_reports()

    def _init_scheduling(self, queue_size: int) -> None:
        """The loop the runtime runs on, its receive queue and its timers."""
        self._queue: deque[bytes] = deque()
        self._queue_size = queue_size
        self._drain_scheduled = False
        self._fed = 0
        """Frames fed to the node from the transport's callback since the last tick
        (module docstring, "Receive path")."""
        self._timer: asyncio.TimerHandle | None = None
        self._armed_at: float | None = None
        self._watchdog: asyncio.TimerHandle | None = None
        self._running = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._slack = 0.0
        """How much after the node's deadline the timer is armed (`timer_slack`)."""

    def _init_persistence(self, state_writer: StateWriter | None, persist_after: float,
                          seq_write_at: int) -> None:
        """When and what state the runtime writes (swarmd/services/state.py)."""
        self._state_writer = state_writer
        self._persist_after = persist_after
        """loop time before which node-driven state is not written: a restarted holder
        keeps its persisted `held` until its rejoin hold is over, so a crash during the
        hold does not forget it."""
        self._last_persisted: tuple[Any, ...] | None = None
        self._seq_write_at = seq_write_at
        """Reaching this sequence number forces a state write (the reservation in the
        state file must stay ahead of every seq sent; swarmd/services/state.py): at
        first, where the state file written before the start reserved up to."""

    def _init_reports(self) -> None:
        """What was last logged or notified, so a report is made once per change."""
        self._last_role: tuple[Role, str | None, int] | None = None
        self._last_health: Health | None = None
        self._reported: dict[str, float] = {}
        self._drops_reported: dict[str, int] = {}
        self._drop_reported_at = -DROP_REPORT_S
        # hash(frame) of the last SENT_MEMORY frames sent, oldest first (an ordered set).
        self._sent_digests: dict[int, None] = {}
        self._duplicate_logged_at = -DUPLICATE_REPORT_S

    # ---------------------------------------------------------------- lifecycle
    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
        return self._loop

    async def start(self) -> None:
        """Open the transport and the link, then fire the node's first tick at once
        (its deadline right after construction is `now`). Raises what the transport or
        link raise on set-up (bad device, socket path taken): the daemon reports it."""
        self._loop = asyncio.get_running_loop()
        self._slack = timer_slack(self._loop)
        self._running = True
        try:
            await self._transport.start(self._on_frame, self._on_transport_event)
            await self._link.start(self._on_health)
        except BaseException:
            # Never started: `stop` must not run the node's stop (a LEAVE into a
            # transport that never opened, a misleading send error).
            self._running = False
            raise
        self._rearm()
        period = self._notifier.watchdog_period() if self._notifier is not None else None
        if period is not None:
            self._watchdog_at(self.loop.time() + period, period)

    async def stop(self, *, handover: bool) -> None:
        """Graceful stop: the node's LEAVE (if it held a function and `handover`) and
        Release go out, state is written, timers stop. The caller closes transport and
        link afterwards, so the LEAVE is on the wire before the socket closes."""
        if not self._running:
            return
        self._step(lambda now: self._node.stop(now, handover=handover))
        self._report_drops()  # what was refused since the last report is not lost
        self._running = False
        self._queue.clear()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        self._check_state(force=True)

    async def first_broadcast(self) -> None:
        """Return once the first frame (the first heartbeat) went out: READY
        (notify.py)."""
        await self._first_broadcast.wait()

    def heard(self) -> Mapping[int, float]:
        """robot -> loop time of the last frame the node accepted from it."""
        return self._node.snapshot().heard

    def snapshot(self) -> Snapshot:
        """The node's state now (what the state file persists)."""
        return self._node.snapshot()

    def keys(self) -> tuple[bytes, ...]:
        """The swarm keys the node uses now (`keys[0]` signs)."""
        return tuple(self._node.keys)

    def next_deadline(self) -> float | None:
        """Loop time of the node's next timer (None: it waits for nothing)."""
        return self._node.next_deadline()

    def drop_counts(self) -> dict[str, int]:
        """Frames refused so far, by reason: the core's and the runtime's own."""
        return {**self._node.drops,
                RuntimeDrop.QUEUE_OVERFLOW: self._counters[RuntimeDrop.QUEUE_OVERFLOW]}

    def send_raw(self, frame: bytes) -> bool:
        """Put bytes on the channel past the core (fault injection: a forger's frames,
        which are not this robot's own, so not remembered as its echoes). False when the
        transport refused them: counted in `transport_errors`, logged the first time."""
        try:
            self._transport.send(frame)
        except Exception as exc:
            self._counters["transport_errors"] += 1
            if not self._raw_send_failed:
                self._raw_send_failed = True
                log.warning("raw send refused by the transport; counted from now on",
                            extra={"error": f"{type(exc).__name__}: {exc}"})
            return False
        return True

    async def close_io(self, timeout: float = 10.0) -> None:
        """Close the link and the transport (after `stop`), each within `timeout` s; a
        close that fails is logged and the other still closed."""
        for what, closer in (("link", self._link.close), ("transport", self._transport.close)):
            try:
                await asyncio.wait_for(closer(), timeout)
            except Exception:
                log.exception("closing the %s failed", what)

    def inject(self, msg: wire.Message) -> None:
        """Broadcast an arbitrary message as this robot (fault injection: `liar:R@T`)."""
        self._step(lambda now: self._node.send_message(msg, now))

    def set_keys(self, keys: Sequence[bytes]) -> None:
        """New swarm keys (SIGHUP): `keys[0]` signs from the next frame on, any of them
        verifies; frames already queued are checked against the new list. Raises
        `NodeError` and keeps the old keys if the node refuses them (`Node.set_keys`)."""
        self._node.set_keys(keys)

    def revoke(self, robots: Iterable[int]) -> None:
        """Robots whose keys were revoked (SIGHUP, per-robot mode): the node forgets
        their heartbeat chains, so they fall silent to it now (`Node.revoke`)."""
        self._node.revoke(robots)

    # ---------------------------------------------------------------- the step path
    def _step(self, call: Callable[[float], list[Action]]) -> None:
        now = self.loop.time()
        try:
            actions = call(now)
        except Exception:
            self._counters["node_errors"] += 1
            log.exception("core node raised (a bug); the daemon continues")
            actions = []
        self._execute(actions)
        self._rearm()

    def _execute(self, actions: list[Action]) -> None:
        changed = False
        for action in actions:
            match action:
                case Broadcast(frame):
                    self._send(frame)
                case Assign(function, epoch):
                    changed = True
                    self._assign(function, epoch)
                case Release(function):
                    changed = True
                    try:
                        self._link.release(function)
                    except Exception:
                        self._counters["link_errors"] += 1
                        log.exception("robot link release failed",
                                      extra={"function": function})
                case Event() as event:
                    changed = True
                    self._event(event)
                    if isinstance(event, Started) and event.role is not RoleName.ACTIVE:
                        self._release_at_start()
        if self._metrics is not None and actions:
            self._metrics.observe_actions(actions)
        if changed:
            self._check_state()

    def _send(self, frame: bytes) -> None:
        try:
            self._transport.send(frame)
        except Exception:
            self._counters["transport_errors"] += 1
            log.exception("transport send raised")
            return
        self._counters["sent"] += 1
        digests = self._sent_digests
        digests[hash(frame)] = None
        if len(digests) > SENT_MEMORY:
            del digests[next(iter(digests))]
        if self._metrics is not None:
            self._metrics.frame_sent()
        if not self._first_broadcast.is_set():
            self._first_broadcast.set()

    def _release_at_start(self) -> None:
        """The node's `started` as a standby (at the start, or after a rejoin hold that
        found the slot taken, DESIGN rule 2): the robot may still execute what it did
        before this daemon died, so the link is told to release it before anything
        else, with no function name (the robot holds nothing now). A holder needs
        nothing here: its Assign follows its `started`."""
        try:
            self._link.release("")
        except Exception:
            self._counters["link_errors"] += 1
            log.exception("robot link release failed", extra={"function": ""})

    def _assign(self, function: str, epoch: int) -> None:
        params: Mapping[str, Any] = {}
        if self._function_params is not None:
            try:
                params = self._function_params(function)
            except Exception:
                log.exception("no parameters for function", extra={"function": function})
        try:
            self._link.assign(function, epoch, params)
        except Exception:
            self._counters["link_errors"] += 1
            log.exception("robot link assign failed", extra={"function": function})

    def _event(self, event: Event) -> None:
        if self._event_sink is None:
            return
        try:
            self._event_sink(round(self._wall_clock() - self._time_origin, 6), event)
        except Exception:
            self._counters["sink_errors"] += 1
            log.exception("event sink failed")

    # ---------------------------------------------------------------- the single timer
    def _rearm(self) -> None:
        if not self._running:
            return
        try:
            deadline = self._node.next_deadline()
        except Exception:
            self._counters["node_errors"] += 1
            log.exception("next_deadline raised (a bug); retrying in 100 ms")
            deadline = self.loop.time() + 0.1
        if deadline == self._armed_at and self._timer is not None:
            return  # already armed there; spare the heap a cancel and a push
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._armed_at = deadline
        if deadline is not None:
            self._timer = self.loop.call_at(deadline + self._slack, self._on_timer)

    def _on_timer(self) -> None:
        self._timer = None
        due = self._armed_at
        self._armed_at = None
        now = self.loop.time()
        if due is not None and self._counters["ticks"] > 0:
            # (The first tick is due at construction time; start-up is not lateness.)
            lateness = max(0.0, now - due)
            self._max_lateness = max(self._max_lateness, lateness)
            if self._metrics is not None:
                self._metrics.heartbeat_lateness(lateness)
        self._counters["ticks"] += 1
        self._fed = 0
        if now - self._drop_reported_at >= DROP_REPORT_S:
            self._drop_reported_at = now
            self._report_drops()
        self._step(self._node.tick)
        # Receive-only steps do not look at the snapshot (a flood would make that
        # costly); a tick does, so an epoch learnt from a heartbeat is persisted within
        # one deadline.
        self._check_state()

    def _report_drops(self) -> None:
        """Log the frames dropped since the last report, by reason (rate-limited by the
        caller). Drops are counted per frame by the core; a log line per frame would let
        a flood fill the journal."""
        current = self.drop_counts()
        new = {reason: n - self._drops_reported.get(reason, 0)
               for reason, n in sorted(current.items())
               if reason not in QUIET_DROPS and n > self._drops_reported.get(reason, 0)}
        self._drops_reported = current
        if new:
            log.warning("dropped frames", extra={"drops": new, "total": sum(new.values())})

    def _watchdog_at(self, when: float, period: float) -> None:
        def ping() -> None:
            if self._notifier is not None:
                self._notifier.watchdog()
            # Scheduled from the previous deadline, so the ping period does not drift.
            self._watchdog_at(when + period, period)

        self._watchdog = self.loop.call_at(when, ping)

    # ---------------------------------------------------------------- receive path
    def _on_frame(self, data: bytes) -> None:
        if not self._running:
            return
        self._counters["received"] += 1
        if self._metrics is not None:
            self._metrics.frame_received()
        now = self.loop.time()
        if self._receive_filter is not None and not self._keep(data, now):
            return
        armed = self._armed_at
        if self._queue or self._drain_scheduled or self._fed >= self._batch \
                or (armed is not None and now >= armed):
            self._enqueue(data)
            return
        self._fed += 1
        self._feed(data, now)
        self._rearm()

    def _keep(self, data: bytes, now: float) -> bool:
        """The receive filter's verdict (a filter that raises keeps the frame)."""
        assert self._receive_filter is not None
        try:
            keep = self._receive_filter(data, now)
        except Exception:
            self._counters["filter_errors"] += 1
            log.exception("receive filter raised; frame kept")
            keep = True
        if not keep:
            self._counters["filtered"] += 1
        return keep

    def _enqueue(self, data: bytes) -> None:
        """Queue a frame for `_drain` (module docstring, "Receive path")."""
        if len(self._queue) >= self._queue_size:
            self._queue.popleft()
            self._counters[RuntimeDrop.QUEUE_OVERFLOW] += 1
            if self._metrics is not None:
                self._metrics.dropped(RuntimeDrop.QUEUE_OVERFLOW)
        self._queue.append(data)
        if not self._drain_scheduled:
            self._drain_scheduled = True
            self.loop.call_soon(self._drain)

    def _drain(self) -> None:
        self._drain_scheduled = False
        if not self._running:
            return
        queue, loop = self._queue, self.loop
        for _ in range(min(self._batch, len(queue))):
            self._feed(queue.popleft(), loop.time())
        self._rearm()
        if queue and not self._drain_scheduled:
            # Yield: timers due meanwhile (our heartbeat) run before the next batch.
            self._drain_scheduled = True
            loop.call_soon(self._drain)

    def _feed(self, data: bytes, now: float) -> None:
        """One frame to the node, its actions executed (the caller re-arms the timer)."""
        # `get`, not `[]`: the drops are a Counter, whose `[]` of a reason never counted
        # calls its Python `__missing__`, and `own` stays 0 where the transport drops our
        # echoes in the kernel (udp.py): twice a frame for nothing.
        drops = self._drops
        own = drops.get(DropReason.OWN, 0)
        try:
            actions = self._node.receive(data, now)
        except Exception:
            self._counters["node_errors"] += 1
            log.exception("core node raised on a frame (a bug); frame dropped")
            return
        if drops.get(DropReason.OWN, 0) != own and hash(bytes(data)) not in self._sent_digests:
            self._duplicate_id()
        if actions:
            self._execute(actions)

    def _duplicate_id(self) -> None:
        """A valid frame with our id that we did not send (module docstring)."""
        self._counters["duplicate_id"] += 1
        if self._metrics is not None:
            self._metrics.duplicate_id()
        now = self.loop.time()
        if now - self._duplicate_logged_at >= DUPLICATE_REPORT_S:
            self._duplicate_logged_at = now
            log.error(f"another daemon is sending as robot {self._robot_id}: two robot "
                      "files with the same id?",
                      extra={"robot": self._robot_id, "frames": self._counters["duplicate_id"]})

    # ---------------------------------------------------------------- robot health
    def _on_health(self, health: Health) -> None:
        if not self._running or health == self._last_health:
            return  # the socket link repeats health every line; only changes matter
        if self._last_health is not None:
            log.info("robot health changed", extra={"health": health.name.lower()})
        self._last_health = health
        self._step(lambda now: self._node.robot_health(health, now))
        self._check_state()

    # ---------------------------------------------------------------- channel events
    def _on_transport_event(self, event: ChannelEvent) -> None:
        """A channel condition (radio up or down, a send error): counted and logged to
        the daemon's own log, not the event log, whose names are a contract (DESIGN
        section 3, `swarmd.core.events`). The protocol itself notices a dead channel through
        missing heartbeats, as the paper's robots would."""
        now = self.loop.time()
        name = event.condition
        if isinstance(event, SendError | ChannelError):
            self._counters["transport_errors"] += 1
            last = self._reported.get(name)
            if last is not None and now - last < _RATE_LIMIT_S:
                return  # counted; reported at most once a second
            self._reported[name] = now
        level = logging.INFO if isinstance(event, ChannelUp) else logging.WARNING
        log.log(level, "channel: %s", name, extra={"channel": name, "fields": describe(event)})

    # ---------------------------------------------------------------- persistence
    def _check_state(self, *, force: bool = False) -> None:
        if not force and self._metrics is None and self._settled():
            return
        try:
            snap = self._node.snapshot()
        except Exception:
            self._counters["node_errors"] += 1
            log.exception("snapshot raised (a bug)")
            return
        role_key = (snap.role, snap.function, snap.epoch)
        if role_key != self._last_role:
            self._last_role = role_key
            status = f"{snap.role.name.lower()} {snap.function or '-'} epoch {snap.epoch}"
            log.info("role", extra={"role": snap.role.name.lower(),
                                    "function": snap.function, "epoch": snap.epoch})
            if self._notifier is not None:
                self._notifier.status(status)
        if self._metrics is not None:
            self._metrics.update(snap)
        if self._state_writer is None:
            return
        if not force and self.loop.time() < self._persist_after:
            return
        key = (snap.role, snap.function, snap.epoch, tuple(sorted(snap.known.items())))
        if not force and key == self._last_persisted and snap.seq < self._seq_write_at:
            return
        try:
            self._seq_write_at = self._state_writer(snap)
        except OSError as exc:  # disk full, directory gone or read-only: say which
            self._counters["persist_errors"] += 1
            log.error("cannot write the state file; will retry on the next change",
                      extra={"error": str(exc)})
            return
        except Exception:
            self._counters["persist_errors"] += 1
            log.exception("cannot write the state file (a bug); will retry on the next "
                          "change")
            return
        self._counters["state_writes"] += 1
        self._last_persisted = key

    def _settled(self) -> bool:
        """Nothing for `_check_state` to report or write, told by the node's `standing`
        rather than a full snapshot, on the same tests: the role is the one reported
        last, and the state file is not due (every tick asks; almost always so)."""
        try:
            st = self._node.standing()
        except Exception:
            return False  # `_check_state` takes the snapshot and reports the bug
        if (st.role, st.function, st.epoch) != self._last_role:
            return False
        if self._state_writer is None or self.loop.time() < self._persist_after:
            return True
        return (st.role, st.function, st.epoch, st.known) == self._last_persisted \
            and st.seq < self._seq_write_at

    # ---------------------------------------------------------------- introspection
    def stats(self) -> dict[str, Any]:
        """Counters, the core's drops and the largest tick lateness (s)."""
        return {**self._counters, "queue": len(self._queue),
                "max_lateness": self._max_lateness, "drops": dict(self._node.drops)}
