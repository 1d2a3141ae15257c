"""The daemon's event loop: uvloop when installed, asyncio's own on request
(swarmd/base/eventloop.py), and timers that never run before the node's deadline."""

from __future__ import annotations

import asyncio
import importlib.util
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from swarmd.base import eventloop
from swarmd.base.eventloop import EventLoopError, chosen, loop_factory, timer_slack
from swarmd.cli import app

ROOT = Path(__file__).resolve().parent.parent
runner = CliRunner()


def test_the_choice_is_the_option_then_the_environment_then_auto(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(eventloop.ENV, raising=False)
    assert chosen() == "auto"
    monkeypatch.setenv(eventloop.ENV, " AsyncIO ")
    assert chosen() == "asyncio"
    assert chosen("uvloop") == "uvloop"


def test_an_unknown_loop_is_refused_naming_where_it_came_from(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(eventloop.ENV, "trio")
    with pytest.raises(EventLoopError, match=f"{eventloop.ENV} 'trio' is not one of"):
        loop_factory()
    with pytest.raises(EventLoopError, match="--event-loop 'tokio' is not one of"):
        loop_factory("tokio")


def test_asyncio_is_the_standard_library_loop() -> None:
    assert loop_factory("asyncio") is asyncio.new_event_loop


def test_without_uvloop_auto_falls_back_and_uvloop_by_name_fails(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "uvloop", None)  # `import uvloop` raises ImportError
    assert loop_factory("auto") is asyncio.new_event_loop
    with pytest.raises(EventLoopError, match="uvloop is not installed"):
        loop_factory("uvloop")


def test_start_refuses_an_unknown_loop_as_a_usage_error() -> None:
    result = runner.invoke(app, ["start", "-c", str(ROOT / "configs" / "robot-example.yaml"),
                                 "--event-loop", "bogus"])
    assert result.exit_code == 2 and "'bogus' is not one of" in result.output


def test_start_refuses_an_unknown_loop_from_the_environment_before_running(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv(eventloop.ENV, "bogus")
    swarm = tmp_path / "swarm.yaml"
    swarm.write_text((ROOT / "configs" / "paper.yaml").read_text().replace(
        "auth: {mode: per-robot, keys_dir: keys}", "auth: none"))
    robot = tmp_path / "robot.yaml"
    robot.write_text(f"robot: 1\nswarm: {swarm}\nstate_dir: {tmp_path / 'state'}\n")
    result = runner.invoke(app, ["start", "-c", str(robot), "--log-format", "json"])
    assert result.exit_code == 1, result.output


needs_uvloop = pytest.mark.skipif(importlib.util.find_spec("uvloop") is None,
                                  reason="uvloop is not installed")


def _timers_run_early(slack: bool) -> int:
    """How many of 20 timers armed at `deadline (+ slack)` on uvloop ran while
    `loop.time()` was still before the deadline."""

    async def main() -> int:
        loop = asyncio.get_running_loop()
        early = 0
        for i in range(20):
            # Deadlines off the millisecond grid, as the node's are (t + k * period).
            deadline = loop.time() + 0.0020004 + i * 1e-5
            ran: asyncio.Future[float] = loop.create_future()

            def fire(f: asyncio.Future[float] = ran) -> None:
                f.set_result(loop.time())

            loop.call_at(deadline + (timer_slack(loop) if slack else 0.0), fire)
            early += await ran < deadline
        return early

    factory = loop_factory("uvloop")
    with asyncio.Runner(loop_factory=factory) as r:
        return r.run(main())


@needs_uvloop
def test_uvloop_timers_armed_with_the_slack_never_run_before_their_deadline() -> None:
    assert _timers_run_early(slack=True) == 0
    # Without it uvloop rounds the delay to the millisecond: some run early, and the
    # runtime would find nothing due and arm the same deadline again at once.
    assert _timers_run_early(slack=False) > 0


def test_asyncio_needs_no_slack() -> None:
    loop = asyncio.new_event_loop()
    try:
        assert timer_slack(loop) == 0.0 and eventloop.describe(loop) == "asyncio"
    finally:
        loop.close()
