"""Swarm keys: generate, load with a permission check, and combine for rotation.

A swarm key is 32 random bytes shared by every robot of a swarm; frames carry an
HMAC-SHA256 tag made with it (DESIGN section 2, `swarmd.core.wire`; MAVLink 2 signing
uses the same size).

File format: either exactly 32 raw bytes (what `generate_key` writes) or 64 hex digits,
optionally surrounded by whitespace (handy when the key travels through a text-only
channel such as a configuration-management variable). The two cannot be confused: a
raw key is 32 bytes long, a hex key at least 64.

Permissions: a key file that the group or others may read or write is refused, with the
reason and the ``chmod`` that fixes it. Anyone who can read the key can forge frames and
take over any function of the swarm; anyone who can write it can cut the robot off.

Rotation: the core signs with ``keys[0]`` and accepts a frame tagged with any key in the
list (`swarmd.core.wire.decode`). `load_keys` builds that list: the signing key first,
then the extra keys accepted during a rotation window. The three-step procedure is in
docs/operations.md ("Rotating the swarm key").
"""

from __future__ import annotations

import binascii
import os
import secrets
import stat
from collections.abc import Callable, Sequence
from pathlib import Path

from swarmd.base.files import file_kind, write_atomic
from swarmd.core.wire import KEY_LEN

__all__ = ["KEY_LEN", "KeyFileError", "generate_key", "load_key", "load_keys", "parse_key"]

_MAX_FILE = 4096  # a key file is 32 or ~65 bytes; anything big is the wrong file


class KeyFileError(ValueError):
    """A key file that cannot be used; the message says why and how to fix it."""


def generate_key(path: Path | str, *, force: bool = False, hex_format: bool = False) -> bytes:
    """Write a new random key to `path` with mode 0600 and return it.

    The file is written to a temporary name created 0600 in the same directory and
    renamed into place, so no reader ever sees a partial key or a moment of wider
    permissions. An existing file is kept unless `force` (overwriting a swarm key cuts
    this robot off from the swarm until every robot has the new one).
    """
    path = Path(path)
    try:
        st = os.stat(path)  # follows a symlink: a link to /dev/null is a device
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise KeyFileError(f"{path}: {exc.strerror}") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        # --force replaces a key, never a device node, FIFO or directory.
        raise KeyFileError(f"{path} is {file_kind(st.st_mode)}, not a regular file; "
                           "refusing to replace it (even with --force)")
    if st is not None and not force:
        raise KeyFileError(f"{path} already exists; pass --force to replace it")
    key = secrets.token_bytes(KEY_LEN)
    data = (key.hex() + "\n").encode() if hex_format else key
    write_atomic(path, data, 0o600)
    return key


def read_private_file(path: Path, *, what: str, missing: str, loose_mode: Callable[[int], str],
                      error: type[KeyFileError] = KeyFileError) -> bytes:
    """The bytes of a key file that must be private to its owner (the shared swarm key,
    a robot's private key). Raises `error` naming the file, the problem and the fix:
    `what` names the file ("key file"), `missing` says how to make one, `loose_mode(mode)`
    says what a mode readable by others risks."""
    try:
        # Check the permissions of the file actually opened (fstat), not of a path
        # that could be swapped between the check and the read.
        # O_NONBLOCK: a FIFO given as key file opens at once (and is refused below)
        # instead of blocking until some writer appears.
        fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist ({missing})") from None
    except PermissionError:
        raise error(
            f"{what} {path} is not readable by this user (uid {os.getuid()}); it must be "
            f"owned by the user the daemon runs as: chown swarmd {path}"
        ) from None
    except OSError as exc:
        raise error(f"{what} {path}: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{what} {path} is {file_kind(st.st_mode)}, not a regular file")
        if stat.S_IMODE(st.st_mode) & 0o077:
            raise error(f"{what} {path} has mode {stat.S_IMODE(st.st_mode):04o}: "
                        f"{loose_mode(st.st_mode)}; fix it with: chmod 600 {path}")
        return os.read(fd, _MAX_FILE + 1)
    finally:
        os.close(fd)


def _swarm_key_risk(mode: int) -> str:
    loose = stat.S_IMODE(mode) & 0o077
    who = [name for bits, name in ((0o070, "its group"), (0o007, "other users")) if loose & bits]
    return (f"{' and '.join(who)} can access it, and anyone who can read the swarm key can "
            "forge frames and take over functions")


def load_key(path: Path | str) -> bytes:
    """Read a key file, refusing one that is not private to its owner.

    Raises `KeyFileError` with a message naming the file, the problem and the fix.
    """
    path = Path(path)
    data = read_private_file(path, what="key file", missing=f"make one: swarmd keygen {path}",
                             loose_mode=_swarm_key_risk)
    return parse_key(data, str(path))

def parse_key(data: bytes, origin: str = "key") -> bytes:
    """A key from file content: 32 raw bytes, or 64 hex digits with optional whitespace."""
    if len(data) == KEY_LEN:
        return data
    if len(data) > _MAX_FILE:
        raise KeyFileError(f"{origin} is {len(data)}+ bytes: not a swarm key file")
    text = data.strip()
    if len(text) == 2 * KEY_LEN:
        try:
            return binascii.unhexlify(text)
        except (binascii.Error, ValueError):
            pass
    raise KeyFileError(
        f"{origin} holds {len(data)} bytes; a swarm key is exactly {KEY_LEN} raw bytes or "
        f"{2 * KEY_LEN} hex digits (make one with: swarmd keygen FILE)"
    )


def load_keys(signing: Path | str | None, extra: Sequence[Path | str] = ()) -> list[bytes]:
    """The key list the core takes: the signing key first, then keys also accepted.

    No signing key and no extra keys means an unsigned swarm (empty list). Extra keys
    without a signing key are refused: the robot would accept signed frames but send
    unsigned ones, which every keyed robot drops. A duplicate key is listed once.
    """
    if signing is None:
        if extra:
            raise KeyFileError(
                "accepted keys are configured but no signing key: set the signing key "
                "too (during a rotation it is the old or the new key, see "
                "docs/operations.md)"
            )
        return []
    keys = [load_key(signing)]
    for path in extra:
        key = load_key(path)
        if key not in keys:
            keys.append(key)
    return keys
