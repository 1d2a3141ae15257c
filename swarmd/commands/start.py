"""`swarmd start --config robot.yaml`: run one robot's daemon (systemd runs this).

Logs one JSON object a line on stdout (journald), or readable lines on a terminal
(`--log-format`), appends the event log if configured,
stops cleanly on SIGTERM / SIGINT (LEAVE when it held a function and handover_on_stop),
reloads on SIGHUP. Exit codes: 0 clean stop, 1 start-up failure, 2 unusable config,
3 this robot's key is revoked (swarmd.services.revocation; not restarted by the unit).
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


def _check_format(value: str | None) -> str | None:
    from swarmd.base.logs import FORMATS

    if value is not None and value.lower() not in FORMATS:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(FORMATS)}")
    return value.lower() if value is not None else None


def _check_loop(value: str | None) -> str | None:
    from swarmd.base.eventloop import CHOICES

    if value is not None and value.lower() not in CHOICES:
        raise typer.BadParameter(f"{value!r} is not one of {', '.join(CHOICES)}")
    return value.lower() if value is not None else None


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
        log_format: Annotated[str | None, typer.Option(
            "--log-format", callback=_check_format,
            help="How log lines look on stdout: text (local time, robot, event, fields; "
            "for people) or json (one object a line, for journald and tools). Default: "
            "text on a terminal, json otherwise.")] = None,
        event_loop: Annotated[str | None, typer.Option(
            "--event-loop", callback=_check_loop,
            help="auto (uvloop when installed, else asyncio's), uvloop or asyncio. "
            "Default: $SWARMD_EVENT_LOOP, else auto.")] = None,
    ) -> None:
        """Run one robot's daemon until SIGTERM / SIGINT (what systemd runs).

        Logs one JSON object a line on stdout, or readable text lines on a terminal
        (--log-format). SIGTERM / SIGINT hand the robot's function
        over (LEAVE, with handover_on_stop) and stop; SIGHUP reloads keys, event log and
        alert hook (docs/daemon.md).

        Exit codes: 0 clean stop, 1 start-up failure (transport, link, state_dir, key
        file), 2 unusable config (every problem logged with its file and field), 3 this
        robot's key is revoked in the swarm file (at start, or learnt by a SIGHUP: it
        released its function through its link and stopped; docs/operations.md).

        Example: swarmd start --config /etc/swarmd/robot.yaml
        """
        _start(config, log_level, log_format, event_loop)


def _start(config: Path, log_level: str, log_format: str | None,
           event_loop: str | None = None) -> None:
    """`swarmd start`: load the robot file and run its daemon; raises typer.Exit."""
    import logging

    from swarmd.base.eventloop import EventLoopError, run
    from swarmd.base.logs import LogFormat, default_format, setup_logging
    from swarmd.config import ConfigError, load_robot
    from swarmd.daemon.daemon import EXIT_CONFIG, run_daemon
    from swarmd.services.revocation import EXIT_REVOKED, revoked_problem

    fmt: LogFormat = "text" if (log_format or default_format()) == "text" else "json"
    setup_logging(log_level, fmt=fmt)
    log = logging.getLogger("swarmd.start")
    try:
        cfg = load_robot(config)
    except ConfigError as exc:
        # Every problem on its own line, each naming file and field.
        for problem in exc.problems:
            log.error(str(problem), extra={"config": str(config)})
        revoked = revoked_problem(exc.problems) is not None
        raise typer.Exit(EXIT_REVOKED if revoked else EXIT_CONFIG) from None
    setup_logging(log_level, fmt=fmt, robot=cfg.robot)
    for warning in cfg.warnings:
        log.warning(str(warning))
    try:
        code = run(run_daemon(cfg, handle_signals=True, config_path=config), event_loop)
    except EventLoopError as exc:
        log.error(str(exc))
        raise typer.Exit(1) from None
    raise typer.Exit(code)
