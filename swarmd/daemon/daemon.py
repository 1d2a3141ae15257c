"""One robot's daemon: config in, a running `Runtime` until told to stop.

`run_daemon` is what `swarmd start` runs and what the multi-process simulator runs in
each robot process (injecting its own link, a receive filter for loss and partitions,
an event sink and a time origin). It:

1. loads the swarm plan, timing and keys; reads the state file (a corrupt one is set
   aside with a clear error and the robot starts fresh);
2. builds the core `Node` with a sequence seed above anything sent before
   (`seq_seed(time.time())` or the persisted reservation) and `Restored(...)` when a
   state file exists, so a restarted holder listens before resuming (DESIGN rule 2);
3. starts transport and link, waits for the first heartbeat, then tells systemd READY;
4. runs until `stop_event` is set (SIGTERM / SIGINT with `handle_signals`), then stops
   the node (LEAVE when it held a function and `handover_on_stop`), writes the state,
   closes everything and returns 0.

SIGHUP (with `handle_signals` and `config_path`) re-reads the robot and swarm files and
applies what can change without a restart; see `Daemon.reload` and docs/daemon.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import logging
import signal
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from swarmd.base import eventloop, signals
from swarmd.base.eventlog import EventLog
from swarmd.base.identity import Ed25519Signer, Keyring
from swarmd.base.notify import Notifier
from swarmd.base.verify_budget import VerifyBudget
from swarmd.config import ConfigError, RobotConfig, load_robot
from swarmd.core.auth import Identity
from swarmd.core.events import NAME_KEY, Alert, Event, Leave, LeaveCause
from swarmd.core.node import Node
from swarmd.core.plan import Unheard
from swarmd.core.roles import Role
from swarmd.core.wire import seq_seed
from swarmd.daemon.waiting import Waiting, describe_channel, report_waiting
from swarmd.link.base import RobotLink
from swarmd.link.exec import run_command
from swarmd.link.factory import make_link
from swarmd.services import state as state_mod
from swarmd.services.revocation import EXIT_REVOKED, revoked_in
from swarmd.services.runtime import ReceiveFilter, Runtime
from swarmd.transport.base import Transport, TransportError
from swarmd.transport.udp import UdpTransport

if TYPE_CHECKING:
    from swarmd.services.metrics import Metrics, MetricsServer

log = logging.getLogger("swarmd.daemon")

EXIT_OK = 0
EXIT_FAILURE = 1
"""Start-up failed (transport, link, state directory, keys): systemd may retry."""
EXIT_CONFIG = 2
"""The config cannot be used: retrying will not help."""

READY_TIMEOUT = 3.0
"""s. READY is sent after the first heartbeat; a robot that reports itself faulty at
start never heartbeats, so READY goes out anyway after this long (it is running)."""
ALERT_HOOK_TIMEOUT = 30.0
"""s. An alert hook still running after this is killed (a page or a mail takes
seconds; a hung one must not pile up, one per alert)."""

RecordSink = Callable[[dict[str, Any]], None]
"""Receives each event-log record as written (`Event.record(t, robot)`, DESIGN
section 3): the simulator's and the tests' copy of the event log."""


def make_transport(cfg: Any, *, unheard: Unheard | None = None) -> Transport:
    """The transport the robot file asks for. Radios live in their own modules, loaded
    only when configured (digi-xbee and pyserial are heavy imports). `unheard`: the
    heartbeats the robot's core drops unread, which the udp transport can drop in the
    kernel instead (swarmd/transport/udp.py)."""
    kind = getattr(cfg, "kind", "udp")
    if kind == "udp":
        return UdpTransport.from_config(cfg, unheard=unheard)
    modules = {"serial": ("swarmd.transport.serial", "SerialTransport"),
               "xbee": ("swarmd.transport.xbee", "XBeeTransport")}
    if kind not in modules:
        raise TransportError(f"unknown transport kind {kind!r} (udp, serial, xbee)")
    module_name, class_name = modules[kind]
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise TransportError(f"transport {kind!r} is not available: {exc}") from exc
    transport: Transport = cls.from_config(cfg)
    return transport


class StartupError(RuntimeError):
    """A set-up step failed (state directory, ...); the message names the config field
    and the path, as the config's own errors do."""


