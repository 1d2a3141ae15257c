"""Per-robot identities: Ed25519 key pairs, their files, and the keyring of a swarm.

Each robot signs the frames that change state with its own private key; every robot
holds the swarm's public keys and checks that a frame said to come from robot N was
signed by N (DESIGN section 2). The sans-IO core sees only `swarmd.core.auth`'s
`Signer` / `Verifier`; this module implements them with `cryptography`'s Ed25519
(PyCA: maintained, wheels for every platform swarmd runs on, OpenSSL underneath).

Files (written by `swarmd keygen --robot N DIR` / `--swarm SWARM.yaml DIR`):

- ``robot-N.key``: the private key, 64 hex digits and a newline (32 raw bytes are
  accepted too), mode 0600, owned by the daemon's user. Refused if the group or others
  may access it, as the swarm key is (`swarmd.base.keys`).
- ``robot-N.pub``: the public key, 64 hex digits a line. More than one line means every
  key listed is accepted for robot N: the window of a key rotation
  (docs/operations.md, "Rotating a robot's key"). A line ``retired <key>`` is a key the
  rotation replaced: it verifies only history, the warnings and LEAVEs that back a
  takeover accepted while it was in force (`swarmd.core.auth.Verifier`), never a frame
  robot N sends now. ``#`` starts a comment.

The keyring is mutable in place (`Keyring.replace`), so a daemon reloads public keys
and the revoked list on SIGHUP without rebuilding its node; `Ed25519Signer.replace`
does the same for the robot's own key.
"""

from __future__ import annotations

import binascii
import os
import stat
from collections.abc import Iterable, Mapping
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)
from cryptography.hazmat.primitives.serialization import (
    Encoding,
    NoEncryption,
    PrivateFormat,
    PublicFormat,
)

from swarmd.base.files import FileRefused, file_kind, read_regular_file, write_atomic
from swarmd.base.keys import KeyFileError, read_private_file
from swarmd.base.verify_budget import VerifyBudget
from swarmd.core.auth import PUBLIC_KEY_LEN, SIGNATURE_LEN, Identity

__all__ = [
    "PRIVATE_KEY_LEN",
    "Ed25519Signer",
    "IdentityFileError",
    "Keyring",
    "check_writable",
    "generate_identity",
    "private_key_path",
    "public_key_of",
    "public_key_path",
    "read_key_file",
    "read_private_key",
    "read_public_keys",
    "throwaway_identities",
    "write_identity",
]

PRIVATE_KEY_LEN = 32
"""An Ed25519 private key (its seed), as `cryptography` takes it raw."""
_MAX_FILE = 4096  # a key file holds one key (a .pub a few): anything bigger is wrong


class IdentityFileError(KeyFileError):
    """A key file that cannot be used; the message names the file, why and the fix."""


def private_key_path(directory: Path | str, robot: int) -> Path:
    return Path(directory) / f"robot-{robot}.key"


def public_key_path(directory: Path | str, robot: int) -> Path:
    return Path(directory) / f"robot-{robot}.pub"


# -- keys in memory -------------------------------------------------------------------------


def generate_identity() -> tuple[bytes, bytes]:
    """A new key pair: (private 32 B, public 32 B)."""
    key = Ed25519PrivateKey.generate()
    private = key.private_bytes(Encoding.Raw, PrivateFormat.Raw, NoEncryption())
    return private, _public_bytes(key.public_key())


def public_key_of(private_key: bytes) -> bytes:
    """The public key that goes with a private key (32 B each)."""
    return _public_bytes(_private(private_key).public_key())


def _public_bytes(key: Ed25519PublicKey) -> bytes:
    return key.public_bytes(Encoding.Raw, PublicFormat.Raw)


def _private(private_key: bytes) -> Ed25519PrivateKey:
    if len(private_key) != PRIVATE_KEY_LEN:
        raise ValueError(f"an Ed25519 private key is {PRIVATE_KEY_LEN} bytes, "
                         f"got {len(private_key)}")
    return Ed25519PrivateKey.from_private_bytes(private_key)


class Ed25519Signer:
    """`swarmd.core.auth.Signer`: signs with one robot's private key."""

    def __init__(self, robot: int, private_key: bytes) -> None:
        self.robot = robot
        self._key = _private(private_key)
        self.public_key = _public_bytes(self._key.public_key())

    def replace(self, private_key: bytes) -> None:
        """Sign with a new key from now on (the robot's own key rotated, SIGHUP)."""
        key = _private(private_key)
        self._key = key
        self.public_key = _public_bytes(key.public_key())

    def sign(self, data: bytes) -> bytes:
        return self._key.sign(data)


