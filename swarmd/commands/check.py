"""`swarmd check SWARM.yaml`: validate; print quorum coverage and timing (DESIGN.md 3)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    """Add the `check` command to the CLI."""

    @app.command("check")
    def check(
        file: Annotated[Path, typer.Argument(help="Swarm file (or a robot file: its swarm "
                                             "is checked too).")],
        json_out: Annotated[bool, typer.Option("--json", help="Print the report as JSON.")]
        = False,
    ) -> None:
        """Validate a swarm file; show who watches and who covers each function.

        Exit 0 if usable (warnings allowed), 1 on errors, 2 if the file is unreadable.
        """
        import json

        from rich.console import Console

        from swarmd.check import render, run_check

        report = run_check(file)
        if json_out:
            typer.echo(json.dumps(report.as_json(), indent=2))
        else:
            render(report, Console(highlight=False))
        raise typer.Exit(report.exit_code)
