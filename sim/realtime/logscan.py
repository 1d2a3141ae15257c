"""What a robot's log says, for a problem report: each robot process writes the daemon's
JSON log lines (swarmd.base.logs) to `<run>/logs/robotN.log`; a robot that fails to start, dies
or logs errors is reported with the lines that explain it."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path


def _message(line: str) -> str:
    """A JSON log line as 'msg: error'; anything else (a traceback line) as is."""
    try:
        rec = json.loads(line)
        return f"{rec['msg']}" + (f": {rec['error']}" if "error" in rec else "")
    except (ValueError, TypeError, KeyError):
        return line


def log_tail(path: Path, lines: int = 3) -> str:
    """The last `lines` lines of a robot's log, joined by ' | '."""
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return "(no log)"
    return " | ".join(_message(line) for line in text.splitlines()[-lines:]) or "(empty log)"


def log_errors(path: Path, robot: int) -> str:
    """'robot R: N error(s) in its log, first: ...', or '' when the log has no error or
    critical line. A daemon logs an error for what it survives (a link that raised, a
    node bug): the run went on, but a summary must not pass over it."""
    errors = []
    with contextlib.suppress(OSError), path.open(errors="replace") as fh:
        for line in fh:
            if '"level":"error"' in line or '"level":"critical"' in line:
                with contextlib.suppress(ValueError, TypeError, KeyError):
                    rec = json.loads(line)
                    errors.append(f"{rec['msg']}" + (f": {rec['error']}"
                                                      if "error" in rec else ""))
    if not errors:
        return ""
    return f"robot {robot}: {len(errors)} error(s) in its log, first: {errors[0]}"
