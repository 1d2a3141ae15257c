"""`ChannelEvents`: how the radio transports report channel conditions (base.py rules)."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping
from typing import Any

import pytest

from swarmd.transport.base import Channel, ChannelEvents

log = logging.getLogger("swarmd.transport.test")


def test_send_errors_are_counted_and_name_the_transport() -> None:
    counters: Counter[str] = Counter()
    seen: list[tuple[str, Mapping[str, Any]]] = []
    events = ChannelEvents("serial", counters, log)
    events.send_error("radio down")  # before start: counted, not reported
    events.callback = lambda name, fields: seen.append((name, fields))
    events.send_error("oversize", size=90, limit=64)
    events.emit(Channel.UP, {"port": "/dev/ttyX"})
    assert counters == {"send_error:radio down": 1, "send_error:oversize": 1}
    assert seen == [
        ("send_error", {"kind": "serial", "reason": "oversize", "size": 90, "limit": 64}),
        ("transport_up", {"port": "/dev/ttyX"}),
    ]


def test_a_callback_that_raises_is_logged_not_propagated(
        caplog: pytest.LogCaptureFixture) -> None:
    def broken(name: str, fields: Mapping[str, Any]) -> None:
        raise RuntimeError("sink broke")

    events = ChannelEvents("xbee", Counter(), log)
    events.callback = broken
    events.send_error("queue full")
    events.emit(Channel.DOWN, {})
    assert [r.getMessage() for r in caplog.records if r.name == log.name] == [
        "on_event raised", "on_event raised"]
    assert events.counters == {"send_error:queue full": 1}