PublicKeys = Mapping[int, bytes | Iterable[bytes]]
"""robot -> its public key, or several (all accepted: a rotation window)."""


class Keyring:
    """`swarmd.core.auth.Verifier`: every robot's public key(s), minus the revoked.

    Keys no longer in force — every key of a revoked robot, a key a rotation retired
    (`retired`) — verify history only (`verify(..., history=True)`: a certificate's
    warnings and LEAVEs), so that a takeover accepted before a key changed keeps its
    proof (DESIGN, "Key changes never rewrite history").

    `verify` never raises: an unknown or revoked robot, a signature of the wrong
    length, a bad signature all give False (the core counts the drop).
    """

    def __init__(self, public_keys: PublicKeys, revoked: Iterable[int] = (),
                 budget: VerifyBudget | None = None, *,
                 retired: PublicKeys | None = None) -> None:
        self._keys: dict[int, tuple[Ed25519PublicKey, ...]] = {}
        self._retired: dict[int, tuple[Ed25519PublicKey, ...]] = {}
        self._revoked: frozenset[int] = frozenset()
        self.budget = budget
        """The daemon's: how many signatures it checks a second (`verify_budget`)."""
        self.replace(public_keys, revoked, retired=retired)

    def replace(self, public_keys: PublicKeys, revoked: Iterable[int] = (), *,
                retired: PublicKeys | None = None) -> None:
        """Swap in a new set of keys, revocations and retired keys (SIGHUP). Raises
        ValueError on a malformed key, leaving the old set in place."""
        keys = _parse_keys(public_keys)
        old = _parse_keys(retired or {})
        self._keys, self._retired = keys, old
        self._revoked = frozenset(revoked)

    @property
    def robots(self) -> frozenset[int]:
        """Robots whose signatures are accepted (known and not revoked)."""
        return frozenset(self._keys) - self._revoked

    @property
    def revoked(self) -> frozenset[int]:
        return self._revoked

    def public_keys(self, robot: int) -> tuple[bytes, ...]:
        """The raw public keys accepted for `robot` (empty when unknown or revoked)."""
        if robot in self._revoked:
            return ()
        return tuple(_public_bytes(k) for k in self._keys.get(robot, ()))

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        keys = self._keys.get(robot, ()) if history or robot not in self._revoked else ()
        if history:
            keys += self._retired.get(robot, ())
        if not keys or len(signature) != SIGNATURE_LEN:
            return False
        if self.budget is not None and not self.budget.take(robot):
            return False  # a flood of signed frames: not checked, so not believed
        for key in keys:
            try:
                key.verify(bytes(signature), bytes(data))
            except InvalidSignature:
                continue
            except Exception:  # never raise into the core (TypeError on odd input)
                return False
            return True
        return False


def _parse_keys(public_keys: PublicKeys) -> dict[int, tuple[Ed25519PublicKey, ...]]:
    """robot -> its keys, parsed. Raises ValueError naming the robot of a malformed
    one."""
    keys: dict[int, tuple[Ed25519PublicKey, ...]] = {}
    for robot, value in public_keys.items():
        raw = (value,) if isinstance(value, bytes | bytearray) else tuple(value)
        parsed = []
        for k in raw:
            if len(k) != PUBLIC_KEY_LEN:
                raise ValueError(f"robot {robot}: an Ed25519 public key is "
                                 f"{PUBLIC_KEY_LEN} bytes, got {len(k)}")
            parsed.append(Ed25519PublicKey.from_public_bytes(bytes(k)))
        keys[robot] = tuple(parsed)
    return keys


def throwaway_identities(robot_ids: Iterable[int]) -> dict[int, Identity]:
    """A fresh key pair per robot and one shared keyring: `swarmd sim` and tests."""
    ids = list(robot_ids)
    pairs = {r: generate_identity() for r in ids}
    keyring = Keyring({r: pub for r, (_, pub) in pairs.items()})
    return {r: Identity(Ed25519Signer(r, priv), keyring) for r, (priv, _) in pairs.items()}


# -- key files ------------------------------------------------------------------------------


def _parse_hex_key(line: bytes, origin: str, what: str) -> bytes:
    try:
        key = binascii.unhexlify(line)
    except (binascii.Error, ValueError):
        key = b""
    if len(key) != PUBLIC_KEY_LEN:
        raise IdentityFileError(
            f"{origin} is not a {what}: expected {2 * PUBLIC_KEY_LEN} hex digits a line "
            "(make one with: swarmd keygen --robot ID DIR)")
    return key


