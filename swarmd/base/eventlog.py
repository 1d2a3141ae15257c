"""The event log file (DESIGN section 3): JSON Lines appended, flushed line by line.

Tests and users parse it while the daemon runs (`tail -f`, the simulator's merger), so
every record is written whole and flushed at once. `reopen()` serves SIGHUP: after
logrotate moved the file, or after the configured path changed.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

# The name an operator filters the JSON logs on ("logger", docs/daemon.md): it names the
# component, not the file, so it stays when the module moves between folders.
log = logging.getLogger("swarmd.eventlog")


class EventLogError(OSError):
    """The event log file cannot be opened; the message names the path and why."""


class EventLog:
    """Append JSON Lines records to a file. Write errors are counted, never raised."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self.errors = 0
        self._fh: IO[str] | None = _open(self.path)

    def write(self, record: Mapping[str, Any]) -> None:
        """Append one record and flush it."""
        if self._fh is None:
            return
        try:
            self._fh.write(json.dumps(record, separators=(",", ":"), default=str) + "\n")
            self._fh.flush()
        except (OSError, ValueError) as exc:
            self.errors += 1
            log.error("event log write failed", extra={"path": str(self.path),
                                                       "error": str(exc)})

    def reopen(self, path: Path | str | None = None) -> None:
        """Open again (same or new path): logrotate and SIGHUP. The new file is opened
        before the old one is closed: if it cannot be (`EventLogError`), records keep
        going to the old one rather than nowhere (nothing lost)."""
        new_path = Path(path) if path is not None else self.path
        fh = _open(new_path)
        self.close()
        self.path, self._fh = new_path, fh

    def close(self) -> None:
        if self._fh is not None:
            try:
                self._fh.close()
            except OSError as exc:
                log.error("event log close failed", extra={"error": str(exc)})
            self._fh = None


def _open(path: Path) -> IO[str]:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Line buffering is not enough for a record split by a full buffer: flush by hand.
        return open(path, "a", encoding="utf-8")  # kept open: the caller closes it
    except OSError as exc:
        raise EventLogError(f"event_log {path}: cannot open for appending: "
                            f"{exc.strerror or exc}") from exc
