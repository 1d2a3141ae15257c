"""Grid swarms for the benchmarks (configs/make_grid.py), shared by bench_realtime and
bench_physics. Not a benchmark itself (`make bench` runs `bench/bench_*.py`)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def grid_swarm(n: int, directory: Path) -> Path:
    """A grid swarm of exactly n robots (configs/make_grid.py `write_grid`); exits with
    the reason for an n no grid makes."""
    spec = importlib.util.spec_from_file_location("make_grid", ROOT / "configs" / "make_grid.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    try:
        path: Path = module.write_grid(n, directory)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    return path
