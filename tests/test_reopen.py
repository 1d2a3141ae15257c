"""The shared reopen-with-back-off supervisor (swarmd/transport/reopen.py), on a fake
clock: `sleep` records the wait and returns at once, so no test sleeps."""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from collections.abc import Callable

import pytest

from swarmd.transport.reopen import Reopener


class Device:
    """Opens once `fails` attempts have failed; records the waits asked for."""

    def __init__(self, fails: int) -> None:
        self.fails = fails
        self.attempts = 0
        self.waits: list[float] = []
        self.opened = asyncio.Event()

    async def open(self) -> None:
        self.attempts += 1
        if self.attempts <= self.fails:
            raise OSError(f"no device (attempt {self.attempts})")
        self.opened.set()

    async def sleep(self, seconds: float) -> None:
        self.waits.append(seconds)
        await asyncio.sleep(0)  # yield, as the real sleep does; no time passes


def reopener(dev: Device, counters: Counter[str], *,
             on_success: Callable[[], None] | None = None,
             on_failure: Callable[[Exception], None] | None = None,
             describe: Callable[[Exception], str] = str,
             logger: logging.Logger | None = None) -> Reopener:
    """0.5 s doubling to 10 s: the transports' defaults."""
    return Reopener("radio ttyX", dev.open, counters, minimum=0.5, maximum=10.0,
                    on_success=on_success, on_failure=on_failure, describe=describe,
                    logger=logger or logging.getLogger("swarmd.transport.reopen"),
                    sleep=dev.sleep)


async def settle(cond: Callable[[], bool]) -> None:
    # The fake clock makes the supervisor run through its attempts in loop turns.
    for _ in range(1000):
        if cond():
            return
        await asyncio.sleep(0)
    raise AssertionError("supervisor did not get there")


async def test_backoff_doubles_to_the_cap_and_logs_each_failure(
        caplog: pytest.LogCaptureFixture) -> None:
    dev, counters = Device(fails=7), Counter[str]()
    r = reopener(dev, counters)
    caplog.set_level(logging.INFO, logger="swarmd.transport.reopen")
    r.lost()
    r.start()
    await asyncio.wait_for(dev.opened.wait(), 5.0)
    await r.close()
    assert dev.waits == [0.5, 1.0, 2.0, 4.0, 8.0, 10.0, 10.0]
    assert counters == {"reopen_failed": 7}
    assert caplog.messages[0] == "radio ttyX still down (no device (attempt 1)); retry in 0.5 s"
    assert caplog.messages[-1].endswith("retry in 10.0 s") and len(caplog.messages) == 7


async def test_success_resets_the_backoff_for_the_next_outage() -> None:
    dev, counters = Device(fails=3), Counter[str]()
    successes: list[int] = []
    r = reopener(dev, counters, on_success=lambda: successes.append(dev.attempts))
    r.lost()
    r.start()
    await asyncio.wait_for(dev.opened.wait(), 5.0)
    await settle(lambda: successes == [4])
    assert r.backoff == 0.5 and not r.down
    dev.fails, dev.waits = 6, []  # the next outage: attempts 5 and 6 fail, 7 opens
    r.lost()
    await settle(lambda: len(successes) == 2)
    await r.close()
    assert dev.waits == [0.5, 1.0]
    assert successes == [4, 7]


async def test_nothing_happens_until_a_loss_is_reported() -> None:
    dev, counters = Device(fails=0), Counter[str]()
    r = reopener(dev, counters)
    r.start()
    for _ in range(20):
        await asyncio.sleep(0)
    assert dev.attempts == 0
    r.lost()
    r.lost()  # repeated reports of one outage: one attempt
    await asyncio.wait_for(dev.opened.wait(), 5.0)
    for _ in range(20):
        await asyncio.sleep(0)
    await r.close()
    assert dev.attempts == 1 and dev.waits == []


async def test_a_loss_during_the_attempt_is_not_forgotten() -> None:
    counters: Counter[str] = Counter()
    attempts: list[int] = []
    holder: list[Reopener] = []

    async def open_then_vanish() -> None:
        attempts.append(len(attempts) + 1)
        if len(attempts) == 1:
            holder[0].lost()  # the device goes away again while we are opening it

    r = Reopener("radio ttyX", open_then_vanish, counters, minimum=0.5, maximum=1.0)
    holder.append(r)
    r.lost()
    r.start()
    await settle(lambda: len(attempts) == 2)
    await r.close()
    assert counters["reopen_failed"] == 0


async def test_failure_hook_sees_the_exception_and_describe_words_it(
        caplog: pytest.LogCaptureFixture) -> None:
    dev, counters = Device(fails=1), Counter[str]()
    seen: list[Exception] = []
    log = logging.getLogger("swarmd.transport.test")
    r = reopener(dev, counters, on_failure=seen.append, logger=log,
                 describe=lambda exc: f"{type(exc).__name__}!")
    caplog.set_level(logging.INFO, logger="swarmd.transport.test")
    r.lost()
    r.start()
    await asyncio.wait_for(dev.opened.wait(), 5.0)
    await r.close()
    assert [str(e) for e in seen] == ["no device (attempt 1)"]
    assert [(rec.name, rec.getMessage()) for rec in caplog.records] == [
        ("swarmd.transport.test", "radio ttyX still down (OSError!); retry in 0.5 s")]


async def test_close_cancels_a_wait_in_progress() -> None:
    counters: Counter[str] = Counter()
    dev = Device(fails=10**6)
    r = Reopener("radio ttyX", dev.open, counters, minimum=60.0, maximum=60.0)
    r.lost()
    r.start()
    await settle(lambda: counters["reopen_failed"] == 1)
    await asyncio.wait_for(r.close(), 1.0)  # a real 60 s sleep, cancelled
    assert dev.attempts == 1


@pytest.mark.parametrize(("minimum", "maximum"), [(0.0, 1.0), (2.0, 1.0), (-1.0, 1.0)])
def test_bad_bounds_are_refused(minimum: float, maximum: float) -> None:
    with pytest.raises(ValueError, match="minimum"):
        Reopener("x", Device(0).open, Counter(), minimum=minimum, maximum=maximum)
