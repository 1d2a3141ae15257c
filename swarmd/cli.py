"""`swarmd` command line (typer). DESIGN.md section 3 fixes the commands.

Each command lives in `swarmd/commands/<name>.py` with a `register(app)` function; this
file only assembles them, so owners of different commands never edit the same code.
"""

from __future__ import annotations

import sys

if sys.argv[1:2] == ["start"]:
    # First of all, before the imports below take their time: a SIGHUP or SIGTERM
    # while the daemon starts must not kill it (swarmd/base/signals.py).
    from swarmd.base import signals

    signals.defer()

import importlib
import inspect
import re

import typer

app = typer.Typer(
    name="swarmd",
    help=(
        "Failure handling for robot swarms. Robots heartbeat to their neighbours; a "
        "neighbour that misses heartbeats warns the standby robot; a standby warned by "
        "enough distinct neighbours takes the failed robot's function over.\n\n"
        "Each command has its own --help (what it does, its options with units and "
        "defaults, exit codes, an example). Docs: README.md and docs/ in the source.\n\n"
        "Example: swarmd sim configs/paper.yaml --virtual --fault crash:2@5 --duration 20"
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

def _version(value: bool) -> None:
    if value:
        from swarmd import __version__

        typer.echo(f"swarmd {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                 help="Print the version and exit."),
) -> None:
    """Failure handling for robot swarms (see --help)."""


# Order here is the order in `swarmd --help`.
COMMAND_MODULES = (
    "start",
    "sim",
    "check",
    "import_launch",
    "monitor",
    "xbee",
    "keygen",
)


def unwrap(text: str) -> str:
    """A docstring as paragraphs, each one line: rich keeps a docstring's line breaks
    and wraps again at the terminal's width, which leaves one word on a line of its own
    at 80 columns. Blank lines still separate paragraphs; a line that starts a list item
    (`- `) or is indented keeps its break."""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(re.sub(r"\n(?![ \t]|- )", " ", p) for p in paragraphs)


def _unwrap_all(group: typer.Typer) -> None:
    """Every command's and sub-group's help, unwrapped (`unwrap`)."""
    for info in group.registered_commands:
        text = info.help or (info.callback.__doc__ if info.callback else None)
        if text:
            info.help = unwrap(text)
    for sub in group.registered_groups:
        if sub.typer_instance is not None:
            sub_info = sub.typer_instance.info
            if isinstance(sub_info.help, str):
                sub_info.help = unwrap(sub_info.help)
            # A group whose callback runs a command of its own (`swarmd sim SWARM`):
            # its help is the callback's docstring.
            cb = sub.typer_instance.registered_callback
            if cb is not None and cb.callback is not None:
                doc = cb.help if isinstance(cb.help, str) else cb.callback.__doc__
                if doc:
                    cb.help = unwrap(doc)
            _unwrap_all(sub.typer_instance)


def _register_all() -> None:
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"swarmd.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"swarmd.commands.{name}":
                continue  # command not built yet in this tree
            raise
        module.register(app)
    _unwrap_all(app)


_register_all()


def main() -> None:
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
