"""The swarm file's `auth:` section: how frames are signed (docs/config.md, "auth").

    auth: none                                        # unsigned, said explicitly
    auth: {mode: shared, key_file: swarm.key}         # one HMAC key for the whole swarm
    auth: {mode: per-robot, keys_dir: keys, revoked: [3]}   # Ed25519, one key per robot

A top-level `key_file:` (no `auth:`) is the shared mode. A swarm file with neither is
unsigned without saying so: `swarmd check` warns, `swarmd start` refuses it.

Per-robot mode: `keys_dir` (relative to the swarm file) holds `robot-<id>.pub` for every
robot of the swarm not in `revoked`; each robot file's `identity_file` names that robot's
private key (`swarmd.identity` has the file formats).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, StrictInt

from swarmd.config.errors import Loc
from swarmd.identity import IdentityFileError, public_key_path, read_public_keys
from swarmd.keys import KeyFileError, load_key

if TYPE_CHECKING:
    from swarmd.config.swarm import SwarmConfig

AuthMode = Literal["none", "shared", "per-robot"]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class NoAuth(_Model):
    """Unsigned frames: anyone who can send on the channel speaks for any robot."""

    mode: Literal["none"]


class SharedAuth(_Model):
    """One 32-byte HMAC key for the whole swarm: the weaker choice for tiny radios
    (every robot holding it can sign as any other; docs/DESIGN.md section 2)."""

    mode: Literal["shared"]
    key_file: str = Field(min_length=1)


class PerRobotAuth(_Model):
    """Each robot signs with its own Ed25519 key; the keys dir holds the public keys."""

    mode: Literal["per-robot"]
    keys_dir: str = Field(default="keys", min_length=1)
    revoked: list[StrictInt] = Field(default_factory=list)
    """Robots whose signatures nobody accepts any more (a lost or compromised robot)."""
    key_file: str | None = None
    """Optionally also a swarm key, given to the core with the identities."""


def _shorthand(value: Any) -> Any:
    # `auth: none` is the one-word form of `auth: {mode: none}`.
    if value == "none":
        return {"mode": "none"}
    if isinstance(value, str):
        raise ValueError(f"must be `none` or a mapping with `mode: shared` or "
                         f"`mode: per-robot`, got {value!r}")
    return value


AuthSpec = Annotated[
    Annotated[NoAuth | SharedAuth | PerRobotAuth, Field(discriminator="mode")],
    BeforeValidator(_shorthand),
]


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
