"""configs/make_grid.py: the grid swarms the benchmarks and docs use."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from swarmd.config import load_swarm
from swarmd.daemon.check import run_check

ROOT = Path(__file__).resolve().parent.parent


def _module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("make_grid", ROOT / "configs" / "make_grid.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("n", [6, 8, 9, 10, 20, 30, 40, 50, 100])
def test_a_grid_of_n_has_n_robots_and_passes_check(n: int, tmp_path: Path) -> None:
    path = _module().write_grid(n, tmp_path)
    cfg = load_swarm(path)
    assert len(cfg.robots) == n
    assert run_check(path).exit_code == 0


def test_the_benchmark_sizes_keep_their_shapes() -> None:
    # 30 robots once came out as 24 (3 x 7 + 3): a shape must give exactly n robots.
    shape = _module().grid_shape
    assert [shape(n) for n in (10, 20, 30, 100)] == [(2, 4), (2, 9), (3, 9), (10, 9)]


@pytest.mark.parametrize("n", [1, 5, 7, 11])
def test_no_grid_of_a_size_that_makes_none(n: int) -> None:
    with pytest.raises(ValueError, match=f"no grid swarm of {n} robots"):
        _module().grid_shape(n)
