"""The real-time control pipe's one codec (sim/realtime/control.py): every message
survives a round trip, and bytes that are no message of a direction are refused with
`ControlError`, never another exception."""

from __future__ import annotations

import pytest

from sim.realtime.control import (
    Act,
    ControlError,
    Drops,
    Failed,
    Forge,
    Go,
    Late,
    Logged,
    Ready,
    Stats,
    decode_command,
    decode_report,
    encode,
)
from sim.shared.faults import FaultKind


@pytest.mark.parametrize("cmd", [Go(1700000000.25), Act(FaultKind.LEAVE), Act(FaultKind.MOTOR),
                                 Forge("replay")])
def test_commands_round_trip(cmd: Go | Act | Forge) -> None:
    assert decode_command(encode(cmd)) == cmd


@pytest.mark.parametrize("report", [
    Ready(4242), Failed("OSError: no such port"), Drops({"auth": 3, "queue_overflow": 1}),
    Late(10, [(1.5, 2.0), (2.25, 40.5)]), Stats(10, 2, 1, 0),
    Logged({"t": 1.0, "robot": 2, "event": "claim", "subject": 1, "function": "f1",
            "epoch": 1}),
])
def test_reports_round_trip(report: object) -> None:
    assert decode_report(encode(report)) == report  # type: ignore[arg-type]


def test_an_event_record_is_written_as_the_daemon_wrote_it() -> None:
    rec = {"t": 1.0, "robot": 2, "event": "stopped"}
    assert encode(Logged(rec)) == b'{"t":1.0,"robot":2,"event":"stopped"}'


@pytest.mark.parametrize("data", [b"", b"\xff", b"[1]", b'{"cmd":"explode"}',
                                  b'{"cmd":"go"}', b'{"cmd":"go","t0":"soon"}', b"{}"])
def test_bad_commands_are_refused(data: bytes) -> None:
    with pytest.raises(ControlError):
        decode_command(data)


@pytest.mark.parametrize("data", [b"nope", b'"x"', b'{"_ctl":"drops","d":[1]}',
                                  b'{"_ctl":"late","n":1,"s":[[1]]}', b'{"_ctl":"ready"}',
                                  b'{"_ctl":"what"}'])
def test_bad_reports_are_refused(data: bytes) -> None:
    with pytest.raises(ControlError):
        decode_report(data)