def _ensure_dir(field: str, path: Path) -> None:
    """Create the directory `field` names, or say clearly why it cannot be used (a file
    in the way, no permission, a read-only file system)."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise StartupError(f"{field} {path}: exists and is not a directory") from None
    except OSError as exc:
        raise StartupError(f"{field} {path}: cannot create the directory: "
                           f"{exc.strerror or exc}") from exc


def _restart_needed(old: RobotConfig, new: RobotConfig) -> list[str]:
    """The settings a SIGHUP changed that only a restart applies."""
    return [name for name, a, b in (
        ("robot", old.robot, new.robot),
        ("transport", old.transport, new.transport),
        ("link", old.link, new.link),
        ("timing", old.swarm.params(), new.swarm.params()),
        ("plan", old.swarm.to_plan(), new.swarm.to_plan()),
        ("state_dir", old.state_dir, new.state_dir),
        ("metrics", old.metrics, new.metrics),
        ("auth", old.swarm.auth_mode, new.swarm.auth_mode),
    ) if a != b]


class Daemon:
    """The pieces of one running daemon; `run_daemon` drives it."""

    def __init__(
        self,
        cfg: RobotConfig,
        *,
        transport: Transport | None = None,
        link: RobotLink | None = None,
        receive_filter: ReceiveFilter | None = None,
        event_sink: RecordSink | None = None,
        time_origin: float = 0.0,
        config_path: Path | None = None,
        notifier: Notifier | None = None,
    ) -> None:
        self._cfg = cfg
        """The config last loaded (start or SIGHUP): the live-applied settings."""
        self._running_cfg = cfg
        """The config the daemon started with: what a SIGHUP that needs a restart is
        compared against (a reload that changed the timing and one that changed it back
        must not ask for a restart)."""
        self._config_path = config_path
        self._robot_id = cfg.robot
        self._swarm_id = cfg.swarm.swarm.id
        self._handover_on_stop = cfg.handover_on_stop
        self._injected_transport = transport
        self._injected_link = link
        self._injected_filter = receive_filter
        self._extra_sink = event_sink
        self._time_origin = time_origin
        self._notifier = notifier if notifier is not None else Notifier.from_env()
        self._metrics: Metrics | None = None
        if cfg.metrics is not None:
            # Imported only here: prometheus_client is about 5 MB of a robot's memory,
            # and without an endpoint nobody reads the counters.
            from swarmd.services.metrics import Metrics

            self._metrics = Metrics(robot_id=cfg.robot, swarm_id=self._swarm_id)
        self._init_started()
        self._state_file = state_mod.StateFile(
            state_mod.state_path(cfg.state_dir, self._swarm_id, cfg.robot),
            robot=cfg.robot, swarm=self._swarm_id, plan=cfg.swarm.to_plan())
        self._state_errors = 0
        self._reload_errors = 0
        self._function_specs: dict[str, dict[str, Any]] = self._specs(cfg)
        self._alert_hook = cfg.swarm.alert_hook
        self._hook_tasks: set[asyncio.Task[None]] = set()
        self._revocation = asyncio.Event()  # a reload found this robot revoked: EXIT_REVOKED

    def _init_started(self) -> None:
        """What `start` makes: None until it runs."""
        self._metrics_server: MetricsServer | None = None
        self._event_log: EventLog | None = None
        self._runtime: Runtime | None = None
        self._waiting: asyncio.Task[None] | None = None
        self._link_events: Callable[[Event], None] | None = None
        """A link that shows the swarm (ros2) gets every event too."""
        self._signer: Ed25519Signer | None = None
        self._keyring: Keyring | None = None
        """Per-robot auth: this robot's key and every robot's public keys, the objects
        the node was given; SIGHUP replaces their keys in place (rotation, revocation)."""

    # ---------------------------------------------------------------- what others read
    @property
    def cfg(self) -> RobotConfig:
        """The config last loaded (start or SIGHUP)."""
        return self._cfg

    @property
    def robot_id(self) -> int:
        return self._robot_id

    @property
    def runtime(self) -> Runtime | None:
        """The running runtime; None before `start`."""
        return self._runtime

    @property
    def signer(self) -> Ed25519Signer | None:
        """Per-robot auth: this robot's own key (what its node signs with)."""
        return self._signer

    @property
    def keyring(self) -> Keyring | None:
        """Per-robot auth: every robot's public key, and those revoked."""
        return self._keyring

    @property
    def handover_on_stop(self) -> bool:
        """Whether a graceful stop hands the function over (LEAVE), as last loaded."""
        return self._handover_on_stop

    @property
    def revoked(self) -> bool:
        """A reload found this robot revoked in the swarm file (it stops: EXIT_REVOKED)."""
        return self._revocation.is_set()

    async def wait_revoked(self) -> None:
        """Return once a reload found this robot revoked."""
        await self._revocation.wait()

    @property
    def state_errors(self) -> int:
        """State files found unusable at start (set aside; the robot started fresh)."""
        return self._state_errors

    @property
    def reload_errors(self) -> int:
        """SIGHUPs whose config or keys were refused (logged; the old ones stay)."""
        return self._reload_errors

    def _identity(self, cfg: RobotConfig) -> Identity | None:
        """The node's Identity in per-robot mode (None otherwise). Raises
        IdentityFileError naming the file."""
        material = cfg.identity_material()
        if material is None:
            return None
        self._signer = Ed25519Signer(cfg.robot, material.private_key)
        self._keyring = Keyring(material.public_keys, material.revoked, VerifyBudget(own=cfg.robot),
                                retired=material.retired)
        return Identity(self._signer, self._keyring)

    @staticmethod
    def _specs(cfg: RobotConfig) -> dict[str, dict[str, Any]]:
        return {f: cfg.swarm.function_spec(f) for f in cfg.swarm.functions}

    def function_params(self, function: str) -> Mapping[str, Any]:
        """Assign carries only (function, epoch); the robot gets the function's spec
        from the swarm file (`{"kind": "slot", "position": [...]}`, ...)."""
        return self._function_specs.get(function, {})

    # ---------------------------------------------------------------- events
    def on_event(self, t: float, event: Event) -> None:
        """Every event, at `t` s since the time origin: as a record to the event log
        and the injected sink (where it is written out), typed to the link, the stdout
        log and the alert hook."""
        record = event.record(t, self._robot_id)
        if self._event_log is not None:
            self._event_log.write(record)
        if self._extra_sink is not None:
            self._extra_sink(record)
        if self._link_events is not None:
            self._link_events(event)
        log.info("event %s", event.name, extra={NAME_KEY: event.name, "fields": event.fields()})
        if isinstance(event, Alert) and self._alert_hook:
            self._run_hook(event)

    def _run_hook(self, alert: Alert) -> None:
        """DESIGN rule 8: an alert (no standby left) runs the configured hook, in the
        background, with the alert in its environment."""
        hook = self._alert_hook
        assert hook is not None
        env = {"SWARMD_ROBOT": str(self._robot_id), "SWARMD_FUNCTION": alert.function,
               "SWARMD_REASON": alert.reason}

        async def run() -> None:
            try:
                status = await run_command(hook, env, ALERT_HOOK_TIMEOUT)
            except TimeoutError:  # first: TimeoutError is an OSError
                log.error("alert hook timed out; killed",
                          extra={"timeout_s": ALERT_HOOK_TIMEOUT})
            except OSError as exc:
                log.error("alert hook could not run", extra={"error": str(exc)})
            else:
                if status != 0:
                    log.error("alert hook failed", extra={"status": status})

        task = asyncio.get_running_loop().create_task(run())
        self._hook_tasks.add(task)
        task.add_done_callback(self._hook_tasks.discard)

    # ---------------------------------------------------------------- state
    def _load_state(self) -> state_mod.PersistedState | None:
        try:
            return self._state_file.load()
        except state_mod.StateError as exc:
            self._state_errors += 1
            moved = state_mod.set_aside(self._state_file.path)
            log.error("state file unusable; starting fresh", extra={
                "error": str(exc), "moved_to": str(moved) if moved else None})
            return None

    # ---------------------------------------------------------------- lifecycle
    async def start(self) -> Runtime:
        """Build the node and start transport, link and timers. Raises on set-up
        failure (the caller turns it into an exit code); `StartupError`, `EventLogError`,
        `MetricsError`, `TransportError` and `SocketLinkError` name the config field."""
        cfg = self._cfg
        loop = asyncio.get_running_loop()
        keys = cfg.keys()  # signing key first, then those also accepted (rotation)
        identity = self._identity(cfg)
        _ensure_dir("state_dir", cfg.state_dir)
        persisted = self._load_state()
        seq_start = state_mod.initial_seq(seq_seed(time.time()), persisted)
        params = cfg.swarm.params()
        now = loop.time()
        restored = persisted.restored() if persisted is not None else None
        node = Node(cfg.robot, cfg.swarm.to_plan(), params, now, keys=keys,
                    identity=identity, seq_start=seq_start, restored=restored)
        try:
            write_at = self._state_file.write_initial(persisted, seq_start)
        except OSError as exc:  # StateWriteError names the file
            raise StartupError(f"state_dir {cfg.state_dir}: {exc}") from exc
        self._open_outputs(cfg)
        transport = self._injected_transport or make_transport(
            cfg.transport, unheard=node.plan.unheard(cfg.robot))
        link = self._injected_link or make_link(cfg.link)
        # A restored holder keeps `held` on disk until its rejoin hold is over.
        holding = restored is not None and restored.held is not None
        self._runtime = self._make_runtime(
            node, transport, link, persist_after=now + params.rejoin_hold if holding else now,
            seq_write_at=write_at)
        self._watch(link, self._runtime)
        log.info("starting", extra={
            "robot": cfg.robot, "swarm": self._swarm_id, "transport": cfg.transport.kind,
            "link": getattr(cfg.link, "kind", "injected"), "seq_start": seq_start,
            "restored": persisted.to_json() if persisted is not None else None,
            "signed": bool(keys) or identity is not None, "auth": cfg.swarm.auth_mode,
            "event_loop": eventloop.describe(loop)})
        await self._runtime.start()
        rt = self._runtime
        self._waiting = loop.create_task(report_waiting(
            Waiting.of(cfg.swarm.to_plan(), cfg.robot), lambda: rt.heard(),
            grace=params.startup_grace, channel=describe_channel(cfg.transport)))
        return self._runtime

    def _open_outputs(self, cfg: RobotConfig) -> None:
        """Open the event log and start the metrics endpoint, if configured."""
        if cfg.event_log is not None:
            self._event_log = EventLog(cfg.event_log)
        if cfg.metrics is not None and self._metrics is not None:
            self._metrics_server = self._metrics.start_server(
                cfg.metrics.host, cfg.metrics.port, allow_remote=cfg.metrics.allow_remote)

    def _make_runtime(self, node: Node, transport: Transport, link: RobotLink, *,
                      persist_after: float, seq_write_at: int) -> Runtime:
        """The runtime that drives `node` over `transport` and `link`."""
        return Runtime(
            node, transport, link,
            function_params=self.function_params,
            event_sink=self.on_event,
            receive_filter=self._receive_filter(),
            state_writer=self._state_file.write_snapshot,
            persist_after=persist_after,
            seq_write_at=seq_write_at,
            # Without an endpoint there are none: spare the per-frame cost.
            metrics=self._metrics,
            notifier=self._notifier,
            time_origin=self._time_origin,
        )

    def _receive_filter(self) -> ReceiveFilter | None:
        """The injected filter (the simulator's losses), then, per robot, the signature
        budget's (`VerifyBudget.allows`: a flood past it is not even decoded)."""
        budget = self._keyring.budget if self._keyring is not None else None
        outer = self._injected_filter
        if budget is None:
            return outer
        if outer is None:
            return lambda data, now: budget.allows(data)
        return lambda data, now: outer(data, now) and budget.allows(data)

    def _watch(self, link: RobotLink, runtime: Runtime) -> None:
        # A link that publishes the swarm's view (ros2) reads the node only through its
        # snapshot and its typed events (DESIGN section 3), on this loop.
        watch = getattr(link, "watch", None)
        if watch is not None:
            self._link_events = watch(runtime.snapshot, self._cfg)

    def ready(self) -> None:
        """The first heartbeat is out (or READY_TIMEOUT passed): tell systemd READY."""
        self._notifier.ready()
        log.info("ready", extra={"robot": self._robot_id})

    async def stop(self, *, handover: bool | None = None) -> None:
        """Stop the node, with a LEAVE if it held a function and `handover` (None: as
        `handover_on_stop` says), then close everything, in that order."""
        self._notifier.stopping()
        if self._waiting is not None:
            self._waiting.cancel()
        rt = self._runtime
        if rt is not None:
            await rt.stop(handover=self._handover_on_stop if handover is None else handover)
            log.info("stopped", extra={"stats": rt.stats()})
            await rt.close_io()
        for task in list(self._hook_tasks):
            with contextlib.suppress(asyncio.TimeoutError, Exception):
                await asyncio.wait_for(asyncio.shield(task), 5.0)
        if self._event_log is not None:
            self._event_log.close()
        if self._metrics_server is not None:
            self._metrics_server.close()
        self._notifier.close()

    def reload(self) -> None:
        """SIGHUP: re-read the config and apply what can change live: the event log
        (reopened: logrotate, or a new path), handover_on_stop, the alert hook, the
        function parameters sent on the next assign, and the keys (rotation). Anything
        else (robot id, transport, link, timing, the plan) needs a restart; a change
        there is logged as such and ignored."""
        if self._config_path is None:
            log.warning("SIGHUP: no config path to reload from; ignored")
            return
        try:
            new = load_robot(self._config_path)
        except ConfigError as exc:
            if revoked_in(self._running_cfg.swarm.source, self._robot_id):
                self._revoke()
                return
            self._reload_errors += 1
            log.error("SIGHUP: config not reloaded", extra={
                "problems": [str(p) for p in exc.problems]})
            return
        old = self._running_cfg
        keys = self._reload_keys(new)
        self._reload_identity(new)
        try:
            self._reload_event_log(new.event_log)
        except OSError as exc:  # EventLogError: the old file (if any) stays in use
            self._reload_errors += 1
            log.error("SIGHUP: event log not reopened", extra={
                "error": str(exc), "kept": str(self._event_log.path) if self._event_log
                else None})
        self._handover_on_stop = new.handover_on_stop
        self._alert_hook = new.swarm.alert_hook
        self._function_specs = self._specs(new)
        restart_needed = _restart_needed(old, new)
        self._cfg = new
        log.info("SIGHUP: config reloaded", extra={
            "keys": len(keys) if keys is not None else None,
            "restart_needed_for": restart_needed})

    def _revoke(self) -> None:
        """SIGHUP found this robot in the swarm file's `auth.revoked` (swarmd.services.revocation):
        nobody accepts its frames any more and its slot is being taken over, so it stops
        acting: one log line, a `leave` (reason `revoked`) in its event log if it held a
        function, then `run_daemon` releases it through the link and exits."""
        if self._revocation.is_set():
            return
        self._revocation.set()
        snap = self._runtime.snapshot() if self._runtime is not None else None
        held = snap.function if snap is not None and snap.role == Role.ACTIVE else None
        log.error("revoked: this robot's key is revoked in the swarm file; releasing its "
                  "function and stopping", extra={
                      "robot": self._robot_id, "function": held,
                      "swarm_file": self._running_cfg.swarm.source,
                      "exit_status": EXIT_REVOKED})
        if held is not None:
            self.on_event(round(time.time() - self._time_origin, 6),
                          Leave(function=held, reason=LeaveCause.REVOKED))

    def _reload_keys(self, new: RobotConfig) -> tuple[bytes, ...] | None:
        """SIGHUP: the new config's keys, given to the node; None when refused (the
        old ones stay in use)."""
        try:
            keys = new.keys()
            if self._runtime is not None:
                # The node signs with keys[0] and accepts any: the rotation window.
                self._runtime.set_keys(keys)
        except Exception as exc:  # KeyFileError, NodeError, or an OSError reading
            self._reload_errors += 1
            log.error("SIGHUP: keys not reloaded; the old ones stay in use",
                      extra={"error": str(exc)})
            return None
        return keys

    def _reload_identity(self, new: RobotConfig) -> None:
        """SIGHUP in per-robot mode: the public keys of the keys dir (retired ones too,
        which verify history only) and the `revoked` list replace the keyring's, and
        this robot's identity_file its own key (docs/operations.md: rotating and
        revoking a robot's key). A key that cannot be read leaves the old ones in use. A
        change of auth mode needs a restart."""
        if self._keyring is None or self._signer is None or new.swarm.auth_mode != "per-robot":
            return
        try:
            material = new.identity_material()
            assert material is not None
            self._keyring.replace(material.public_keys, material.revoked,
                                  retired=material.retired)
            self._signer.replace(material.private_key)
            if self._runtime is not None:
                # A revoked robot's heartbeat chain must not keep it alive: from now on
                # only its anchors could, and they no longer verify.
                self._runtime.revoke(material.revoked)
        except Exception as exc:  # IdentityFileError, ValueError: a malformed key
            self._reload_errors += 1
            log.error("SIGHUP: identity keys not reloaded; the old ones stay in use",
                      extra={"error": str(exc)})
            return
        log.info("SIGHUP: identity keys reloaded", extra={
            "robots": sorted(self._keyring.robots), "revoked": sorted(self._keyring.revoked)})

    def _reload_event_log(self, path: Path | None) -> None:
        """SIGHUP: reopen the event log (logrotate moved it, or the path changed), start
        one newly configured, close one no longer configured. Raises `EventLogError`."""
        if self._event_log is not None and path is not None:
            self._event_log.reopen(path)
        elif self._event_log is not None:
            self._event_log.close()
            self._event_log = None
        elif path is not None:
            self._event_log = EventLog(path)


