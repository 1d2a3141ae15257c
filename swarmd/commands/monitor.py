"""`swarmd monitor`: a live table of every robot on the channel (DESIGN section 3).

The monitor joins the channel as a passive listener, the paper's base station; it never
sends. With `--config` it listens through the transport that file names: UDP multicast,
an XBee (the coordinator, as in the paper) or a transparent serial radio.
`--once --json` listens for `--duration` seconds, prints one JSON document and exits
(for scripts and tests).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from swarmd.commands.numbers import positive
from swarmd.transport.addresses import DEFAULT_GROUP, DEFAULT_INTERFACE, DEFAULT_PORT

if TYPE_CHECKING:
    from rich.console import Console

    from swarmd.config import SwarmConfig
    from swarmd.daemon.monitor import MonitorState
    from swarmd.daemon.monitor_ros2 import MonitorPublisher
    from swarmd.transport.base import Transport

# Each option's declaration (flag, range, help) as a type of its own, so the signature
# of `monitor` stays short beside its docstring (the --help text).
ConfigOpt = Annotated[Path | None, typer.Option(
    "--config", help="A base station file (swarm, transport, key_files; "
    "docs/operations.md) or a robot file: listen with its swarm, its transport "
    "(udp, xbee, serial) and its keys (signed swarms).")]
SwarmOpt = Annotated[Path | None, typer.Option(
    "--swarm", help="A swarm file instead of --config; the channel is then "
    "--group, --port, --interface.")]
GroupOpt = Annotated[str, typer.Option("--group", help="UDP multicast group (with --swarm).")]
PortOpt = Annotated[int, typer.Option("--port", min=1, max=0xFFFF,
                                      help="UDP port (with --swarm).")]
InterfaceOpt = Annotated[str, typer.Option(
    "--interface",
    help="IPv4 address of the interface to listen on (with --swarm; the default "
    "is loopback, a Wi-Fi swarm needs this machine's address on it).")]
OnceOpt = Annotated[bool, typer.Option(
    "--once", help="Listen for --duration seconds, print one table, exit.")]
JsonOpt = Annotated[bool, typer.Option(
    "--json", help="Print one JSON document instead of a table (implies --once).")]
DurationOpt = Annotated[float | None, typer.Option(
    "--duration", callback=positive,
    help="Seconds to listen, more than 0. Default: 2 with --once or --json, else until "
    "Ctrl-C.")]
Ros2Opt = Annotated[bool, typer.Option(
    "--ros2", help="Also publish the swarm on ROS 2 /diagnostics (one status per "
    "function, at every change and at least once a second) for rqt_robot_monitor; "
    "domain $ROS_DOMAIN_ID, this machine only unless "
    "$ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise. Needs swarmd\\[ros2] "
    "(docs/ros2.md).")]


def register(app: typer.Typer) -> None:
    """Add the `monitor` command to the CLI."""
    app.command()(monitor)


def monitor(
    config: ConfigOpt = None, swarm: SwarmOpt = None, group: GroupOpt = DEFAULT_GROUP,
    port: PortOpt = DEFAULT_PORT, interface: InterfaceOpt = DEFAULT_INTERFACE,
    once: OnceOpt = False, as_json: JsonOpt = False, duration: DurationOpt = None,
    ros2: Ros2Opt = False,
) -> None:
    """Watch the swarm channel, like the paper's base station; sends nothing.

    A live table per robot: role, function, epoch, last heard, health, who warns
    about it and how many distinct witnesses, status (live, silent, superseded by a
    newer epoch, left), alerts (a silent slot, a suspicion nobody claims, two robots
    on one function). Give exactly one of --config or --swarm. --config listens
    through any transport its file names (udp, an XBee coordinator, serial).

    Exit codes: 0 done, 1 the channel cannot be opened, 2 unusable config or bad
    usage (neither or both of --config and --swarm), 130 Ctrl-C (as `start` and
    `sim`).

    Example: swarmd monitor --config base.yaml --once --json --duration 5
    """
    err = _plain_stderr()
    if (config is None) == (swarm is None):
        err.print("give exactly one of --config ROBOT.yaml or --swarm SWARM.yaml")
        raise typer.Exit(2)
    swarm_cfg, keys, transport = _channel(err, config, swarm, group, port, interface)
    state = _state(err, swarm_cfg, keys)
    listen_for = duration if duration is not None else (2.0 if once else None)
    publisher = _ros2_publisher(err, state, swarm_cfg) if ros2 else None
    listened = _listen(err, state, transport, listen_for, publisher, live=not (once or as_json))
    _print_result(state, listened, as_json=as_json, once=once)


def _plain_stderr() -> Console:
    """Problems as plain text on stderr: no rich markup (a `[x]` in a message is not a
    tag) and no wrapping (one problem a line, for grep)."""
    from rich.console import Console

    return Console(stderr=True, highlight=False, markup=False, soft_wrap=True)


def _channel(err: Console, config: Path | None, swarm: Path | None, group: str, port: int,
             interface: str) -> tuple[SwarmConfig, list[bytes], Transport]:
    """The swarm to watch, its keys and the transport to listen through: those a base
    station (or robot) file names, or a swarm file's on a UDP channel of the options.
    Exits 2 on an unusable file, 1 on a transport that cannot be made."""
    from swarmd.config import ConfigError, ConfigUnreadable, load_swarm
    from swarmd.config.base_station import load_base_station
    from swarmd.daemon.daemon import make_transport
    from swarmd.transport.base import TransportError
    from swarmd.transport.udp import UdpTransport

    try:
        if config is not None:
            base = load_base_station(config)
            return base.swarm, list(base.keys), make_transport(base.transport)
        assert swarm is not None
        swarm_cfg = load_swarm(swarm)
        key = swarm_cfg.key()
        keys = [key] if key is not None else []
        return swarm_cfg, keys, UdpTransport(group=group, port=port, interface=interface)
    except (ConfigError, ConfigUnreadable) as exc:
        err.print(str(exc))
        raise typer.Exit(2) from None
    except TransportError as exc:
        err.print(str(exc))
        raise typer.Exit(1) from None


def _state(err: Console, swarm_cfg: SwarmConfig, keys: list[bytes]) -> MonitorState:
    """An empty view of the swarm, checking frames with `keys`."""
    from swarmd.base.identity import Keyring
    from swarmd.base.keys import KeyFileError
    from swarmd.config.auth import public_keys, retired_keys
    from swarmd.daemon.monitor import MonitorState

    # Per-robot auth: every robot's public keys, so the base station verifies the
    # signed WARN, CLAIM and LEAVE frames it listens to (it signs nothing itself).
    keyring: Keyring | None = None
    if swarm_cfg.auth_mode == "per-robot":
        try:
            keyring = Keyring(public_keys(swarm_cfg), swarm_cfg.revoked,
                              retired=retired_keys(swarm_cfg))
        except KeyFileError as exc:  # heartbeats still show; signed frames are dropped
            err.print(f"warning: {exc}: signed WARN/CLAIM/LEAVE frames cannot be "
                      "verified and are not shown")
    return MonitorState(swarm_cfg.to_plan(), swarm_cfg.params(), keys, verifier=keyring)


def _ros2_publisher(err: Console, state: MonitorState,
                    swarm_cfg: SwarmConfig) -> MonitorPublisher:
    """`state` published on ROS 2 /diagnostics from now on; exits 2 without rclpy."""
    from swarmd.daemon.monitor_ros2 import MonitorPublisher
    from swarmd.link.ros2_node import Ros2Unavailable, require_rclpy

    try:
        require_rclpy("swarmd monitor --ros2")
    except Ros2Unavailable as exc:
        err.print(str(exc))
        raise typer.Exit(2) from None
    publisher = MonitorPublisher(state, swarm_cfg.swarm.name or str(swarm_cfg.swarm.id))
    publisher.start()
    return publisher


def _listen(err: Console, state: MonitorState, transport: Transport, duration: float | None,
            publisher: MonitorPublisher | None, *, live: bool) -> float:
    """Listen for `duration` s (None: until Ctrl-C), under a live table if `live`; the
    seconds listened. Exits 1 when the channel fails, 130 on Ctrl-C; the publisher is
    stopped either way."""
    import asyncio

    from swarmd.daemon.monitor import listen
    from swarmd.transport.base import TransportError

    try:
        return asyncio.run(
            _listen_live(state, transport, duration, publisher) if live else
            listen(state, transport, duration=duration,
                   on_refresh=publisher.refresh if publisher else None))
    except TransportError as exc:
        err.print(str(exc))
        raise typer.Exit(1) from None
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    finally:
        if publisher is not None:
            publisher.stop()


async def _listen_live(state: MonitorState, transport: Transport, duration: float | None,
                       publisher: MonitorPublisher | None) -> float:
    """`listen`, with the table on stdout redrawn (and the publisher refreshed) as
    frames come in."""
    import asyncio

    from rich.console import Console
    from rich.live import Live

    from swarmd.daemon.monitor import listen

    loop = asyncio.get_running_loop()
    with Live(state.table(loop.time()), console=Console(), refresh_per_second=4) as live:
        def refresh(now: float) -> None:
            live.update(state.table(now))
            if publisher is not None:
                publisher.refresh(now)

        return await listen(state, transport, duration=duration, on_refresh=refresh)


def _print_result(state: MonitorState, listened: float, *, as_json: bool, once: bool) -> None:
    """What `--json` or `--once` prints once listening is over (a live table has shown
    it all already)."""
    import json
    import time

    from rich.console import Console

    # asyncio's loop clock is time.monotonic, so this continues the listener's clock.
    t = time.monotonic()
    if as_json:
        print(json.dumps(state.to_json(t, listened), indent=2))
    elif once:
        Console().print(state.table(t))
