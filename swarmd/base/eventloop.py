"""Which event loop a daemon runs on: uvloop when it is installed, asyncio's own otherwise.

An idle daemon wakes up about 54 times a second (its neighbours' heartbeats, its own
10 Hz tick) and does a few microseconds of protocol work each time; most of what it costs
is waking up and the event loop's turn around that work (docs/daemon.md, "Where an idle
daemon's CPU goes"). uvloop's turn is libuv in C: a bare listener that wakes for the same
frames costs a quarter less CPU on it than on asyncio's loop, and robot 1 of the paper
swarm about a fifth less. It runs the same asyncio API: the transports' readers, timers,
subprocesses, signal handlers and threads calling in with `call_soon_threadsafe`.

`SWARMD_EVENT_LOOP` (or `swarmd start --event-loop`) chooses: `auto` (the default:
uvloop when importable), `uvloop` (fail when it is not) or `asyncio` (the standard
library's loop, e.g. to rule uvloop out when chasing a problem).
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

ENV = "SWARMD_EVENT_LOOP"
CHOICES = ("auto", "uvloop", "asyncio")

T = TypeVar("T")


class EventLoopError(RuntimeError):
    """The event loop asked for cannot be had (an unknown name, uvloop not installed)."""


def chosen(choice: str | None = None) -> str:
    """The loop to run: `choice`, else `SWARMD_EVENT_LOOP`, else `auto`; case-insensitive.
    Raises EventLoopError for a name not in CHOICES."""
    name = (choice or os.environ.get(ENV) or "auto").strip().lower()
    if name not in CHOICES:
        source = "--event-loop" if choice else ENV
        raise EventLoopError(f"{source} {name!r} is not one of {', '.join(CHOICES)}")
    return name


def loop_factory(choice: str | None = None) -> Callable[[], asyncio.AbstractEventLoop]:
    """A factory of the chosen loop (`chosen`). Raises EventLoopError when `uvloop` is
    asked for by name and cannot be imported; `auto` then falls back to asyncio."""
    name = chosen(choice)
    if name != "asyncio":
        try:
            import uvloop
        except ImportError as exc:
            if name == "uvloop":
                raise EventLoopError(f"uvloop is not installed ({exc}); install it "
                                     f"(pip install uvloop) or set {ENV}=asyncio") from None
        else:
            factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
            return factory
    return asyncio.new_event_loop


def run(main: Coroutine[Any, Any, T], choice: str | None = None) -> T:
    """`asyncio.run(main)` on the chosen loop (`loop_factory`). Raises EventLoopError,
    with `main` closed unrun, when the choice is refused."""
    try:
        factory = loop_factory(choice)
    except EventLoopError:
        main.close()
        raise
    with asyncio.Runner(loop_factory=factory) as runner:
        return runner.run(main)


UVLOOP_TIMER_SLACK = 0.001
"""uvloop's clock and timers count whole milliseconds (libuv): `call_at(t)` rounds the
delay to the nearest one, so a timer may run up to half a millisecond before `t` by
`loop.time()`. asyncio's own runs timers at or after `t` (its clock resolution)."""


def timer_slack(loop: asyncio.AbstractEventLoop) -> float:
    """How much later than a deadline to arm a timer on `loop` so that, when it runs,
    `loop.time()` has reached the deadline: a timer that runs early finds nothing due
    and is armed again at once, a busy turn of the loop until its clock ticks over."""
    return UVLOOP_TIMER_SLACK if describe(loop) == "uvloop" else 0.0


def describe(loop: asyncio.AbstractEventLoop) -> str:
    """`uvloop` or `asyncio`: what the daemon logs at start."""
    return "uvloop" if type(loop).__module__.startswith("uvloop") else "asyncio"


__all__ = ["CHOICES", "ENV", "EventLoopError", "chosen", "describe", "loop_factory", "run",
           "timer_slack"]
