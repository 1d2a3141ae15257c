"""`swarmd keygen FILE`: write a new 32-byte swarm key, mode 0600 (issue 6 point 3)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    """Add the `keygen` command to the CLI."""

    @app.command()
    def keygen(
        path: Annotated[
            Path, typer.Argument(help="Key file to create (its directory must exist).")
        ],
        force: Annotated[
            bool, typer.Option("--force", help="Replace an existing key file (default: "
                               "refuse).")
        ] = False,
        hex_format: Annotated[
            bool, typer.Option("--hex", help="Write 64 hex digits instead of 32 raw bytes.")
        ] = False,
    ) -> None:
        """Generate a swarm key (32 random bytes, file mode 0600).

        Every robot of a swarm needs the same key: generate it once and copy it to each
        robot (scp -p keeps the mode), owned by the daemon's user; the swarm file's
        key_file names it (docs/operations.md section 4).

        Exit codes: 0 written, 1 the file exists (without --force) or cannot be written.

        Example: swarmd keygen swarm.key
        """
        from swarmd.keys import KeyFileError, generate_key

        try:
            generate_key(path, force=force, hex_format=hex_format)
        except KeyFileError as exc:
            typer.echo(f"swarmd keygen: {exc}", err=True)
            raise typer.Exit(1) from None
        except OSError as exc:
            typer.echo(f"swarmd keygen: cannot write {path}: {exc.strerror}", err=True)
            raise typer.Exit(1) from None
        typer.echo(
            f"wrote a new swarm key to {path} (mode 0600). Copy it to every robot of the "
            f"swarm, owned by the daemon's user: install -m 600 -o swarmd {path} "
            "/etc/swarmd/swarm.key"
        )
