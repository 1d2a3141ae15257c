"""Prometheus metrics for people who run Prometheus.

Optional: the daemon builds a `Metrics` only when the robot file asks for an endpoint,
and the endpoint listens on loopback unless the operator explicitly allows otherwise
(DESIGN section 4: nothing the project starts by default is reachable from elsewhere;
scrape it through a node-local Prometheus agent or an SSH tunnel).

The metrics live in a private `CollectorRegistry`, so two daemons in one process (tests,
`sim`) never share counters and the default registry's process metrics are not mixed in.

Exported series (``swarmd_`` prefix):

==========================================  ===============================================
``frames_sent_total``                       frames put on the channel
``frames_received_total``                   frames taken off the channel (before checks)
``frames_dropped_total{reason}``            frames dropped, by reason (core: malformed,
                                            version, auth, replay, ...; runtime: its own)
``duplicate_id_frames_total``               frames with this robot's id it did not send:
                                            another daemon runs with the same id
``events_total{event}``                     event-log records by name (DESIGN section 3):
                                            ``suspect``, ``vote``, ``takeover``, ...
``role{swarmd_role}``                       1 for the current role (ACTIVE, STANDBY, ...)
``function_info{function}``                 the function held ("" when none)
``epoch``                                   epoch of the held function
``votes{function}``                         distinct witnesses counted now (standbys)
``heartbeat_lateness_seconds``              histogram: how late a due heartbeat went out
``robot_info{robot,swarm}``                 who this endpoint is
==========================================  ===============================================
"""

from __future__ import annotations

import ipaddress
import socket
import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Enum,
    Gauge,
    Histogram,
    Info,
    generate_latest,
    start_http_server,
)
from prometheus_client.core import CounterMetricFamily
from prometheus_client.registry import Collector

from swarmd.core.actions import Action
from swarmd.core.events import CORE_EVENTS, NAME_KEY, Event
from swarmd.core.roles import Role

if TYPE_CHECKING:
    from wsgiref.simple_server import WSGIServer

    from prometheus_client.metrics_core import Metric

    from swarmd.core.node import Snapshot

DEFAULT_PORT = 9477
"""Port of the endpoint when the robot file enables it without naming one."""

EVENT_NAMES = tuple(cls.name for cls in CORE_EVENTS)
"""DESIGN section 3's event names, exported at 0 from the start so `rate()` works
before the first occurrence (Prometheus best practice: avoid missing series)."""

LATENESS_BUCKETS = (0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 5.0)
"""Seconds. From a millisecond of loop jitter up to past the radio preset's t_max (2 s),
where a late heartbeat becomes a false suspicion at the neighbours (paper Fig. 7)."""


class MetricsError(ValueError):
    """The endpoint cannot be started as asked."""


class _Drops(Collector):
    """``frames_dropped_total{reason}``: the core's cumulative counts (from its snapshot)
    plus the runtime's own, summed per reason. A custom collector because the core
    already keeps the totals; copying them into a Counter would need deltas."""

    def __init__(self) -> None:
        self.core: dict[str, int] = {}
        self.local: dict[str, int] = {}
        self.lock = threading.Lock()

    def collect(self) -> Iterable[Metric]:
        with self.lock:
            total = dict(self.core)
            for reason, n in self.local.items():
                total[reason] = total.get(reason, 0) + n
        family = CounterMetricFamily(
            "swarmd_frames_dropped", "Frames dropped, by reason.", labels=["reason"]
        )
        for reason in sorted(total):
            family.add_metric([reason], float(total[reason]))
        yield family


