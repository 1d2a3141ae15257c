"""The merged event log of a simulated run, as a file: JSON Lines, one event a line.

The one writer both simulators' logs go through (`--events FILE`, `--report DIR`'s
events.jsonl, the real-time orchestrator's `events_path`), in the format the daemon's
own event log uses (swarmd.eventlog: compact separators), so the same tools read both.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any


def write_events(path: Path, events: Iterable[Mapping[str, Any]]) -> None:
    """Write `events` to `path` (replacing it), creating its parent directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", encoding="utf-8") as fh:
        for rec in events:
            fh.write(json.dumps(rec, separators=(",", ":"), default=str) + "\n")
