"""Reading a small file the user named, without hanging or exhausting memory on the wrong
kind of file.

Config, state and key files are small regular files. Given a FIFO, `open` would block
until a writer comes (forever, under systemd); given `/dev/zero`, a plain read would
fill memory; given a directory, the error would come from deep inside a parser. So the
file is opened with O_NONBLOCK (a FIFO opens at once), its type is checked on the opened
descriptor (fstat: no race with a path swapped in between) and at most `limit` bytes
are read. Bad input gets one clear message (docs/DESIGN.md, "Standards").
"""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

__all__ = ["FileRefused", "file_kind", "output_problem", "read_regular_file"]


class FileRefused(OSError):
    """The path is not a regular file, or is too big; `reason` is a short phrase
    ("is a FIFO, not a regular file") to put after the file name."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def file_kind(mode: int) -> str:
    """What a non-regular file is, in words."""
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def read_regular_file(path: Path | str, limit: int) -> bytes:
    """The bytes of `path`, a regular file of at most `limit` bytes.

    Raises FileNotFoundError / PermissionError / OSError as `open` does, and
    `FileRefused` for a FIFO, device, directory or socket, or a file above `limit`.
    """
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0)
    fd = os.open(path, flags)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FileRefused(f"is {file_kind(st.st_mode)}, not a regular file")
        if st.st_size > limit:
            raise FileRefused(f"is {st.st_size} bytes, above the limit of {limit}")
        chunks: list[bytes] = []
        total = 0
        while True:  # a file that grows while being read is still capped
            chunk = os.read(fd, min(1 << 20, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:
                raise FileRefused(f"is above the limit of {limit} bytes")
        return b"".join(chunks)
    finally:
        os.close(fd)


def output_problem(path: Path | str) -> str | None:
    """Why `path` cannot take an output file (None when it can): an existing path that
    is not a regular file (a FIFO would block the write forever; a device or directory
    is never the file the user meant, also through a symlink), or a parent directory
    that is missing or not writable. Checked before a command does any work."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        return exc.strerror or str(exc)
    if st is not None and not stat.S_ISREG(st.st_mode):
        return f"it is {file_kind(st.st_mode)}, not a regular file"
    parent = path.parent
    if not parent.is_dir():
        return f"directory {parent} does not exist"
    if not os.access(parent if st is None else path, os.W_OK):
        return f"{'directory ' + str(parent) if st is None else 'the file'} is not writable"
    return None


def write_atomic(path: Path, data: bytes, mode: int) -> None:
    """Write to a temporary name created with `mode`, then rename into place: no reader
    sees a partial file (a key, a state file) or a moment of wider permissions."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
    try:
        os.fchmod(fd, mode)  # the umask can only remove bits, but be explicit
        os.write(fd, data)
        os.fsync(fd)
    except BaseException:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    os.close(fd)
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
