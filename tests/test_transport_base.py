"""`ChannelEvents`: how the radio transports report channel conditions (base.py rules)."""

from __future__ import annotations

import errno
import logging
from collections import Counter

import pytest

from swarmd.transport.base import (
    Channel,
    ChannelDown,
    ChannelError,
    ChannelEvent,
    ChannelEvents,
    SendError,
    SendFailure,
    describe,
    failure_of,
)
from swarmd.transport.serial import SerialUp

log = logging.getLogger("swarmd.transport.test")


def test_send_errors_are_counted_and_name_the_transport() -> None:
    counters: Counter[str] = Counter()
    seen: list[ChannelEvent] = []
    events = ChannelEvents("serial", counters, log)
    events.send_error(SendFailure.DOWN, "radio down")  # before start: counted, not reported
    events.callback = seen.append
    events.send_error(SendFailure.OVERSIZE, "oversize", size=90, limit=64)
    events.emit(SerialUp("/dev/ttyX", 57600, 64))
    assert counters == {"send_error:down": 1, "send_error:oversize": 1}
    assert seen == [SendError("serial", SendFailure.OVERSIZE, "oversize", size=90, limit=64),
                    SerialUp("/dev/ttyX", 57600, 64)]
    assert [e.condition for e in seen] == [Channel.SEND_ERROR, Channel.UP]


def test_each_event_is_logged_with_its_kind_and_the_fields_it_has() -> None:
    # What the daemon's log shows (`channel: send_error`, its fields): kind first.
    assert describe(SendError("serial", SendFailure.OVERSIZE, "oversize", size=90,
                              limit=64)) == {"kind": "serial", "reason": "oversize",
                                             "detail": "oversize", "size": 90, "limit": 64}
    assert describe(SerialUp("/dev/ttyX", 57600, 64)) == {
        "kind": "serial", "port": "/dev/ttyX", "baud": 57600, "max_payload": 64}
    assert describe(ChannelDown("xbee", "/dev/xbee", "port closed")) == {
        "kind": "xbee", "port": "/dev/xbee", "reason": "port closed"}
    assert describe(ChannelError("udp", "Connection refused", "receive")) == {
        "kind": "udp", "reason": "Connection refused", "where": "receive"}


@pytest.mark.parametrize(("exc", "failure"), [
    (BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable"), SendFailure.NO_BUFFER),
    (OSError(errno.ENOBUFS, "No buffer space available"), SendFailure.NO_BUFFER),
    (OSError(errno.ENETUNREACH, "Network is unreachable"), SendFailure.UNREACHABLE),
    (OSError(errno.EHOSTUNREACH, "No route to host"), SendFailure.UNREACHABLE),
    (PermissionError(errno.EPERM, "Operation not permitted"), SendFailure.PERMISSION),
    (OSError(errno.EMSGSIZE, "Message too long"), SendFailure.OVERSIZE),
    (OSError(errno.ENETDOWN, "Network is down"), SendFailure.DOWN),
    (TimeoutError("write timeout"), SendFailure.TIMEOUT),
    (OSError(errno.EIO, "Input/output error"), SendFailure.OSERROR),
    (OSError("no errno at all"), SendFailure.OSERROR),
    (ValueError("not an OS error"), SendFailure.OSERROR),
])
def test_a_write_error_falls_in_one_of_a_few_classes(exc: BaseException,
                                                     failure: SendFailure) -> None:
    # Counters are keyed by the class, never by the error's words: a bounded set.
    assert failure_of(exc) is failure


def test_a_callback_that_raises_is_logged_not_propagated(
        caplog: pytest.LogCaptureFixture) -> None:
    def broken(event: ChannelEvent) -> None:
        raise RuntimeError("sink broke")

    events = ChannelEvents("xbee", Counter(), log)
    events.callback = broken
    events.send_error(SendFailure.NO_BUFFER, "queue full")
    events.emit(ChannelDown("xbee", "/dev/xbee", "port closed"))
    assert [r.getMessage() for r in caplog.records if r.name == log.name] == [
        "on_event raised", "on_event raised"]
    assert events.counters == {"send_error:no_buffer": 1}
