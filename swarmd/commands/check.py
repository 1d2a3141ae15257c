"""`swarmd check SWARM.yaml`: validate; print quorum coverage and timing (DESIGN.md 3)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    """Add the `check` command to the CLI."""

    @app.command("check")
    def check(
        file: Annotated[Path, typer.Argument(help="Swarm file, or a robot file (then its "
                                             "swarm file is checked too).")],
        json_out: Annotated[bool, typer.Option(
            "--json", help="Print the report as one JSON document: file, ok, problems, "
            "coverage, timing, channel_budget, flight.")] = False,
    ) -> None:
        """Validate a swarm file; show who watches and who covers each function.

        Prints every problem with its file, field and line, then the coverage table, the
        timing in use with the takeover bound, the channel budget on each radio medium,
        and what a simulated craft could not fly (docs/config.md).

        Exit codes: 0 usable (warnings allowed), 1 errors, 2 the file cannot be read.

        Example: swarmd check configs/paper.yaml
        """
        import json

        from rich.console import Console

        from swarmd.daemon.check import render, run_check

        report = run_check(file)
        if json_out:
            typer.echo(json.dumps(report.as_json(), indent=2))
        else:
            render(report, Console(highlight=False))
        raise typer.Exit(report.exit_code)
