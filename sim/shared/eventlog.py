"""The merged event log of a simulated run, as a file: JSON Lines, one event a line.

The one writer both simulators' logs go through (`--events FILE`, `--report DIR`'s
events.jsonl, the real-time orchestrator's `events_path`), in the format the daemon's
own event log uses (swarmd.base.eventlog: compact separators), so the same tools read both.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from sim.shared.holders import HolderFold
from swarmd.core.events import Stopped


def write_events(path: Path, events: Iterable[Mapping[str, Any]]) -> None:
    """Write `events` to `path` (replacing it), creating its parent directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", encoding="utf-8") as fh:
        for rec in events:
            fh.write(json.dumps(rec, separators=(",", ":"), default=str) + "\n")


def stops_at_end(events: Sequence[Mapping[str, Any]], end: float,
                 dead: Iterable[int] = ()) -> list[dict[str, Any]]:
    """The `stopped{}` records a run's end writes (DESIGN section 3): one for each robot
    still up when the run ended, at the end (or the last event, if one came later), so
    every robot's log ends as a daemon's does when it is stopped. A robot that crashed
    (or collided), stopped already, or whose process died on its own (`dead`) gets none:
    its log ends where it went down. The run's checker and summary have seen the log
    before: the end of a run is no failure of the swarm."""
    fold = HolderFold().feed_all(events)
    gone = set(dead)
    t = max([end, *(float(e.get("t", 0.0)) for e in events)])
    return [Stopped().record(round(t, 6), robot) for robot, holding in sorted(fold.robots.items())
            if holding.role not in ("crashed", "stopped") and robot not in gone]
