"""Log lines: JSON for machines (journald, pipes, tests), text for people on a terminal."""

from __future__ import annotations

import io
import json
import logging
import os
from pathlib import Path

from typer.testing import CliRunner

from swarmd.base.logs import JsonFormatter, TextFormatter, default_format, setup_logging
from swarmd.cli import app

ROOT = Path(__file__).resolve().parent.parent


def _record(msg: str, level: int = logging.INFO, **extra: object) -> logging.LogRecord:
    record = logging.LogRecord("swarmd.daemon", level, __file__, 1, msg, (), None)
    record.__dict__.update(extra)
    record.created = 1_700_000_000.25
    record.msecs = 250.0
    return record


def test_an_event_reads_as_time_robot_event_and_fields() -> None:
    line = TextFormatter(robot=6).format(_record(
        "event takeover", event="takeover",
        fields={"function": "f2", "epoch": 1, "replaced": 2}))
    clock, rest = line.split(" ", 1)
    assert clock.endswith(".250") and clock.count(":") == 2  # local time, milliseconds
    assert rest == "robot 6  takeover  function=f2 epoch=1 replaced=2"


def test_the_level_shows_when_it_is_not_info_and_odd_values_are_quoted() -> None:
    line = TextFormatter().format(_record("alert hook failed", logging.ERROR, status=3,
                                          reason="no standby left", gone=None))
    assert line.split(" ", 1)[1] == \
        'ERROR  alert hook failed  status=3 reason="no standby left" gone=null'


def test_json_lines_keep_their_fields() -> None:
    out = json.loads(JsonFormatter().format(_record("event stopped", event="stopped",
                                                    fields={})))
    assert out["msg"] == "event stopped" and out["event"] == "stopped" and out["ts"] > 0


def test_default_is_text_on_a_terminal_and_json_elsewhere() -> None:
    assert default_format(io.StringIO()) == "json"
    leader, follower = os.openpty()
    try:
        with os.fdopen(follower, "w", closefd=False) as tty:
            assert default_format(tty) == "text"
    finally:
        os.close(leader)
        os.close(follower)


def test_setup_replaces_the_handler_it_made() -> None:
    root = logging.getLogger()
    before = list(root.handlers)
    try:
        setup_logging("info", io.StringIO())
        handler = setup_logging("info", io.StringIO(), fmt="text", robot=3)
        ours = [h for h in root.handlers if h not in before]
        assert ours == [handler] and isinstance(handler.formatter, TextFormatter)
    finally:
        for h in list(root.handlers):
            if h not in before:
                root.removeHandler(h)


def test_start_refuses_an_unknown_log_format() -> None:
    result = CliRunner().invoke(app, ["start", "-c", str(ROOT / "configs" / "robot-example.yaml"),
                                      "--log-format", "xml"])
    assert result.exit_code == 2 and "'xml' is not one of text, json" in result.output
