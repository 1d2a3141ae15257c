"""A starting robot says whom it waits for, and what to check when they stay silent."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import pytest

from swarmd.config import load_swarm
from swarmd.daemon import waiting
from swarmd.daemon.waiting import Waiting, describe_channel, report_waiting

PLAN = load_swarm(Path(__file__).resolve().parent.parent / "configs" / "paper.yaml").to_plan()


def test_an_active_robot_waits_for_its_neighbours_and_their_standbys() -> None:
    w = Waiting.of(PLAN, 2)  # f2, in the ring 1-2-3-4; 5 covers f1, f4 and 6 covers f2, f3
    assert dict(w.neighbours) == {1: "f1", 3: "f3"}
    assert dict(w.standbys) == {5: ("f1",), 6: ("f2", "f3")}
    assert w.line() == ("waiting for robots 1, 3 (neighbours, holding f1, f3), 5 (standby "
                        "of f1) and 6 (standby of f2, f3)")


def test_a_standby_waits_for_the_holders_near_the_slots_it_covers() -> None:
    w = Waiting.of(PLAN, 5)
    assert set(w.neighbours) == {1, 2, 3, 4} and set(w.standbys) == {6}
    assert 5 not in w.robots


def test_the_missing_line_names_the_silent_robots_and_the_channel() -> None:
    line = Waiting.of(PLAN, 2).missing_line({3}, 2.0, "udp 239.255.77.7:47007 on 127.0.0.1")
    assert line.startswith("never heard robot 3 (neighbour, holding f3) within the start-up "
                           "grace of 2 s: start them")
    assert "(udp 239.255.77.7:47007 on 127.0.0.1)" in line


def test_describe_channel() -> None:
    class Udp:
        kind, group, port, interface = "udp", "239.1.2.3", 5000, "127.0.0.1"

    class Xbee:
        kind, port = "xbee", "/dev/xbee"

    assert describe_channel(Udp()) == "udp 239.1.2.3:5000 on 127.0.0.1"
    assert describe_channel(Xbee()) == "xbee /dev/xbee"


@pytest.fixture(autouse=True)
def _no_pause(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(waiting, "CHECK_PERIOD", 0.0)  # the fake clock moves instead


def _run(heard: list[set[int]], caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    """report_waiting on a fake clock: each check sees the next `heard` set."""
    clock = [0.0]
    steps = iter(heard)

    def now() -> float:
        return clock[0]

    def who() -> set[int]:
        clock[0] += 0.5
        return next(steps, heard[-1])

    with caplog.at_level(logging.INFO, logger="swarmd.waiting"):
        asyncio.run(report_waiting(Waiting.of(PLAN, 2), who, grace=2.0, channel="udp x",
                                   clock=now))
    return [r for r in caplog.records if r.name == "swarmd.waiting"]


def test_all_heard_in_time_is_one_info_line(caplog: pytest.LogCaptureFixture) -> None:
    records = _run([set(), {1, 3}, {1, 3, 5, 6}], caplog)
    assert [r.getMessage() for r in records][1] == "heard every robot it waits for"
    assert all(r.levelno == logging.INFO for r in records)


def test_silence_past_the_grace_is_one_warning(caplog: pytest.LogCaptureFixture) -> None:
    records = _run([set(), {1}, {1, 5}], caplog)
    warnings = [r for r in records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert warnings[0].getMessage().startswith(
        "never heard robots 3 (neighbour, holding f3) and 6 (standby of f2, f3)")
    assert warnings[0].__dict__["never_heard"] == [3, 6]
