"""Daemon logging: one JSON object a line on stdout (journald-friendly).

journald stores each stdout line as one message, and tools (`journalctl -o cat | jq`)
can parse it when every line is a JSON object. Records carry `ts` (Unix time), `level`,
`msg`, `logger`, and any `extra={...}` fields given to the logging call.
"""

from __future__ import annotations

import json
import logging
import sys
from typing import Any, TextIO

# Attributes every LogRecord has; anything else came from `extra=` and is emitted.
_STANDARD = frozenset(vars(logging.LogRecord("", 0, "", 0, "", (), None)).keys()) | {
    "message", "asctime", "taskName",
}


class JsonFormatter(logging.Formatter):
    """Format a record as one JSON object (no newlines inside)."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "ts": round(record.created, 6),
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for key, value in vars(record).items():
            if key not in _STANDARD and not key.startswith("_"):
                out[key] = value
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        return json.dumps(out, default=str, separators=(",", ":"))


def setup_logging(level: str | int = "INFO", stream: TextIO | None = None) -> logging.Handler:
    """Route the root logger to `stream` (stdout) as JSON lines; returns the handler.
    Calling it again replaces the previous JSON handler (SIGHUP reload of the level)."""
    root = logging.getLogger()
    for h in list(root.handlers):
        if isinstance(h.formatter, JsonFormatter):
            root.removeHandler(h)
    handler = logging.StreamHandler(stream if stream is not None else sys.stdout)
    handler.setFormatter(JsonFormatter())
    root.addHandler(handler)
    root.setLevel(level.upper() if isinstance(level, str) else level)
    return handler