async def run_daemon(
    robot_cfg: RobotConfig,
    *,
    transport: Transport | None = None,
    link: RobotLink | None = None,
    receive_filter: ReceiveFilter | None = None,
    event_sink: RecordSink | None = None,
    stop_event: asyncio.Event | None = None,
    on_ready: Callable[[Daemon], None] | None = None,
    time_origin: float = 0.0,
    handle_signals: bool = False,
    config_path: Path | None = None,
) -> int:
    """Run one robot's daemon until `stop_event` is set; returns the exit code.

    `transport` / `link` replace the configured ones (the simulator's MuJoCo link);
    `receive_filter(data, now) -> False` drops a frame before the node sees it (loss,
    partitions); `event_sink` receives every event record as well as the event log
    file; event times are `time.time() - time_origin`. `on_ready(daemon)` is called
    once the first heartbeat is out. `handle_signals` installs SIGTERM / SIGINT (stop)
    and SIGHUP (reload from `config_path`) handlers on the running loop: only one daemon
    per process may ask for that.

    Cancelling the task stops the daemon without handover (see `_stop_cancelled`),
    cleans up, and re-raises `CancelledError`.
    """
    stop = stop_event if stop_event is not None else asyncio.Event()
    daemon = Daemon(robot_cfg, transport=transport, link=link, receive_filter=receive_filter,
                    event_sink=event_sink, time_origin=time_origin, config_path=config_path)
    loop = asyncio.get_running_loop()
    before = {sig: signal.getsignal(sig) for sig in signals.DEFERRED} if handle_signals else {}
    installed = _install_signals(loop, stop, daemon) if handle_signals else []
    try:
        return await _lifecycle(daemon, stop, on_ready, config_path)
    finally:
        for sig in installed:
            loop.remove_signal_handler(sig)  # leaves the signal's default action: death
            # Put back what was there: `swarmd start` records these signals from its first
            # line (swarmd/base/signals.py), so one that lands between the stop and the
            # process's exit (a reload burst) is no death and the exit status stays ours.
            prior = before.get(sig)
            if prior is not None:
                signal.signal(sig, prior)


