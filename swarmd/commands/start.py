"""`swarmd start --config robot.yaml`: run one robot's daemon (systemd runs this).

Logs one JSON object a line on stdout (journald), appends the event log if configured,
stops cleanly on SIGTERM / SIGINT (LEAVE when it held a function and handover_on_stop),
reloads on SIGHUP. Exit codes: 0 clean stop, 1 start-up failure, 2 unusable config.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

LEVELS = ("debug", "info", "warning", "error")


def _check_level(value: str) -> str:
    if value.lower() not in LEVELS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(LEVELS)}")
    return value.lower()


def register(app: typer.Typer) -> None:
    """Add the `start` command to the CLI."""

    @app.command()
    def start(
        config: Annotated[Path, typer.Option(
            "--config", "-c", help="Robot file (YAML, docs/config.md): robot id, swarm "
            "file, transport, link.")],
        log_level: Annotated[str, typer.Option(
            "--log-level", callback=_check_level,
            help="Least severe level logged: debug, info, warning or error.")] = "info",
    ) -> None:
        """Run one robot's daemon until SIGTERM / SIGINT (what systemd runs).

        Logs one JSON object a line on stdout. SIGTERM / SIGINT hand the robot's function
        over (LEAVE, with handover_on_stop) and stop; SIGHUP reloads keys, event log and
        alert hook (docs/daemon.md).

        Exit codes: 0 clean stop, 1 start-up failure (transport, link, state_dir, key
        file), 2 unusable config (every problem logged with its file and field).

        Example: swarmd start --config /etc/swarmd/robot.yaml
        """
        import asyncio
        import logging

        from swarmd.config import ConfigError, load_robot
        from swarmd.daemon import EXIT_CONFIG, run_daemon
        from swarmd.logs import setup_logging

        setup_logging(log_level)
        log = logging.getLogger("swarmd.start")
        try:
            cfg = load_robot(config)
        except ConfigError as exc:
            # Every problem on its own line, each naming file and field.
            for problem in exc.problems:
                log.error(str(problem), extra={"config": str(config)})
            raise typer.Exit(EXIT_CONFIG) from None
        for warning in cfg.warnings:
            log.warning(str(warning))
        code = asyncio.run(run_daemon(cfg, handle_signals=True, config_path=config))
        raise typer.Exit(code)
