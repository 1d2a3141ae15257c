"""An executor on one daemon thread, for blocking libraries that may never return."""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import Any, TypeVar

_T = TypeVar("_T")


class DaemonThreadExecutor(Executor):
    """Like `ThreadPoolExecutor(1)`, but on a *daemon* thread that is never joined.

    A library call can block for good on a device in a bad state (digi-xbee's close or
    open does); a `ThreadPoolExecutor` thread stuck like that keeps `asyncio.run` (its
    default executor shutdown) and the interpreter's exit waiting forever, i.e. a daemon
    that needs SIGKILL. Abandoning a stuck daemon thread lets the process exit."""

    def __init__(self, name: str) -> None:
        self._jobs: queue.SimpleQueue[tuple[Future[Any], Callable[..., Any], tuple[Any, ...]]
                                      | None] = queue.SimpleQueue()
        self._closed = False
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def submit(self, fn: Callable[..., _T], /, *args: Any, **kwargs: Any) -> Future[_T]:
        if self._closed:
            raise RuntimeError("device thread closed")
        future: Future[_T] = Future()
        self._jobs.put((future, fn, args))
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Stop after the queued jobs; never waits (a stuck job would wait forever)."""
        self._closed = True
        self._jobs.put(None)

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            future, fn, args = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args))
            except BaseException as exc:
                future.set_exception(exc)