async def _lifecycle(daemon: Daemon, stop: asyncio.Event,
                     on_ready: Callable[[Daemon], None] | None,
                     config_path: Path | None) -> int:
    """Start the daemon, serve until `stop`, stop it: the exit code."""
    runtime = await _start_or_log(daemon, config_path)
    if runtime is None:
        return EXIT_FAILURE
    await _serve(daemon, runtime, stop, on_ready)
    revoked = daemon.revoked
    # A revoked robot's LEAVE nobody accepts: it releases the robot and goes.
    handover = daemon.handover_on_stop and not revoked
    log.info("stopping", extra={"handover": handover})
    await daemon.stop(handover=handover)
    return EXIT_REVOKED if revoked else EXIT_OK


def _install_signals(loop: asyncio.AbstractEventLoop, stop: asyncio.Event,
                     daemon: Daemon) -> list[signal.Signals]:
    """SIGTERM and SIGINT set `stop`, SIGHUP reloads: the signals handled, to remove.
    What arrived before, while `swarmd start` was starting (swarmd/base/signals.py), is acted
    on now: a stop stops the daemon as soon as it has started, a reload reloads it."""
    installed: list[signal.Signals] = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
        installed.append(sig)
    loop.add_signal_handler(signal.SIGHUP, daemon.reload)
    installed.append(signal.SIGHUP)
    early = signals.take()
    if early:
        log.info("signals received while starting", extra={
            "signals": [signal.Signals(s).name for s in early]})
    if any(s != signal.SIGHUP for s in early):
        stop.set()
    elif early:
        loop.call_soon(daemon.reload)
    return installed


