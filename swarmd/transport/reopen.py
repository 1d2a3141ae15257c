"""Reopen a lost radio with exponential back-off (serial.py and xbee.py share it).

A radio on USB is pulled, browns out, or stops answering; the daemon must keep running
and pick it up again when it is back (base.py: bad I/O never takes the daemon down).
The transport says *when* it lost the device (`lost()`); this supervisor says *how* it
comes back: one background task that waits for a loss, calls the transport's `open`,
and on failure counts `reopen_failed`, logs "<label> still down (<why>); retry in N s"
and sleeps, doubling the wait from `minimum` up to `maximum`. A success resets the wait
to `minimum`, so the next outage starts fast again.

The loss flag is cleared *before* each attempt, not after it: a loss reported while
the open is still running (the device vanishing again at once) is kept and leads to
another attempt, never to a supervisor waiting on a device that is already gone.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import Counter
from collections.abc import Awaitable, Callable

log = logging.getLogger(__name__)

Sleep = Callable[[float], Awaitable[object]]


class Reopener:
    """Background reopen-with-back-off for one device (see the module docstring).

    `open_device` raises on failure; `describe(exc)` turns that into the log text;
    `on_failure(exc)` runs after each failed attempt (before the wait), `on_success()`
    after each successful one. `sleep` is `asyncio.sleep` except in tests (a fake
    clock). `logger` is the transport's, so the lines keep their logger name.
    """

    def __init__(
        self,
        label: str,
        open_device: Callable[[], Awaitable[None]],
        counters: Counter[str],
        *,
        minimum: float,
        maximum: float,
        describe: Callable[[Exception], str] = str,
        on_failure: Callable[[Exception], None] | None = None,
        on_success: Callable[[], None] | None = None,
        logger: logging.Logger = log,
        sleep: Sleep = asyncio.sleep,
    ) -> None:
        if not 0 < minimum <= maximum:
            raise ValueError(f"reopen back-off needs 0 < minimum <= maximum, "
                             f"got {minimum}, {maximum}")
        self.label = label
        self._open = open_device
        self.counters = counters
        self.minimum = minimum
        self.maximum = maximum
        self.describe = describe
        self.on_failure = on_failure
        self.on_success = on_success
        self.logger = logger
        self._sleep = sleep
        self.backoff = minimum
        """s. The wait after the next failed attempt."""
        self._down = asyncio.Event()
        self._task: asyncio.Task[None] | None = None

    @property
    def down(self) -> bool:
        """A loss was reported and no attempt has started since."""
        return self._down.is_set()

    def lost(self) -> None:
        """The device is gone (or never opened): reopen it. Safe to call repeatedly."""
        self._down.set()

    def start(self) -> None:
        """Start the supervising task on the running loop."""
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(
                self.run(), name=f"reopen {self.label}")

    async def close(self) -> None:
        """Stop supervising (an attempt in progress is cancelled)."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def run(self) -> None:
        """The supervisor loop; `start` runs it as a task, tests may await it."""
        while True:
            await self._down.wait()
            self._down.clear()
            try:
                await self._open()
            except Exception as exc:
                self._down.set()  # still down: try again after the wait
                self.counters["reopen_failed"] += 1
                if self.on_failure is not None:
                    self.on_failure(exc)
                self.logger.info("%s still down (%s); retry in %.1f s", self.label,
                                 self.describe(exc), self.backoff)
                await self._sleep(self.backoff)
                self.backoff = min(self.maximum, self.backoff * 2)
            else:
                self.backoff = self.minimum
                if self.on_success is not None:
                    self.on_success()
