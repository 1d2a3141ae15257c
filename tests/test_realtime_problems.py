"""What the real-time `swarmd sim` does when the processes, not the protocol, go wrong.

Pure tests of the summary's new facts (robots that died on their own, lateness, the
problems that make a run not ok), and three short real-process runs of the paper swarm:
a robot process ended from outside plus a robot whose daemon cannot start, a robot that
hangs before `ready`, an interrupted run; and one SIGTERM to the command itself. Every
real run is bounded, and each checks that no robot process is left behind.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from rich.console import Console
from test_realtime import _alive, _descendants
from typer.testing import CliRunner

import sim.realtime.orchestrator as realtime
import sim.realtime.robotfiles as robotfiles
from sim.realtime.orchestrator import Orchestrator, RealtimeResult, run_realtime_async
from sim.realtime.problems import errors_of, robot_log
from sim.realtime.summary import summarize_realtime
from sim.shared.faults import parse_fault
from sim.shared.summary import (
    lateness_figures,
    lateness_warning,
    render_summary,
    summarize,
)
from swarmd.cli import app
from swarmd.config import load_swarm
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"


# -- the summary --------------------------------------------------------------------------


def _started() -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = [
        {"t": 0.01, "robot": r, "event": "started", "role": "active", "function": f"f{r}"}
        for r in (1, 2, 3, 4)]
    return out + [{"t": 0.01, "robot": r, "event": "started", "role": "standby",
                   "function": None} for r in (5, 6)]


def test_a_robot_that_died_on_its_own_is_a_crash_not_a_false_takeover(
    paper: tuple[SwarmPlan, Params],
) -> None:
    plan, params = paper
    events = [*_started(),
              {"t": 2.6, "robot": 6, "event": "takeover", "function": "f2", "epoch": 1,
               "replaced": 2}]
    blind = summarize(events, [], plan, params, loss=0.0, duration=5.0, mode="real time")
    # What it used to say: robot 2 still held f2, so 6 replaced a healthy robot.
    assert {v.kind for v in blind.violations} == {"false_takeover", "dual_execution"}
    told = summarize(events, [], plan, params, loss=0.0, duration=5.0, mode="real time",
                     deaths={2: 2.0})
    assert told.violations == [] and told.false_takeovers == []
    assert [(f.spec, f.function, f.by) for f in told.faults] == [("died:2@2.00", "f2", 6)]


def test_suspicions_of_healthy_robots_are_counted(paper: tuple[SwarmPlan, Params]) -> None:
    plan, params = paper
    events = [*_started(),
              {"t": 3.4, "robot": 1, "event": "suspect", "subject": 2, "function": "f2"},
              {"t": 4.0, "robot": 2, "event": "suspect", "subject": 3, "function": "f3"}]
    summary = summarize(events, [parse_fault("crash:2@3")], plan, params, loss=0.0,
                        duration=5.0, mode="real time")
    assert summary.false_suspicions == 1  # robot 3's; robot 2 had crashed
    assert json.loads(summary.to_json())["false_suspicions"] == 1


def test_a_robot_started_after_the_grace_is_dead_to_the_swarm_and_warned_about(
    paper: tuple[SwarmPlan, Params],
) -> None:
    plan, params = paper
    # A loaded machine started robot 2's daemon at 3.5 s: robot 6 had replaced it.
    events = [e for e in _started() if e["robot"] != 2] + [
        {"t": 3.3, "robot": 6, "event": "takeover", "function": "f2", "epoch": 1,
         "replaced": 2},
        {"t": 3.5, "robot": 2, "event": "started", "role": "active", "function": "f2"},
        {"t": 3.6, "robot": 2, "event": "fenced", "function": "f2", "epoch": 1}]
    summary = summarize_realtime(_result(events=events), [], plan, params, loss=0.0)
    assert summary.violations == [] and summary.false_takeovers == []
    assert summary.extra["slow_starts"] == {"2": 3.5}
    assert any("started after the start-up grace" in w and "2 at 3.50 s" in w
               for w in summary.warnings)


def test_lateness_leaves_out_a_paused_robot_and_counts_on_time_wake_ups() -> None:
    late = [(2, 3.2, 2000.0), (2, 5.5, 900.0), (4, 1.0, 30.0)]
    figures = lateness_figures(late, 100, [parse_fault("pause:2@3+2")])
    # Robot 2's 2 s freeze and its catching up within a second are the pause's.
    assert figures["wakes"] == 98 and figures["max_ms"] == 30.0
    assert (figures["max_robot"], figures["p50_ms"]) == (4, 0.0)
    assert lateness_figures(late, 100, [])["max_ms"] == 2000.0
    assert lateness_figures([], 0, []) == {"wakes": 0}


def test_late_robots_get_a_warning_and_on_time_ones_none(
    paper: tuple[SwarmPlan, Params],
) -> None:
    _, params = paper  # udp: t_max 0.5 s, heartbeat 0.1 s: margin 400 ms
    on_time = lateness_figures([(1, 2.0, 150.0)], 200, [])
    assert lateness_warning(on_time, params, []) is None
    late = lateness_figures([(3, 4.5, 450.0)], 200, [])
    text = lateness_warning(late, params, [])
    assert text is not None
    assert "robots were late" in text and "450 ms" in text and "robot 3 at t=4.50" in text


def _result(**kw: Any) -> RealtimeResult:
    base: dict[str, Any] = {"events": _started(), "robots": (1, 2, 3, 4, 5, 6),
                            "duration": 5.0, "t0": 0.0, "startup_s": 0.3, "run_dir": None}
    return RealtimeResult(**{**base, **kw})


def test_process_problems_make_the_run_not_ok_and_are_printed_one_a_line(
    paper: tuple[SwarmPlan, Params],
) -> None:
    plan, params = paper
    problem = "robot 3: process ended on its own at t=1.00 s (exit code 1): [boom]"
    summary = summarize_realtime(_result(problems=[problem], late=[(1, 2.0, 420.0)],
                                         wakes=300), [], plan, params, loss=0.0)
    assert summary.violations == [] and not summary.ok
    doc = json.loads(summary.to_json())
    assert doc["process_problems"] == [problem] and doc["ok"] is False
    assert doc["lateness_ms"]["max_ms"] == 420.0 and len(doc["warnings"]) == 1
    console = Console(record=True, width=200)
    render_summary(summary, console)
    text = console.export_text()
    assert f"PROCESS PROBLEM: {problem}" in text  # markup-free: "[boom]" stays
    assert "WARNING: robots were late" in text


def test_counted_drops_are_in_the_json_and_totalled_in_the_text(
    paper: tuple[SwarmPlan, Params],
) -> None:
    plan, params = paper
    drops = {3: {"auth": 7, "replay": 2}, 5: {"auth": 4}}
    summary = summarize_realtime(_result(drops=drops), [], plan, params, loss=0.0)
    assert json.loads(summary.to_json())["drops"] == {"3": {"auth": 7, "replay": 2},
                                                       "5": {"auth": 4}}
    console = Console(record=True, width=200)
    render_summary(summary, console)
    assert "dropped frames: auth 11, replay 2" in console.export_text()
    assert summary.ok  # refused frames are the defence working, not a failure


def test_an_interrupted_run_is_summarised_up_to_where_it_ended(
    paper: tuple[SwarmPlan, Params],
) -> None:
    plan, params = paper
    crash = parse_fault("crash:2@3")  # after the interruption: no expectation on it
    summary = summarize_realtime(_result(interrupted="SIGTERM", ended_at=2.5), [crash],
                                 plan, params, loss=0.0)
    assert summary.duration == 2.5 and summary.faults == [] and summary.ok
    assert summary.extra["interrupted"] == {"signal": "SIGTERM", "at": 2.5}
    assert any("interrupted by SIGTERM" in w for w in summary.warnings)


# -- --report -----------------------------------------------------------------------------


def test_report_that_cannot_be_written_is_refused_before_the_run(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    result = CliRunner().invoke(app, ["sim", str(PAPER), "--no-physics", "--report",
                                      str(blocker / "out")])
    assert result.exit_code == 2, result.output
    assert "cannot be written" in result.output and "is not a directory" in result.output


# -- real processes -----------------------------------------------------------------------


def _pids(run_dir: Path) -> list[int]:
    doc = json.loads((run_dir / "pids.json").read_text())
    return [*doc["robots"].values(), *doc["retired"]]


async def _wait_for_file(path: Path, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < deadline, path
        await asyncio.sleep(0.05)


@pytest.mark.slow
async def test_robot_processes_that_end_on_their_own_are_reported(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Robot 4's daemon cannot start (its state_dir is under a file): it exits non-zero
    # right after `go`. Robot 2 is killed from outside the orchestrator.
    write = robotfiles.write_robot_file
    (tmp_path / "blocker").write_text("a file")

    def robot_file(run_dir: Path, swarm: Path, robot: int, **kw: Any) -> Path:
        path = write(run_dir, swarm, robot, **kw)
        if robot == 4:
            doc = yaml.safe_load(path.read_text())
            doc["state_dir"] = str(tmp_path / "blocker" / "state")
            path.write_text(yaml.safe_dump(doc))
        return path

    monkeypatch.setattr(realtime, "write_robot_file", robot_file)
    run = asyncio.ensure_future(run_realtime_async(PAPER, duration=3.0,
                                                   report_dir=tmp_path))
    await _wait_for_file(tmp_path / "realtime" / "pids.json")
    pids = json.loads((tmp_path / "realtime" / "pids.json").read_text())["robots"]
    await asyncio.sleep(1.8)  # robots ready, go, t ~ 1 s: the daemons run
    os.kill(pids["2"], signal.SIGTERM)
    result = await asyncio.wait_for(run, 30.0)
    assert set(result.deaths) == {2, 4}
    assert 0.0 <= result.deaths[4] < result.deaths[2]
    by_robot = {p.split(":")[0]: p for p in result.problems}
    assert set(by_robot) == {"robot 2", "robot 4"}, result.problems
    assert "ended on its own" in by_robot["robot 2"] and "exit code -15" in by_robot["robot 2"]
    assert "ended on its own" in by_robot["robot 4"]
    swarm = load_swarm(PAPER)
    summary = summarize_realtime(result, [], swarm.to_plan(), swarm.params(), loss=0.0)
    # Robot 6 replaced robot 2 (4's slot went to 5): crashes, not false takeovers.
    assert summary.false_takeovers == [] and summary.violations == []
    assert not summary.ok
    assert [p for p in _pids(tmp_path / "realtime") if _alive(p)] == []


@pytest.mark.slow
async def test_a_robot_that_hangs_before_ready_is_named_and_nothing_is_left(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Robot 3's process is stopped (SIGSTOP) as soon as it is spawned, before it can load
    # its file and say ready. (A FIFO as robot file no longer hangs a robot: it is
    # refused at once, swarmd.base.files.) The orchestrator's SIGKILL ends a stopped process.
    # A forked robot runs at once: on a loaded machine it could say ready before the
    # SIGSTOP lands. So its log is a FIFO with no reader when it is spawned: its first
    # act, opening that log (`robot_proc.child_main`), waits until it is stopped; then
    # a plain file stands in its place for the orchestrator to read the log's tail.
    spawn = Orchestrator._spawn

    def spawn_stopped(self: Orchestrator, robot: int, t0: float | None) -> Any:
        log = robot_log(self.run_dir, robot)
        if robot == 3:
            os.mkfifo(log)
        proc = spawn(self, robot, t0)
        if robot == 3:
            assert proc.process.pid is not None
            os.kill(proc.process.pid, signal.SIGSTOP)
            log.unlink()
            log.touch()
        return proc

    monkeypatch.setattr(Orchestrator, "_spawn", spawn_stopped)
    monkeypatch.setattr(realtime, "READY_TIMEOUT", 1.5)
    monkeypatch.setattr(realtime, "READY_PER_ROBOT", 0.0)
    with pytest.raises(RuntimeError, match=r"robots \[3\] not ready after 1.5 s"):
        await asyncio.wait_for(run_realtime_async(PAPER, duration=2.0, report_dir=tmp_path),
                               30.0)
    assert [p for p in _pids(tmp_path / "realtime") if _alive(p)] == []


def test_the_constructor_does_no_io_prepare_does(tmp_path: Path) -> None:
    # The orchestrator's I/O (run directory, keys, radios) is its explicit start step.
    orch = Orchestrator(PAPER, duration=1.0, faults=[], loss=0.0, seed=0, physics=False,
                        live=False, report_dir=tmp_path / "report")
    assert not (tmp_path / "report").exists()
    with pytest.raises(RuntimeError, match="prepare"):
        _ = orch.run_dir
    orch.prepare()
    assert (tmp_path / "report" / "realtime" / "logs").is_dir()
    assert orch.robots == (1, 2, 3, 4, 5, 6) and orch.port > 0
    orch.cleanup()


@pytest.mark.slow
async def test_an_interrupted_run_returns_what_happened_so_far(tmp_path: Path) -> None:
    orch = Orchestrator(PAPER, duration=30.0, faults=[parse_fault("crash:2@0.5")], loss=0.0,
                        seed=0, physics=False, live=False, report_dir=tmp_path)
    try:
        run = asyncio.ensure_future(orch.run())
        # Past the takeover: a crash before the links are measured is taken over within
        # the bound of t_max_bursty (DESIGN "Detection", "A link not measured yet").
        while not orch.t0 or orch.run_time() < 3.5:
            await asyncio.sleep(0.05)
        orch.interrupt("SIGINT")
        result = await asyncio.wait_for(run, 15.0)
    finally:
        orch.cleanup()
    assert result.interrupted == "SIGINT"
    assert result.ended_at is not None and 3.5 <= result.ended_at < 7.0
    assert [e["robot"] for e in result.events if e["event"] == "takeover"] == [6]
    assert result.problems == [] and result.deaths == {}
    assert [p for p in _pids(tmp_path / "realtime") if _alive(p)] == []


@pytest.mark.slow
def test_sigterm_to_the_command_writes_a_partial_report_and_exits_143(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarmd.cli", "sim", str(PAPER), "--no-physics", "--json",
         "--duration", "60", "--fault", "crash:2@0.5", "--report", str(tmp_path)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pids_file = tmp_path / "realtime" / "pids.json"
        deadline = time.monotonic() + 30
        robots: list[int] = []
        # Every robot spawned and running: the family below then holds all six robots,
        # the forkserver and multiprocessing's resource tracker.
        while len(robots) < 6 or not all(_alive(p) for p in robots):
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
            if pids_file.exists():
                robots = list(json.loads(pids_file.read_text())["robots"].values())
        family = _descendants(proc.pid)
        assert set(robots) <= family
        time.sleep(1.5)  # past t0 and the crash
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signal.SIGTERM, err[-2000:]
    summary = json.loads(out)
    assert summary["interrupted"]["signal"] == "SIGTERM"
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / "events.jsonl").exists() and (tmp_path / "timeline.png").exists()
    # The robots are SIGKILLed and reaped before the command exits (kill_all).
    assert [p for p in robots if _alive(p)] == []
    # The forkserver and
    # the resource tracker end on their own once the command has exited (EOF on their
    # pipe from it), and they hold its stdout/stderr: communicate() returns the moment
    # the kernel closes their files, a little before they are zombies, so a check at
    # that instant can still see them running. Give them the same bounded grace as
    # test_realtime_interrupt_leaves_no_process_behind.
    deadline = time.monotonic() + 5
    while any(_alive(p) for p in family) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert [p for p in family if _alive(p)] == []


def test_errors_a_robot_survived_are_quoted_from_its_log(
    tmp_path: Path, paper: tuple[SwarmPlan, Params],
) -> None:
    orch = Orchestrator(PAPER, duration=1.0, faults=[], loss=0.0, seed=0, physics=False,
                        live=False, report_dir=tmp_path)
    orch.prepare()
    log = tmp_path / "realtime" / "logs" / "robot3.log"
    log.write_text('{"level":"warning","msg":"channel: send_error"}\n'
                   '{"level":"error","msg":"robot 3: cannot fly f3 (epoch 0): under the ground"}\n'
                   '{"level":"error","msg":"robot link assign failed","error":"boom"}\n')
    assert errors_of(orch.run_dir, 3) == ("robot 3: 2 error(s) in its log, first: robot 3: cannot "
                                   "fly f3 (epoch 0): under the ground")
    assert errors_of(orch.run_dir, 4) == ""  # no log at all
    plan, params = paper
    summary = summarize_realtime(_result(log_errors=[errors_of(orch.run_dir, 3)]), [], plan, params,
                                 loss=0.0)
    assert summary.ok and any("cannot fly f3" in w for w in summary.warnings)
