"""What a swarm file's `auth:` section means on disk (docs/config.md, "auth").

The section's shape (`auth: none`, `{mode: shared, key_file: ...}`, `{mode: per-robot,
keys_dir: ..., revoked: [...]}`) is part of the swarm file's schema in `swarm.py`; here
are the checks that reach past it: the key file loads, the keys dir holds a public key
for every robot not revoked, the revoked robots are in the swarm. `swarmd check` reports
them (`swarm_rules.cross_check`), `swarmd start` refuses a robot whose swarm fails them
(`robot.py`, with `deploying`), and `public_keys` and `retired_keys` read the keys for
the keyring.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from swarmd.base.identity import (
    IdentityFileError,
    public_key_path,
    read_key_file,
    read_public_keys,
)
from swarmd.base.keys import KeyFileError, load_key
from swarmd.config.errors import Loc
from swarmd.config.swarm import NoAuth, PerRobotAuth, SwarmConfig


@dataclass(frozen=True, slots=True)
class AuthIssue:
    loc: Loc
    message: str
    severity: Literal["error", "warning"] = "error"


def keygen_hint(cfg: SwarmConfig, keys_dir: Path) -> str:
    return f"swarmd keygen --swarm {cfg.source} {keys_dir}"


def unsigned_implicit_message(cfg: SwarmConfig) -> str:
    return ("the swarm is unsigned and does not say so: sign it (`auth: {mode: per-robot, "
            f"keys_dir: keys}}`, then swarmd keygen --swarm {cfg.source} KEYS_DIR) or "
            "write `auth: none` to run it unsigned")


def auth_issues(cfg: SwarmConfig, *, deploying: bool = False) -> list[AuthIssue]:
    """What is wrong or doubtful in the auth of a swarm file. `deploying` (a robot file
    names this swarm: `swarmd start`) turns what a plan may lack into errors: a swarm
    unsigned without saying so, a keys dir not made yet."""
    out: list[AuthIssue] = []
    auth = cfg.auth
    if auth is not None and cfg.key_file is not None:
        out.append(AuthIssue(("key_file",), "both `auth` and `key_file` are set: put the key "
                             "under auth (`auth: {mode: shared, key_file: ...}`)"))
        return out
    if auth is None and cfg.key_file is None:
        out.append(AuthIssue(("auth",), unsigned_implicit_message(cfg),
                             "error" if deploying else "warning"))
        return out
    if isinstance(auth, NoAuth):
        return out  # chosen explicitly; `swarmd check` prints what it leaves open
    key_path = cfg.key_path
    if key_path is not None:
        loc: Loc = ("key_file",) if auth is None else ("auth", "key_file")
        try:
            load_key(key_path)
        except KeyFileError as exc:
            out.append(AuthIssue(loc, str(exc)))
    if isinstance(auth, PerRobotAuth):
        out += _per_robot_issues(cfg, auth, deploying=deploying)
    return out


def _per_robot_issues(cfg: SwarmConfig, auth: PerRobotAuth, *,
                      deploying: bool) -> list[AuthIssue]:
    """Revoked robots the swarm does not have; a keys dir or public key missing."""
    out: list[AuthIssue] = []
    ids = set(cfg.robot_ids())
    for i, r in enumerate(auth.revoked):
        if r not in ids:
            out.append(AuthIssue(("auth", "revoked", i), f"robot {r} is not in the "
                                 "swarm", "warning"))
    keys_dir = cfg.keys_dir_path
    assert keys_dir is not None
    if not keys_dir.is_dir():
        # A plan may be checked and simulated (throwaway keys) before its keys are
        # made: `swarmd check` says so in its auth line; a robot cannot start.
        if deploying or keys_dir.exists():
            what = "is not a directory" if keys_dir.exists() else "does not exist"
            out.append(AuthIssue(
                ("auth", "keys_dir"),
                f"keys dir {keys_dir} {what}: make the swarm's keys with "
                f"{keygen_hint(cfg, keys_dir)}"))
        return out
    for r in sorted(ids - set(auth.revoked)):
        try:
            read_public_keys(public_key_path(keys_dir, r))
        except IdentityFileError as exc:
            out.append(AuthIssue(
                ("auth", "keys_dir"),
                f"robot {r}: {exc} (make it: swarmd keygen --robot {r} {keys_dir}, "
                "then copy robot-N.pub to every robot)"))
    for r in sorted(ids & set(auth.revoked)):
        path = public_key_path(keys_dir, r)
        if not path.exists():
            continue  # a revoked robot's key is optional: it only proves history
        try:
            read_key_file(path)
        except IdentityFileError as exc:
            out.append(AuthIssue(("auth", "keys_dir"), f"revoked robot {r}: {exc}"))
    return out


def public_keys(cfg: SwarmConfig) -> dict[int, tuple[bytes, ...]]:
    """Every non-revoked robot's public key(s) from the keys dir. Raises
    IdentityFileError (the first missing or bad file)."""
    keys_dir = cfg.keys_dir_path
    if keys_dir is None:
        return {}
    revoked = cfg.revoked
    return {r: read_public_keys(public_key_path(keys_dir, r))
            for r in cfg.robot_ids() if r not in revoked}


def retired_keys(cfg: SwarmConfig) -> dict[int, tuple[bytes, ...]]:
    """The keys that verify history only (`swarmd.base.identity.Keyring`): the lines a
    rotation retired (`retired <key>`) of every robot, and every key of a revoked robot
    whose public key file is still in the keys dir (DESIGN, "Key changes never rewrite
    history"). Raises IdentityFileError (the first bad file; a missing file of a
    revoked robot is none)."""
    keys_dir = cfg.keys_dir_path
    if keys_dir is None:
        return {}
    out: dict[int, tuple[bytes, ...]] = {}
    for r in cfg.robot_ids():
        path = public_key_path(keys_dir, r)
        if r in cfg.revoked and not path.exists():
            continue
        current, retired = read_key_file(path)
        old = current + retired if r in cfg.revoked else retired
        if old:
            out[r] = old
    return out