def read_private_key(path: Path | str) -> bytes:
    """A robot's private key from its file, refusing one not private to its owner.

    Raises `IdentityFileError` naming the file, the problem and the fix."""
    path = Path(path)
    data = read_private_file(
        path, what="private key", error=IdentityFileError,
        missing=f"make it: swarmd keygen --robot ID {path.parent}",
        loose_mode=lambda _: "other users can access it, and whoever reads it can sign "
                             "frames as this robot")
    if len(data) == PRIVATE_KEY_LEN:
        return data
    text = data.strip()
    if len(text) == 2 * PRIVATE_KEY_LEN:
        try:
            return binascii.unhexlify(text)
        except (binascii.Error, ValueError):
            pass
    raise IdentityFileError(
        f"private key {path} holds {len(data)} bytes; a robot's private key is "
        f"{2 * PRIVATE_KEY_LEN} hex digits (make one with: swarmd keygen --robot ID DIR)")


_RETIRED = b"retired"
"""The word that starts a key line a rotation retired (module doc)."""


def read_public_keys(path: Path | str) -> tuple[bytes, ...]:
    """The public key(s) in force in a ``robot-N.pub`` file: one per line, at least
    one (`retired` lines are not: `read_key_file`).

    Raises `IdentityFileError` naming the file."""
    keys, _ = read_key_file(path)
    if not keys:
        raise IdentityFileError(f"public key {path} lists no key in force, only retired "
                                "ones (make one with: swarmd keygen --robot ID DIR)")
    return keys


def read_key_file(path: Path | str) -> tuple[tuple[bytes, ...], tuple[bytes, ...]]:
    """(keys in force, retired keys) of a ``robot-N.pub`` file (module doc), at least
    one key in all.

    Raises `IdentityFileError` naming the file."""
    path = Path(path)
    try:
        data = read_regular_file(path, _MAX_FILE)
    except FileNotFoundError:
        raise IdentityFileError(f"public key {path} does not exist") from None
    except FileRefused as exc:
        raise IdentityFileError(f"public key {path} {exc.reason}") from None
    except OSError as exc:
        raise IdentityFileError(f"public key {path}: {exc.strerror or exc}") from None
    keys: list[bytes] = []
    retired: list[bytes] = []
    for line in data.splitlines():
        line = line.split(b"#", 1)[0].strip()
        if not line:
            continue
        word, *rest = line.split(None, 1)
        into = retired if word == _RETIRED and rest else keys
        key = _parse_hex_key(rest[0] if into is retired else line, f"public key {path}",
                             "public key file")
        if key not in into:
            into.append(key)
    if not keys and not retired:
        raise IdentityFileError(f"public key {path} is empty (make it: swarmd keygen "
                                "--robot ID DIR)")
    return tuple(keys), tuple(k for k in retired if k not in keys)


def _refuse_non_regular(path: Path) -> bool:
    """True if `path` exists (a regular file); raises for anything else there."""
    try:
        st = os.stat(path)  # follows a symlink: a link to /dev/null is a device
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise IdentityFileError(f"{path}: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        # --force replaces a key, never a device node, FIFO or directory.
        raise IdentityFileError(f"{path} is {file_kind(st.st_mode)}, not a regular file; "
                                "refusing to replace it (even with --force)")
    return True


def check_writable(directory: Path | str, robot: int, *, force: bool = False) -> None:
    """Raise IdentityFileError if `write_identity` would refuse (a whole swarm's set
    is checked before any file is written)."""
    if not 1 <= robot <= 0xFFFF:
        raise IdentityFileError(f"robot id {robot} is outside 1..65535")
    paths = (private_key_path(directory, robot), public_key_path(directory, robot))
    exists = [p for p in paths if _refuse_non_regular(p)]
    if exists and not force:
        raise IdentityFileError(f"{exists[0]} already exists; pass --force to replace it")


def write_identity(directory: Path | str, robot: int, *, force: bool = False,
                   ) -> tuple[Path, Path]:
    """Make robot `robot`'s key pair in `directory` (created 0755 if missing):
    ``robot-N.key`` (0600) and ``robot-N.pub`` (0644). Returns their paths.

    Nothing is written unless both can be: an existing key is kept unless `force`, and
    a non-regular file in the way (FIFO, device, directory) is refused even with it."""
    check_writable(directory, robot, force=force)
    directory = Path(directory)
    key_path = private_key_path(directory, robot)
    pub_path = public_key_path(directory, robot)
    try:
        directory.mkdir(mode=0o755, parents=True, exist_ok=True)
    except FileExistsError:
        raise IdentityFileError(f"{directory} exists and is not a directory") from None
    private, public = generate_identity()
    write_atomic(key_path, (private.hex() + "\n").encode(), 0o600)
    write_atomic(pub_path, (public.hex() + "\n").encode(), 0o644)
    return key_path, pub_path
