"""A robot that learns its own key is revoked stops acting (swarmd.services.revocation;
docs/operations.md, "Revoking a robot"), on real daemons over UDP on loopback.

Before: robot 2 refused the reload (`config not reloaded ... robot 2 is revoked`) and
kept flying f2 while standby 6 took it over: two holders for good."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest
from swarms import signed_paper

from swarmd.config import load_robot, load_swarm
from swarmd.daemon.daemon import Daemon, run_daemon
from swarmd.link.none import NoneLink
from swarmd.services.revocation import EXIT_REVOKED, revoked_problem

pytestmark = pytest.mark.slow


async def _until(cond: Any, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        await asyncio.sleep(0.02)


async def test_a_robot_told_it_is_revoked_releases_its_function_and_exits(
        tmp_path: Path, udp_port: int) -> None:
    swarm, _keys = signed_paper(tmp_path)
    events: list[dict[str, Any]] = []
    daemons: dict[int, Daemon] = {}
    links = {r: NoneLink() for r in range(1, 7)}
    stop = asyncio.Event()
    tasks: dict[int, asyncio.Task[int]] = {}
    for r in range(1, 7):
        path = tmp_path / f"robot{r}.yaml"
        path.write_text(f"robot: {r}\nswarm: {swarm}\nstate_dir: {tmp_path / 'state'}\n"
                        f"identity_file: keys/robot-{r}.key\n"
                        f"event_log: {tmp_path / f'events{r}.jsonl'}\n"
                        f"transport: {{kind: udp, port: {udp_port}}}\n")
        tasks[r] = asyncio.create_task(run_daemon(
            load_robot(path), link=links[r], event_sink=events.append, stop_event=stop,
            config_path=path, on_ready=lambda d, r=r: daemons.__setitem__(r, d)))  # type: ignore[misc]
    params = load_swarm(swarm).params()
    try:
        await _until(lambda: len(daemons) == 6, 20.0, "six daemons ready")
        await asyncio.sleep(3 * params.startup_grace / 2)
        assert links[2].function == "f2"
        swarm.write_text(swarm.read_text().replace(
            "{mode: per-robot, keys_dir: keys}",
            "{mode: per-robot, keys_dir: keys, revoked: [2]}"))
        for d in daemons.values():
            d.reload()  # SIGHUP on every robot, robot 2 included
        code = await asyncio.wait_for(tasks[2], 10.0)
        assert code == EXIT_REVOKED
        assert links[2].function is None and links[2].history[-1] == ("release", "f2", None)
        mine = [e for e in events if e.get("robot") == 2]
        assert {"event": "leave", "function": "f2", "reason": "revoked"}.items() <= \
            next(e for e in mine if e["event"] == "leave").items()
        assert "revoked" in (tmp_path / "events2.jsonl").read_text()
        try:
            await _until(lambda: any(e["event"] == "takeover" for e in events), 20.0,
                         "takeover of f2")
        except AssertionError:
            print([(e["robot"], e["event"], e.get("function"), e.get("reason")) for e in events])
            raise
        take = [(e["robot"], e["function"]) for e in events if e["event"] == "takeover"]
        assert take == [(6, "f2")]
        await asyncio.sleep(params.t_max)
        assert links[6].function == "f2" and links[2].function is None  # one holder
    finally:
        stop.set()
        await asyncio.wait_for(asyncio.gather(*tasks.values(), return_exceptions=True), 30.0)


def test_a_revoked_robot_that_starts_exits_with_the_revoked_status(tmp_path: Path) -> None:
    """`swarmd start` of a revoked robot: status 3 (the unit does not restart it), not 2."""
    import os
    import subprocess
    import sys

    from swarms import ROOT

    swarm, _keys = signed_paper(tmp_path)
    swarm.write_text(swarm.read_text().replace(
        "{mode: per-robot, keys_dir: keys}", "{mode: per-robot, keys_dir: keys, revoked: [2]}"))
    robot = tmp_path / "robot2.yaml"
    robot.write_text(f"robot: 2\nswarm: {swarm}\nstate_dir: {tmp_path / 'state'}\n"
                     "identity_file: keys/robot-2.key\n")
    proc = subprocess.run([sys.executable, "-m", "swarmd.cli", "start", "--config", str(robot)],
                          capture_output=True, text=True, timeout=60, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert proc.returncode == EXIT_REVOKED, proc.stdout + proc.stderr
    assert "is revoked" in proc.stdout + proc.stderr
    assert revoked_problem([]) is None


def test_the_units_do_not_restart_a_revoked_robot() -> None:
    from swarms import ROOT

    for unit in ("swarmd.service", "swarmd@.service"):
        text = (ROOT / "deploy" / unit).read_text()
        assert f"RestartPreventExitStatus={EXIT_REVOKED}" in text.splitlines()