class Metrics:
    """The counters and gauges one daemon updates. Thread-safe (prometheus_client's
    metrics are; the drop collector takes a lock), so the HTTP thread can read while
    the event loop writes."""

    def __init__(self, robot_id: int | None = None, swarm_id: int | None = None) -> None:
        self.registry = CollectorRegistry()
        reg = self.registry
        self._sent = Counter("swarmd_frames_sent", "Frames put on the channel.", registry=reg)
        self._received = Counter(
            "swarmd_frames_received", "Frames taken off the channel.", registry=reg
        )
        self._drops = _Drops()
        reg.register(self._drops)
        self._duplicate_id = Counter(
            "swarmd_duplicate_id_frames",
            "Frames with this robot's id that it did not send (a second daemon with the "
            "same id).", registry=reg,
        )
        self._events = Counter(
            "swarmd_events", "Event-log records by event name (DESIGN section 3).",
            [NAME_KEY], registry=reg,
        )
        for name in EVENT_NAMES:
            self._events.labels(name)

        # The role, function, epoch and votes of the node, as it reports them.
        self._role = Enum(
            "swarmd_role", "Current role (paper Fig. 5 with the wait state).",
            states=[r.name for r in Role], registry=reg,
        )
        self._function = Info("swarmd_function", "Function held now.", registry=reg)
        self._function.info({"function": ""})
        self._epoch = Gauge("swarmd_epoch", "Epoch of the function held.", registry=reg)
        self._votes = Gauge(
            "swarmd_votes", "Distinct witnesses counted now, per function (standbys).",
            ["function"], registry=reg,
        )
        self._vote_labels: set[str] = set()

        self._lateness = Histogram(
            "swarmd_heartbeat_lateness_seconds",
            "How late a due heartbeat tick ran (event-loop lag).",
            buckets=LATENESS_BUCKETS, registry=reg,
        )
        if robot_id is not None:
            Info("swarmd_robot", "Robot and swarm ids.", registry=reg).info(
                {"robot": str(robot_id), "swarm": "" if swarm_id is None else str(swarm_id)}
            )

    # -- what the runtime calls --------------------------------------------------------
    def frame_sent(self, n: int = 1) -> None:
        """`n` frames went out on the transport."""
        self._sent.inc(n)

    def frame_received(self, n: int = 1) -> None:
        """`n` frames came in from the transport (counted before any check)."""
        self._received.inc(n)

    def dropped(self, reason: str, n: int = 1) -> None:
        """The runtime dropped `n` frames itself (e.g. a transport-level error)."""
        with self._drops.lock:
            self._drops.local[reason] = self._drops.local.get(reason, 0) + n

    def duplicate_id(self, n: int = 1) -> None:
        """`n` frames carried this robot's id but were not sent by it."""
        self._duplicate_id.inc(n)

    def set_drops(self, drops: Mapping[str, int]) -> None:
        """The core's cumulative drop counts (`Snapshot.drops`), replacing the last."""
        with self._drops.lock:
            self._drops.core = {str(k): int(v) for k, v in drops.items()}

    def observe_event(self, name: str) -> None:
        """Count one event-log record (suspicions, votes, takeovers, ...)."""
        self._events.labels(name).inc()

    def observe_actions(self, actions: Sequence[Action]) -> None:
        """Count the `Event`s among a step's actions (call with every action list)."""
        for action in actions:
            if isinstance(action, Event):
                self.observe_event(action.name)

    def set_role(self, role: str | Role, function: str | None, epoch: int | None = None) -> None:
        """Current role, held function and its epoch."""
        self._role.state(role.name if isinstance(role, Role) else role)
        self._function.info({"function": function or ""})
        if epoch is not None:
            self._epoch.set(epoch)

    def set_votes(self, votes: Mapping[str, int]) -> None:
        """Witnesses counted now per function; functions no longer voted on read 0."""
        for f in self._vote_labels - set(votes):
            self._votes.labels(f).set(0)
        for f, n in votes.items():
            self._votes.labels(f).set(n)
            self._vote_labels.add(f)

    def update(self, snapshot: Snapshot) -> None:
        """Role, function, epoch, votes and drops from a core `Snapshot` in one call."""
        self.set_role(snapshot.role, snapshot.function, snapshot.epoch)
        self.set_votes(snapshot.votes)
        self.set_drops(snapshot.drops)

    def heartbeat_lateness(self, seconds: float) -> None:
        """How late (s) a due tick ran: `now - next_deadline()` when the timer fired.
        Lateness near `t_max` means the neighbours will suspect this robot."""
        self._lateness.observe(max(0.0, seconds))

    # -- exposition --------------------------------------------------------------------
    def render(self) -> bytes:
        """The text exposition format, as the endpoint serves it."""
        return generate_latest(self.registry)

    def start_server(
        self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *, allow_remote: bool = False
    ) -> MetricsServer:
        """Serve ``/metrics`` over HTTP from a daemon thread; port 0 picks a free port.

        Refuses a non-loopback address unless `allow_remote` (the endpoint has no
        authentication; it tells anyone who can reach it the swarm's state)."""
        if not allow_remote:
            check_loopback(host)
        try:
            server, thread = start_http_server(port, addr=host, registry=self.registry)
        except OSError as exc:
            raise MetricsError(f"cannot listen on {host}:{port} for metrics: {exc}") from exc
        return MetricsServer(server, thread, host, server.server_port)


@dataclass
class MetricsServer:
    """A running endpoint; `close()` stops it."""

    server: WSGIServer
    thread: threading.Thread
    host: str
    port: int

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/metrics"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=5)


def check_loopback(host: str) -> None:
    """Raise `MetricsError` unless every address `host` resolves to is loopback."""
    try:
        infos = socket.getaddrinfo(host, None, proto=socket.IPPROTO_TCP)
    except socket.gaierror as exc:
        raise MetricsError(f"metrics host {host!r} does not resolve: {exc}") from exc
    for info in infos:
        addr = ipaddress.ip_address(str(info[4][0]).split("%")[0])
        if not addr.is_loopback:
            raise MetricsError(
                f"metrics host {host!r} is not a loopback address ({addr}); the endpoint "
                "has no authentication, so it listens on 127.0.0.1 unless remote access "
                "is allowed explicitly (metrics.allow_remote: true)"
            )
