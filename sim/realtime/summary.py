"""The summary of a real-time run: the shared summary over the merged log, plus what only
real processes on a real machine have (their problems, start-up time, lateness, load)."""

from __future__ import annotations

import os

from sim.realtime.result import RealtimeResult
from sim.shared.faults import Fault
from sim.shared.summary import (
    Summary,
    lateness_figures,
    lateness_warning,
    restart_delays,
    slow_starts,
    summarize,
)
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan


def summarize_realtime(
    result: RealtimeResult, faults: list[Fault], plan: SwarmPlan, params: Params, *,
    loss: float,
) -> Summary:
    """The summary of a real-time run (`orchestrator`): `summarize` over the merged log,
    up to the time the run really ended (earlier when interrupted), with the robots that
    died on their own as crashes, plus what only real processes have: their problems,
    start-up time, lateness and the load of the machine."""
    end = result.ended_at if result.ended_at is not None else result.duration
    summary = summarize(result.events, [f for f in faults if f.at <= end], plan, params,
                        loss=loss, duration=round(end, 2), mode="real time",
                        deaths=result.deaths)
    summary.problems = list(result.problems)
    summary.drops = dict(result.drops)
    figures = lateness_figures(result.late, result.wakes, faults)
    warning = lateness_warning(figures, params, summary.violations, summary.false_suspicions)
    if warning is not None:
        summary.warnings.append(warning)
    summary.warnings.extend(result.log_errors)
    slow = slow_starts(result.events, faults, params.startup_grace)
    if slow:
        late_robots = ", ".join(f"{r} at {t:.2f} s" for r, t in list(slow.items())[:10])
        summary.warnings.append(
            f"{len(slow)} robot(s) started after the start-up grace of "
            f"{params.startup_grace:g} s ({late_robots}{', ...' if len(slow) > 10 else ''})"
            ": this machine could not start the swarm in time, and the swarm rightly took "
            "them for dead (their takeovers are no protocol failure)")
        summary.extra["slow_starts"] = {str(r): round(t, 3) for r, t in slow.items()}
    if result.interrupted is not None:
        summary.warnings.append(f"interrupted by {result.interrupted} at t={end:.2f} s of "
                                f"{result.duration:g} s: a partial run")
        summary.extra["interrupted"] = {"signal": result.interrupted, "at": round(end, 3)}
    summary.extra["startup_s"] = round(result.startup_s, 2)
    restarts = restart_delays(result.events, faults)
    if restarts:
        summary.extra["restart_s"] = {str(r): ds for r, ds in restarts.items()}
    summary.extra["lateness_ms"] = figures
    summary.extra["loadavg"] = [round(x, 2) for x in os.getloadavg()]
    return summary
