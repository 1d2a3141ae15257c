"""Daemon logging on stdout: JSON lines for machines, readable lines for people.

journald stores each stdout line as one message, and tools (`journalctl -o cat | jq`)
can parse it when every line is a JSON object. Records carry `ts` (Unix time), `level`,
`msg`, `logger`, and any `extra={...}` fields given to the logging call.

On a terminal the same records read as text (`TextFormatter`): local time, the robot,
the message or event, then its fields as `key=value`. `swarmd start --log-format`
chooses; by default text when stdout is a terminal, JSON when it is not (systemd, a
pipe, a test), so nothing that parses the lines sees a change.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from typing import Any, Literal, TextIO

from swarmd.core.events import NAME_KEY

LogFormat = Literal["text", "json"]
FORMATS: tuple[LogFormat, ...] = ("text", "json")

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


def _value(value: Any) -> str:
    """A field's value as one short token: bare when it has no blank, else JSON."""
    if isinstance(value, str) and value and not any(c.isspace() or c in "\"=" for c in value):
        return value
    if value is None or isinstance(value, (bool, int, float)):
        return json.dumps(value)
    return json.dumps(value, default=str, separators=(",", ":"))


class TextFormatter(logging.Formatter):
    """Format a record as one line for people: `14:03:21.512 robot 2  takeover
    function=f2 epoch=1 replaced=2`. The level shows when it is not INFO; an event's
    fields (the daemon logs them under `fields`) are spelled out like the others."""

    def __init__(self, robot: int | None = None) -> None:
        super().__init__()
        self.robot = robot

    def format(self, record: logging.LogRecord) -> str:
        clock = time.strftime("%H:%M:%S", time.localtime(record.created))
        head = f"{clock}.{int(record.msecs):03d}"
        if self.robot is not None:
            head += f" robot {self.robot}"
        if record.levelno != logging.INFO:
            head += f" {record.levelname}"
        extra = {k: v for k, v in vars(record).items()
                 if k not in _STANDARD and not k.startswith("_")}
        fields = extra.pop("fields", None)
        event = extra.pop(NAME_KEY, None)
        text = f"{head}  {event if event is not None else record.getMessage()}"
        if isinstance(fields, dict):
            extra = {**fields, **extra}
        parts = [f"{k}={_value(v)}" for k, v in extra.items()]
        if parts:
            text += "  " + " ".join(parts)
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        return text


def default_format(stream: TextIO | None = None) -> LogFormat:
    """Text on a terminal, JSON otherwise (journald, pipes, tests)."""
    out = stream if stream is not None else sys.stdout
    try:
        return "text" if out.isatty() else "json"
    except (AttributeError, ValueError):  # a closed or odd stream: the machine's choice
        return "json"


def setup_logging(level: str | int = "INFO", stream: TextIO | None = None, *,
                  fmt: LogFormat = "json", robot: int | None = None) -> logging.Handler:
    """Route the root logger to `stream` (stdout) as JSON lines, or as text lines
    (`fmt="text"`, naming `robot` on each); returns the handler. Calling it again
    replaces the previous handler (SIGHUP reload of the level; the robot id once the
    config is read)."""
    root = logging.getLogger()
    for h in list(root.handlers):
        if isinstance(h.formatter, (JsonFormatter, TextFormatter)):
            root.removeHandler(h)
    handler = logging.StreamHandler(stream if stream is not None else sys.stdout)
    handler.setFormatter(TextFormatter(robot) if fmt == "text" else JsonFormatter())
    root.addHandler(handler)
    root.setLevel(level.upper() if isinstance(level, str) else level)
    return handler
