"""`swarmd sim SWARM.yaml`: the whole swarm on this machine (DESIGN section 3).

Without `--virtual`: one OS process per robot, each a real daemon over UDP multicast on
loopback (`sim.realtime`). With `--virtual`: every robot's protocol core in this process
on a virtual clock (`sim.virtual`), deterministic by `--seed`, far faster than real
time. Both write the same event log and print the same summary.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

if TYPE_CHECKING:
    from sim.shared.summary import Summary

FAULT_HELP = (
    "Inject a fault (repeatable): crash:R@T, restart:R@T, pause:R@T+D, "
    "partition:1,2|3,4@T+D, liar:R@T, leave:R@T, unhealthy:R@T, motor:R@T (physics "
    "only). R a robot id; T seconds from the start, before --duration; D seconds it "
    "lasts. docs/sim.md tells what each one does."
)


TRANSPORTS = ("udp", "xbee", "serial")
"""Channels of the real-time mode (sim.realtime.orchestrator)."""


def register(app: typer.Typer) -> None:
    """Add the `sim` command to the CLI."""

    @app.command("sim")
    def sim(
        swarm: Annotated[Path, typer.Argument(help="Swarm file, e.g. configs/paper.yaml.")],
        virtual: Annotated[bool, typer.Option(
            "--virtual", help="Run every protocol core in this process on a virtual "
            "clock: deterministic by --seed, far faster than real time, no robot "
            "processes, no physics.")] = False,
        duration: Annotated[float, typer.Option(
            "--duration", min=0.1, help="Length of the run in seconds (wall-clock in "
            "real time, simulated with --virtual).")] = 15.0,
        seed: Annotated[int, typer.Option("--seed", help="Seed of frame loss, jitter and "
                                          "start times.")] = 0,
        loss: Annotated[float, typer.Option(
            "--loss", min=0.0, max=1.0, help="Probability, 0 to 1, that a receiver misses "
            "a frame (drawn per frame and per receiver).")] = 0.0,
        fault: Annotated[list[str] | None, typer.Option("--fault", help=FAULT_HELP)] = None,
        events: Annotated[Path | None, typer.Option(
            "--events", help="Also write the merged event log to this file (JSON Lines, "
            "one event a line). Default: not written.")] = None,
        report: Annotated[Path | None, typer.Option(
            "--report", help="Directory for summary.json, events.jsonl, timeline.png and, "
            "with physics, trajectories.png, swarm.mp4 and key frames; what an earlier run "
            "wrote there is removed first. Default: no report.")]
        = None,
        json_out: Annotated[bool, typer.Option(
            "--json", help="Print the summary as JSON on stdout; no live table, the "
            "report lines go to stderr.")] = False,
        no_physics: Annotated[bool, typer.Option(
            "--no-physics", help="Real time with bare daemons (robot link 'none'): no "
            "MuJoCo quadrotors, so no trajectories or video.")] = False,
        craft: Annotated[str | None, typer.Option(
            "--craft", help="Quadrotor every robot flies (physics only): x2 (Skydio "
            "X2-class, 1.3 kg, visible in pictures) or crazyflie (27 g). Default: "
            "$SWARMD_QUAD_PRESET, else x2.")] = None,
        transport: Annotated[str, typer.Option(
            "--transport", help="Channel in real time: udp (multicast on loopback), xbee "
            "or serial (emulated radios on pseudo-terminals). Refused with --virtual.")]
        = "udp",
    ) -> None:
        """Run the whole swarm on this machine, inject faults, print a summary.

        Default: one process per robot, each a real daemon (the code swarmd start runs)
        flying a MuJoCo quadrotor, over UDP multicast on loopback. --no-physics: the same
        without quadrotors. --virtual: one process on a virtual clock.

        Exit codes: 0 no invariant violated, 1 an invariant was violated or a robot
        process failed, 2 bad input (swarm file, --fault, --craft, --report; nothing was
        started), 130 / 143 ended early by Ctrl-C / SIGTERM (partial report).

        Example: swarmd sim configs/paper.yaml --fault crash:2@5 --duration 15 --report out/demo
        """
        from rich.console import Console

        from sim.shared.faults import FaultSpecError, check_faults, parse_fault
        from swarmd.config import ConfigError, load_swarm

        # Problems are plain text: no rich markup (a `[x, y, z]` in a message is not a
        # tag) and no wrapping (one problem a line, for grep).
        err = Console(stderr=True, highlight=False, markup=False, soft_wrap=True)
        # An option the chosen mode ignores is refused, not silently dropped: the user
        # would believe the run used it.
        usage = []
        if transport not in TRANSPORTS:
            usage.append(f"--transport: {transport!r} is not one of {', '.join(TRANSPORTS)}")
        elif virtual and transport != "udp":
            usage.append("--transport: --virtual has no channel (it runs every core in "
                         "this process); drop --virtual to use emulated radios")
        if craft is not None and (virtual or no_physics):
            usage.append("--craft: only with physics (not with --virtual or --no-physics)")
        if virtual and no_physics:
            usage.append("--no-physics: --virtual never flies; give one of the two")
        for u in usage:
            err.print(u)
        if usage:
            raise typer.Exit(2)
        try:
            cfg = load_swarm(swarm)
        except ConfigError as exc:
            for problem in exc.problems:
                err.print(str(problem))
            raise typer.Exit(2) from None
        try:
            faults = [parse_fault(s) for s in fault or []]
        except FaultSpecError as exc:
            err.print(f"--fault: {exc}")
            raise typer.Exit(2) from None
        plan, params = cfg.to_plan(), cfg.params()
        problems = check_faults(faults, set(plan.robots), physics=virtual or not no_physics,
                                duration=duration)
        if problems:
            for p in problems:
                err.print(f"--fault: {p}")
            raise typer.Exit(2)
        if not virtual and not no_physics:
            import os

            from sim.physics.model import PRESETS

            # The robot processes read the preset from their environment (sim.physics.link),
            # which the forkserver, started below, inherits.
            chosen = craft or os.environ.get("SWARMD_QUAD_PRESET", "x2")
            if chosen not in PRESETS:
                err.print(f"--craft: unknown quadrotor preset {chosen!r} "
                          f"(known: {', '.join(PRESETS)})")
                raise typer.Exit(2)
            os.environ["SWARMD_QUAD_PRESET"] = chosen
            # What a craft cannot fly (a waypoint under the ground...) is refused before
            # any robot starts, not logged by a robot that then stays parked.
            from swarmd.functions import flight_problems

            flight = flight_problems({n: cfg.function_spec(n) for n in plan.functions})
            for p in flight:
                err.print(f"{swarm}: {p} (or run with --no-physics)")
            if flight:
                raise typer.Exit(2)
        if report is not None:
            try:
                _clear_report(report)
            except OSError as exc:  # read-only, a file on the path, no permission...
                err.print(f"--report: {report} cannot be written: "
                          f"{exc.strerror or exc} ({type(exc).__name__})")
                raise typer.Exit(2) from None
        out = Console(highlight=False, stderr=json_out)

        if virtual:
            summary = _run_virtual(cfg, plan, params, faults, duration=duration, seed=seed,
                                   loss=loss)
        else:
            summary = _run_realtime(swarm, plan, params, faults, duration=duration, seed=seed,
                                    loss=loss, report=report, physics=not no_physics,
                                    transport=transport, live=not json_out)
        events_list: list[dict[str, Any]] = summary.extra.pop("_events")
        t0: float | None = summary.extra.pop("_t0", None)
        if events is not None:
            _write_events(events, events_list)
        pictures: dict[str, Any] = {}
        if report is not None:
            # summary.duration: where the run really ended (earlier when interrupted).
            _write_report(report, events_list, summary, summary.duration)
            if not virtual and not no_physics:
                # Trajectory plot, video and key frames from the robots' trajectory files.
                from sim.physics.render import report_pictures

                pictures = report_pictures(report, events_list,
                                           {n: cfg.function_spec(n) for n in plan.functions},
                                           t0=t0, end=summary.duration)
        if json_out:
            typer.echo(summary.to_json())
        else:
            from sim.shared.summary import render_summary

            render_summary(summary, out)
        if report is not None:
            _say_report(out, report, pictures, physics=not virtual and not no_physics)
        interrupted = summary.extra.get("interrupted")
        if interrupted:  # Ctrl-C / SIGTERM: the shell's 128 + signal number
            import signal

            raise typer.Exit(128 + signal.Signals[interrupted["signal"]].value)
        raise typer.Exit(0 if summary.ok else 1)


def _run_virtual(cfg: Any, plan: Any, params: Any, faults: list[Any], *, duration: float,
                 seed: int, loss: float) -> Summary:
    import time

    from sim.shared.summary import summarize
    from sim.virtual.simulator import run_virtual

    key = cfg.key()
    t0 = time.perf_counter()
    result = run_virtual(plan, params, duration=duration, faults=faults, loss=loss, seed=seed,
                         keys=(key,) if key else ())
    wall = time.perf_counter() - t0
    summary = summarize(result.events, faults, plan, params, loss=loss, duration=duration,
                        mode="virtual", extra_violations=result.violations)
    summary.extra["frames_sent"] = result.frames_sent
    summary.extra["robot_seconds_per_wall_second"] = round(
        result.robot_seconds / max(wall, 1e-9))
    summary.extra["_events"] = result.events
    return summary


def _run_realtime(swarm: Path, plan: Any, params: Any, faults: list[Any], *, duration: float,
                  seed: int, loss: float, report: Path | None, physics: bool, transport: str,
                  live: bool) -> Summary:
    from sim.realtime.orchestrator import run_realtime
    from sim.realtime.summary import summarize_realtime

    try:
        result = run_realtime(swarm, duration=duration, faults=faults, loss=loss, seed=seed,
                              report_dir=report, physics=physics, transport=transport,
                              live=live)
    except (ValueError, RuntimeError) as exc:
        typer.echo(f"swarmd sim: {exc}", err=True)
        raise typer.Exit(2) from None
    summary = summarize_realtime(result, faults, plan, params, loss=loss)
    summary.extra["_t0"] = result.t0
    summary.extra["_events"] = result.events
    return summary


REPORT_FILES = ("events.jsonl", "summary.json", "timeline.png", "trajectories.png",
                "swarm.mp4", "swarm.gif", "key-*.png")
"""What `--report DIR` writes at its top level (plus `realtime/`, the robots' files)."""


def _clear_report(report: Path) -> None:
    """Remove what an earlier run wrote into `report`, and nothing else. A reused report
    directory must not mix runs: the robots' persisted state under `realtime/state`
    would make them restore the old run's roles (DESIGN rule 2), and old trajectory
    files and key frames would be drawn with the new ones."""
    import shutil

    if report.exists() and not report.is_dir():
        raise typer.BadParameter(f"{report} exists and is not a directory", param_hint="--report")
    report.mkdir(parents=True, exist_ok=True)
    shutil.rmtree(report / "realtime", ignore_errors=True)
    for pattern in REPORT_FILES:
        for path in report.glob(pattern):
            path.unlink(missing_ok=True)
    # Refuse an unwritable directory now, not after the run (an OSError goes up).
    probe = report / ".swarmd-write-test"
    probe.write_bytes(b"")
    probe.unlink()


def _say_report(out: Any, report: Path, pictures: dict[str, Any], *, physics: bool) -> None:
    """Tell the user what `--report` wrote and, when a picture is missing, why: a
    missing GL backend must not look like a silent success (issue 4 item 5)."""
    names = sorted(p.name for p in report.iterdir() if p.is_file())
    out.print(f"report: {report}/ — {', '.join(names)}", soft_wrap=True)
    if not physics:
        out.print("report: trajectories and video need physics (not with --virtual or "
                  "--no-physics)")
    for problem in pictures.get("skipped", []):
        out.print(f"report: trajectory file skipped: {problem}")
    if pictures.get("video_error"):
        out.print(f"report: no video or key frames: {pictures['video_error']} "
                  "(scripts/system-deps.sh installs a headless GL backend)")


def _write_events(path: Path, events: list[dict[str, Any]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", encoding="utf-8") as fh:
        for e in events:
            fh.write(json.dumps(e, separators=(",", ":")) + "\n")


def _write_report(report: Path, events: list[dict[str, Any]], summary: Summary,
                  duration: float) -> None:
    _write_events(report / "events.jsonl", events)
    (report / "summary.json").write_text(summary.to_json() + "\n", encoding="utf-8")
    from sim.physics.plots import timeline_png

    timeline_png(events, report / "timeline.png", end=duration,
                 title=f"swarmd sim ({summary.mode})")
