"""One rclpy node spinning in its own thread, fed from asyncio without blocking it.

rclpy's executor blocks while it waits, and a reliable publisher may block on a full
history: neither may run on the daemon's loop, whose single timer heartbeats the robot
(DESIGN section 1, runtime.py). So each `RosThread` owns an rclpy context (its own
domain id), a node and a single-threaded executor spinning in a daemon thread. The loop
hands work over with `call(fn)`: a thread-safe deque and a guard condition whose
`trigger()` wakes the executor, which runs `fn(node)` on its own thread. Data coming
back (health) goes through `loop.call_soon_threadsafe`. Every rclpy object is touched
by one thread only once spinning has started.

The ROS 2 wheels are the `ros2` extra: `require_rclpy` turns their absence into one line
that says what to install.
"""

from __future__ import annotations

import collections
import importlib.util
import logging
import os
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger("swarmd.link.ros2")

ROS2_HINT = "pip install 'swarmd[ros2]'"
"""The one line that tells an install without the ROS 2 wheels what to add."""

SPIN_TIMEOUT = 0.2
"""s an idle executor waits before it looks at the stop flag again."""


class Ros2Unavailable(RuntimeError):
    """rclpy (the `ros2` extra) is not installed."""


def rclpy_missing() -> bool:
    return importlib.util.find_spec("rclpy") is None


def require_rclpy(what: str) -> None:
    """Raise `Ros2Unavailable` naming `what` and the extra when rclpy is absent."""
    if rclpy_missing():
        raise Ros2Unavailable(f"{what} needs the ROS 2 wheels (rclpy is not installed): "
                              f"{ROS2_HINT}")


def localhost_discovery() -> None:
    """Keep DDS discovery on this machine unless the environment already chose (Kilted
    reads ROS_AUTOMATIC_DISCOVERY_RANGE when the context starts; ROS_LOCALHOST_ONLY is
    its deprecated form)."""
    if "ROS_AUTOMATIC_DISCOVERY_RANGE" not in os.environ \
            and os.environ.get("ROS_LOCALHOST_ONLY") != "1":
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


class RosThread:
    """A node in its own context and executor thread. `start(setup)` creates the node,
    runs `setup(node)` (publishers, subscriptions, timers) before spinning, then spins;
    `call(fn)` runs `fn(node)` on the executor thread; `stop()` ends it (blocking: call
    it through `asyncio.to_thread`)."""

    def __init__(self, name: str, *, namespace: str = "", domain_id: int | None = None,
                 localhost_only: bool = True) -> None:
        self.name = name
        self.namespace = namespace
        self.domain_id = domain_id
        self.localhost_only = localhost_only
        self.node: Any = None
        self.errors = 0
        """Calls that raised on the executor thread (logged, never fatal)."""
        self._context: Any = None
        self._executor: Any = None
        self._guard: Any = None
        self._queue: collections.deque[Callable[[Any], None]] = collections.deque()
        self._thread: threading.Thread | None = None
        self._stopping = False

    def start(self, setup: Callable[[Any], None]) -> None:
        require_rclpy("the ros2 link")
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        if self.localhost_only:
            localhost_discovery()
        self._context = rclpy.Context()
        # The daemon owns SIGINT / SIGTERM (daemon.py): rclpy must not install its own.
        rclpy.init(context=self._context, domain_id=self.domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        try:
            self.node = rclpy.create_node(self.name, namespace=self.namespace,
                                          context=self._context)
            self._guard = self.node.create_guard_condition(self._drain)
            setup(self.node)
            self._executor = SingleThreadedExecutor(context=self._context)
            self._executor.add_node(self.node)
        except BaseException:
            self._context.try_shutdown()
            raise
        self._thread = threading.Thread(target=self._spin, name=f"ros2-{self.name}",
                                        daemon=True)
        self._thread.start()
        self._guard.trigger()  # what was queued before the start

    def call(self, fn: Callable[[Any], None]) -> None:
        """Run `fn(node)` on the executor thread, soon; thread-safe, never blocks. Calls
        made before `start` finished (the daemon may assign while the link still starts)
        wait in the queue and run first."""
        if self._stopping:
            return
        self._queue.append(fn)
        guard = self._guard
        if guard is not None:
            guard.trigger()

    def _drain(self) -> None:
        while self._queue:
            fn = self._queue.popleft()
            self.guarded(fn, self.node)

    def guarded(self, fn: Callable[..., None], *args: Any) -> None:
        """Run a callback on the executor thread; an error is logged, never fatal."""
        try:
            fn(*args)
        except Exception:
            self.errors += 1
            log.exception("ros2 callback failed", extra={"node": self.name})

    def _spin(self) -> None:
        executor, context = self._executor, self._context
        while not self._stopping and context.ok():
            try:
                executor.spin_once(timeout_sec=SPIN_TIMEOUT)
            except Exception:  # ExternalShutdownException, a broken callback
                if self._stopping or not context.ok():
                    break
                self.errors += 1
                log.exception("ros2 executor step failed", extra={"node": self.name})

    def stop(self, timeout: float = 5.0) -> None:
        """Stop spinning (after the calls already queued), destroy node and context."""
        if self._thread is None:
            return
        done = threading.Event()

        def last(_node: Any) -> None:
            self._stopping = True
            done.set()

        self.call(last)
        done.wait(timeout)
        self._stopping = True
        self._thread.join(timeout)
        self._thread = None
        try:
            self._executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            self._context.try_shutdown()
