"""`swarmd monitor`: a live table of every robot on the channel (DESIGN section 3).

The monitor joins the channel as a passive listener, the paper's base station; it never
sends. `--once --json` listens for `--duration` seconds, prints one JSON document and
exits (for scripts and tests).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from swarmd.transport.addresses import DEFAULT_GROUP, DEFAULT_INTERFACE, DEFAULT_PORT


def register(app: typer.Typer) -> None:
    """Add the `monitor` command to the CLI."""

    @app.command()
    def monitor(
        config: Annotated[Path | None, typer.Option(
            "--config", help="A robot file: listen with its swarm, its UDP transport and "
            "its keys (signed swarms).")] = None,
        swarm: Annotated[Path | None, typer.Option(
            "--swarm", help="A swarm file instead of --config; the channel is then "
            "--group, --port, --interface.")] = None,
        group: Annotated[str, typer.Option(
            "--group", help="UDP multicast group (with --swarm).")] = DEFAULT_GROUP,
        port: Annotated[int, typer.Option("--port", help="UDP port (with --swarm).")] = (
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
            "--duration",
            help="Seconds to listen. Default: 2 with --once or --json, else until "
            "Ctrl-C.")] = None,
    ) -> None:
        """Watch the swarm channel, like the paper's base station; sends nothing.

        A live table per robot: role, function, epoch, last heard, health, who warns
        about it and how many distinct witnesses, alerts (a silent slot, a suspicion
        nobody claims, two robots on one function). Give exactly one of --config or
        --swarm. UDP only.

        Exit codes: 0 done, 1 the channel cannot be opened, 2 unusable config or bad
        usage (neither or both of --config and --swarm, a radio transport), 130 Ctrl-C
        (as `start` and `sim`).

        Example: swarmd monitor --swarm configs/paper.yaml --once --json --duration 5
        """
        import asyncio
        import json
        import time

        from rich.console import Console

        from swarmd.config import ConfigError, ConfigUnreadable, load_robot, load_swarm
        from swarmd.monitor import MonitorState, listen
        from swarmd.transport.base import TransportError
        from swarmd.transport.udp import UdpTransport

        console = Console()
        err = Console(stderr=True, highlight=False, markup=False, soft_wrap=True)
        if (config is None) == (swarm is None):
            err.print("give exactly one of --config ROBOT.yaml or --swarm SWARM.yaml")
            raise typer.Exit(2)
        try:
            if config is not None:
                robot = load_robot(config)
                swarm_cfg = robot.swarm
                keys = list(robot.keys())
                tcfg = robot.transport
                if tcfg.kind != "udp":
                    err.print(f"{config}: monitor listens on udp only (transport is "
                              f"{tcfg.kind}); use an emulated radio bridge")
                    raise typer.Exit(2)
                transport = UdpTransport.from_config(tcfg)
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
        state = MonitorState(swarm_cfg.to_plan(), swarm_cfg.params(), keys)
        listen_for = duration if duration is not None else (2.0 if once else None)

        async def run_once() -> float:
            return await listen(state, transport, duration=listen_for)

        async def run_live() -> float:
            from rich.live import Live

            loop = asyncio.get_running_loop()
            with Live(state.table(loop.time()), console=console, refresh_per_second=4) as live:
                return await listen(state, transport, duration=listen_for,
                                    on_refresh=lambda now: live.update(state.table(now)))

        try:
            listened = asyncio.run(run_once() if once or as_json else run_live())
        except TransportError as exc:
            err.print(str(exc))
            raise typer.Exit(1) from None
        except KeyboardInterrupt:
            raise typer.Exit(130) from None
        # asyncio's loop clock is time.monotonic, so this continues the listener's clock.
        t = time.monotonic()
        if as_json:
            print(json.dumps(state.to_json(t, listened), indent=2))
        elif once:
            console.print(state.table(t))
