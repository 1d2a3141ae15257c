"""`swarmd keygen`: a swarm key (shared mode), or per-robot Ed25519 key pairs.

    swarmd keygen FILE                      # 32-byte shared swarm key, mode 0600
    swarmd keygen --robot 3 DIR             # DIR/robot-3.key (0600) + DIR/robot-3.pub
    swarmd keygen --swarm SWARM.yaml DIR    # one pair per robot of the swarm
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _fail(message: str) -> typer.Exit:
    typer.echo(f"swarmd keygen: {message}", err=True)
    return typer.Exit(1)


# Each parameter's declaration (flag, range, help) as a type of its own, so the
# signature of `keygen` fits in two lines.
PathArg = Annotated[
    Path, typer.Argument(help="Key file to create (its directory must exist); "
                         "with --robot or --swarm, the keys directory.")
]
RobotOpt = Annotated[
    int | None, typer.Option("--robot", min=1, max=0xFFFF,
                             help="Make robot ID's key pair in PATH: robot-ID.key "
                             "(private, 0600) and robot-ID.pub.")
]
SwarmOpt = Annotated[
    Path | None, typer.Option("--swarm", help="Make a key pair in PATH for every "
                              "robot of this swarm file (revoked ones skipped).")
]
ForceOpt = Annotated[
    bool, typer.Option("--force", help="Replace existing key files (default: refuse).")
]
HexOpt = Annotated[
    bool, typer.Option("--hex", help="Shared key: write 64 hex digits instead of "
                       "32 raw bytes.")
]


def register(app: typer.Typer) -> None:
    """Add the `keygen` command to the CLI."""
    app.command()(keygen)


def keygen(path: PathArg, robot: RobotOpt = None, swarm: SwarmOpt = None,
           force: ForceOpt = False, hex_format: HexOpt = False) -> None:
    """Generate keys: a shared swarm key, or per-robot Ed25519 key pairs.

    Per-robot (the default for new swarms, `auth: {mode: per-robot}`): each robot's
    robot-N.key goes to that robot only (identity_file in its robot file); every
    robot-N.pub goes to the keys dir beside the swarm file on every robot
    (docs/operations.md, "Keys").

    Shared (`auth: {mode: shared}`): one 32-byte key, the same on every robot.

    A device node, FIFO or directory where a key would go is never replaced, even
    with --force. Exit codes: 0 written, 1 refused (exists without --force, cannot
    be written, bad swarm file).

    Example: swarmd keygen --swarm configs/paper.yaml configs/keys (also:
    swarmd keygen --robot 3 configs/keys; swarmd keygen swarm.key)
    """
    _keygen(path, robot, swarm, force, hex_format)


def _keygen(path: Path, robot: int | None, swarm: Path | None, force: bool,
            hex_format: bool) -> None:
    """`swarmd keygen`: one robot's key pair, a whole swarm's, or a shared key."""
    from swarmd.base.keys import KeyFileError

    if robot is not None and swarm is not None:
        raise _fail("give --robot or --swarm, not both")
    try:
        if robot is not None:
            _one_robot(path, robot, force)
        elif swarm is not None:
            _whole_swarm(path, swarm, force)
        else:
            _shared_key(path, force, hex_format)
    except KeyFileError as exc:
        raise _fail(str(exc)) from None
    except OSError as exc:
        raise _fail(f"cannot write {exc.filename or path}: {exc.strerror}") from None


def _shared_key(path: Path, force: bool, hex_format: bool) -> None:
    from swarmd.base.keys import generate_key

    generate_key(path, force=force, hex_format=hex_format)
    typer.echo(
        f"wrote a new swarm key to {path} (mode 0600). Copy it to every robot of the "
        f"swarm, owned by the daemon's user: install -m 600 -o swarmd {path} "
        "/etc/swarmd/swarm.key"
    )


def _one_robot(directory: Path, robot: int, force: bool) -> None:
    from swarmd.base.identity import write_identity

    key, pub = write_identity(directory, robot, force=force)
    typer.echo(f"wrote {key} (private, mode 0600: robot {robot} only, its identity_file) "
               f"and {pub} (copy it into the keys dir of every robot, then SIGHUP them)")


def _whole_swarm(directory: Path, swarm: Path, force: bool) -> None:
    from swarmd.base.identity import check_writable, write_identity
    from swarmd.config import ConfigError
    from swarmd.config.source import read_source
    from swarmd.config.swarm_rules import inspect_swarm

    try:
        cfg, problems = inspect_swarm(read_source(swarm))
    except ConfigError as exc:
        raise _fail(str(exc)) from None
    if cfg is None:
        raise _fail("\n".join(str(p) for p in problems if p.severity == "error"))
    robots = [r for r in cfg.robot_ids() if r not in cfg.revoked]
    for r in robots:  # all or nothing: no half-made set
        check_writable(directory, r, force=force)
    for r in robots:
        write_identity(directory, r, force=force)
    typer.echo(f"wrote {len(robots)} key pairs to {directory}: robot-N.key (private, "
               "0600) goes to robot N only; every robot-N.pub to every robot")
    keys_dir = cfg.keys_dir_path
    if keys_dir is None or keys_dir.resolve() != directory.resolve():
        typer.echo(f"note: {swarm} does not name {directory} as its keys dir; set "
                   "`auth: {mode: per-robot, keys_dir: ...}` there")
