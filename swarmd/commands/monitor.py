"""`swarmd monitor`: a live table of every robot on the channel (DESIGN section 3).

The monitor joins the channel as a passive listener, the paper's base station; it never
sends. With `--config` it listens through the transport that file names: UDP multicast,
an XBee (the coordinator, as in the paper) or a transparent serial radio.
`--once --json` listens for `--duration` seconds, prints one JSON document and exits
(for scripts and tests).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from swarmd.commands.numbers import positive
from swarmd.transport.addresses import DEFAULT_GROUP, DEFAULT_INTERFACE, DEFAULT_PORT


def register(app: typer.Typer) -> None:
    """Add the `monitor` command to the CLI."""

    @app.command()
    def monitor(
        config: Annotated[Path | None, typer.Option(
            "--config", help="A base station file (swarm, transport, key_files; "
            "docs/operations.md) or a robot file: listen with its swarm, its transport "
            "(udp, xbee, serial) and its keys (signed swarms).")] = None,
        swarm: Annotated[Path | None, typer.Option(
            "--swarm", help="A swarm file instead of --config; the channel is then "
            "--group, --port, --interface.")] = None,
        group: Annotated[str, typer.Option(
            "--group", help="UDP multicast group (with --swarm).")] = DEFAULT_GROUP,
        port: Annotated[int, typer.Option("--port", min=1, max=0xFFFF,
                                          help="UDP port (with --swarm).")] = (
            DEFAULT_PORT),
        interface: Annotated[str, typer.Option(
            "--interface",
            help="IPv4 address of the interface to listen on (with --swarm; the default "
            "is loopback, a Wi-Fi swarm needs this machine's address on it).")] = (
            DEFAULT_INTERFACE),
        once: Annotated[bool, typer.Option(
            "--once", help="Listen for --duration seconds, print one table, exit.")] = False,
        as_json: Annotated[bool, typer.Option(
            "--json", help="Print one JSON document instead of a table (implies "
            "--once).")] = False,
        duration: Annotated[float | None, typer.Option(
            "--duration", callback=positive,
            help="Seconds to listen, more than 0. Default: 2 with --once or --json, else until "
            "Ctrl-C.")] = None,
        ros2: Annotated[bool, typer.Option(
            "--ros2", help="Also publish the swarm on ROS 2 /diagnostics (one status per "
            "function, at every change and at least once a second) for rqt_robot_monitor; "
            "domain $ROS_DOMAIN_ID, this machine only unless "
            "$ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise. Needs swarmd[ros2] "
            "(docs/ros2.md).")] = False,
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
        import asyncio
        import json
        import time

        from rich.console import Console

        from swarmd.config import ConfigError, ConfigUnreadable, load_swarm
        from swarmd.config.auth import public_keys
        from swarmd.config.base_station import load_base_station
        from swarmd.daemon import make_transport
        from swarmd.identity import Keyring
        from swarmd.keys import KeyFileError
        from swarmd.monitor import MonitorState, listen
        from swarmd.transport.base import Transport, TransportError
        from swarmd.transport.udp import UdpTransport

        console = Console()
        err = Console(stderr=True, highlight=False, markup=False, soft_wrap=True)
        if (config is None) == (swarm is None):
            err.print("give exactly one of --config ROBOT.yaml or --swarm SWARM.yaml")
            raise typer.Exit(2)
        try:
            transport: Transport
            if config is not None:
                base = load_base_station(config)
                swarm_cfg = base.swarm
                keys = list(base.keys)
                transport = make_transport(base.transport)
            else:
                assert swarm is not None
                swarm_cfg = load_swarm(swarm)
                key = swarm_cfg.key()
                keys = [key] if key is not None else []
                transport = UdpTransport(group=group, port=port, interface=interface)
        except (ConfigError, ConfigUnreadable) as exc:
            err.print(str(exc))
            raise typer.Exit(2) from None
        except TransportError as exc:
            err.print(str(exc))
            raise typer.Exit(1) from None
        # Per-robot auth: every robot's public keys, so the base station verifies the
        # signed WARN, CLAIM and LEAVE frames it listens to (it signs nothing itself).
        keyring: Keyring | None = None
        if swarm_cfg.auth_mode == "per-robot":
            try:
                keyring = Keyring(public_keys(swarm_cfg), swarm_cfg.revoked)
            except KeyFileError as exc:  # heartbeats still show; signed frames are dropped
                err.print(f"warning: {exc}: signed WARN/CLAIM/LEAVE frames cannot be "
                          "verified and are not shown")
        state = MonitorState(swarm_cfg.to_plan(), swarm_cfg.params(), keys, verifier=keyring)
        listen_for = duration if duration is not None else (2.0 if once else None)
        publisher = None
        if ros2:
            from swarmd.link.ros2_node import Ros2Unavailable, require_rclpy
            from swarmd.monitor_ros2 import MonitorPublisher

            try:
                require_rclpy("swarmd monitor --ros2")
            except Ros2Unavailable as exc:
                err.print(str(exc))
                raise typer.Exit(2) from None
            publisher = MonitorPublisher(state, swarm_cfg.swarm.name or str(swarm_cfg.swarm.id))
            publisher.start()

        async def run_once() -> float:
            return await listen(state, transport, duration=listen_for,
                                on_refresh=publisher.refresh if publisher else None)

        async def run_live() -> float:
            from rich.live import Live

            loop = asyncio.get_running_loop()
            with Live(state.table(loop.time()), console=console, refresh_per_second=4) as live:
                def refresh(now: float) -> None:
                    live.update(state.table(now))
                    if publisher is not None:
                        publisher.refresh(now)

                return await listen(state, transport, duration=listen_for, on_refresh=refresh)

        try:
            listened = asyncio.run(run_once() if once or as_json else run_live())
        except TransportError as exc:
            err.print(str(exc))
            raise typer.Exit(1) from None
        except KeyboardInterrupt:
            raise typer.Exit(130) from None
        finally:
            if publisher is not None:
                publisher.stop()
        # asyncio's loop clock is time.monotonic, so this continues the listener's clock.
        t = time.monotonic()
        if as_json:
            print(json.dumps(state.to_json(t, listened), indent=2))
        elif once:
            console.print(state.table(t))
