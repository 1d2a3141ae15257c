"""Swarm key files: 32 bytes that sign every frame (DESIGN.md section 2, MAVLink-2 style).

A key file holds the key either as 32 raw bytes or as 64 hexadecimal characters (an
optional trailing newline allowed), so a key can be made with `head -c32 /dev/urandom`
or copied as text. Anything else is refused: a wrong key silently splits the swarm.
"""

from __future__ import annotations

import string
from pathlib import Path

KEY_LEN = 32


class KeyFileError(ValueError):
    """A key file that is missing, unreadable or not a 32-byte key."""


def read_key(path: Path) -> bytes:
    """The 32-byte key in `path` (raw or hex). Raises KeyFileError with the reason."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise KeyFileError(f"cannot read key file {path}: {exc.strerror or exc}") from exc
    if len(raw) == KEY_LEN:
        return raw
    text = raw.strip()
    if len(text) == 2 * KEY_LEN and all(chr(c) in string.hexdigits for c in text):
        return bytes.fromhex(text.decode("ascii"))
    raise KeyFileError(
        f"key file {path} holds {len(raw)} bytes; expected {KEY_LEN} raw bytes or "
        f"{2 * KEY_LEN} hex characters"
    )