async def _start_or_log(daemon: Daemon, config_path: Path | None) -> Runtime | None:
    """`daemon.start()`, or None after logging why it failed and cleaning up."""
    try:
        return await daemon.start()
    except asyncio.CancelledError:
        await _stop_cancelled(daemon)
        raise
    except Exception as exc:
        log.error("daemon failed to start", extra={
            "error": str(exc), "error_type": type(exc).__name__,
            "config": str(config_path) if config_path is not None else None})
        await daemon.stop()
        return None


async def _serve(daemon: Daemon, runtime: Runtime, stop: asyncio.Event,
                 on_ready: Callable[[Daemon], None] | None) -> None:
    """Announce readiness once the first heartbeat is out, then wait for `stop`."""
    try:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(runtime.first_broadcast(), READY_TIMEOUT)
        daemon.ready()
        if on_ready is not None:
            on_ready(daemon)
        waits = [asyncio.ensure_future(stop.wait()),
                 asyncio.ensure_future(daemon.wait_revoked())]
        try:
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in waits:
                w.cancel()
    except asyncio.CancelledError:
        await _stop_cancelled(daemon)
        raise


async def _stop_cancelled(daemon: Daemon) -> None:
    """The task running `run_daemon` was cancelled: stop as a crash looks to the swarm
    (no LEAVE, whatever `handover_on_stop` says: the neighbours' watchdogs find it, as
    the paper's robots would), but still release the robot, write the state and close
    transport, link and event log, so no timer keeps heartbeating for a daemon nobody
    runs and no socket is left open. A graceful stop with handover is `stop_event`."""
    log.info("stopping", extra={"handover": False, "cancelled": True})
    await daemon.stop(handover=False)
