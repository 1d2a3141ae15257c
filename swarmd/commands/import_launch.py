"""`swarmd import-launch FILE.launch [-o SWARM.yaml]`: the paper's ROS launch file as a
swarm file (DESIGN.md section 3)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from swarmd.config import SwarmConfig


def register(app: typer.Typer) -> None:
    """Add the `import-launch` command to the CLI."""

    @app.command("import-launch")
    def import_launch(
        file: Annotated[Path, typer.Argument(
            help="ROS launch XML (ROS 1 or ROS 2) or ROS 2 launch YAML, one node per robot "
            "with params robot_id, state, neighbors, subs (the paper's appendix).")],
        output: Annotated[
            Path | None, typer.Option("-o", "--output", help="Write the swarm file here "
                                      "(replaced if it exists). Default: stdout.")
        ] = None,
        swarm_id: Annotated[
            int, typer.Option("--swarm-id", min=0, max=0xFFFF,
                              help="16-bit swarm id carried by every frame.")
        ] = 1543,
        name: Annotated[
            str | None, typer.Option("--name", help="Swarm name. Default: the launch "
                                     "file's name without its extension.")
        ] = None,
    ) -> None:
        """Convert the paper's ROS launch file (ROS 1 XML, ROS 2 XML or YAML) into a
        swarm file.

        Active robot R gets the function fR, a slot on a circle of radius 2 m at 1.5 m;
        neighbors and subs carry over; timing is the udp preset. The result is validated
        like swarmd check before anything is written (docs/config.md).

        Exit codes: 0 written, 1 malformed launch file or a swarm check would refuse, 2
        the launch file cannot be read or the output cannot be written.

        Example: swarmd import-launch tests/fixtures/paper.launch -o my-swarm.yaml
        """
        _import_launch(file, output, swarm_id, name)


def _import_launch(file: Path, output: Path | None, swarm_id: int, name: str | None) -> None:
    """`swarmd import-launch`: convert, validate, write; raises typer.Exit on failure."""
    from swarmd.base.files import output_problem

    # The output path is checked before anything runs: a FIFO would block the write
    # forever, a device or a directory is never a swarm file.
    if output is not None and (why := output_problem(output)) is not None:
        typer.echo(f"{output}: cannot write: {why}", err=True)
        raise typer.Exit(2)
    text = _convert(file, swarm_id, name)
    cfg = _validated(text, file, output)
    for w in cfg.warnings:
        typer.echo(str(w), err=True)
    if output is None:
        typer.echo(text, nl=False)
    else:
        try:
            output.write_text(text, encoding="utf-8")
        except OSError as exc:
            typer.echo(f"{output}: cannot write: {exc}", err=True)
            raise typer.Exit(2) from None
        typer.echo(f"wrote {output} ({len(cfg.robots)} robots, "
                   f"{len(cfg.functions)} functions)", err=True)


def _convert(file: Path, swarm_id: int, name: str | None) -> str:
    """The swarm file's text converted from the launch file."""
    from swarmd.base.files import FileRefused
    from swarmd.services.launch import LaunchError, import_launch_file

    try:
        return import_launch_file(file, swarm_id=swarm_id, name=name)
    except FileRefused as exc:
        typer.echo(f"{file}: cannot read the file: {exc.reason}", err=True)
        raise typer.Exit(2) from None
    except (OSError, UnicodeDecodeError) as exc:
        typer.echo(f"{file}: cannot read the file: {exc}", err=True)
        raise typer.Exit(2) from None
    except LaunchError as exc:
        typer.echo(str(exc), err=True)
        raise typer.Exit(1) from None


def _validated(text: str, file: Path, output: Path | None) -> SwarmConfig:
    """The converted swarm, checked as `swarmd check` would."""
    from swarmd.config import ConfigError, parse_swarm

    # The result must be a valid swarm (an unknown neighbour in the launch file, a
    # slot with too few watchers): say so in the launch file's terms, write nothing.
    # Name the problems after the converted text, never after `output`: nothing was
    # written there, so a line number in that file would point at nothing.
    target = output if output is not None else Path(file.name)
    try:
        return parse_swarm(text, f"<{file.name} converted>", target)
    except ConfigError as exc:
        typer.echo(f"{file}: the converted swarm is not valid:", err=True)
        for p in exc.problems:
            typer.echo(f"  {p}", err=True)
        raise typer.Exit(1) from None
