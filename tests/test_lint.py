"""ruff and mypy --strict run as part of the tests."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600, check=False)


# The interpreter's own ruff (`python -m ruff`, as `_run` calls it), not one on PATH: the
# suite runs from the checkout's .venv, whose bin/ is usually not on PATH.
@pytest.mark.skipif(importlib.util.find_spec("ruff") is None,
                    reason="ruff is not installed (pip install -e '.[dev]')")
def test_ruff_clean() -> None:
    proc = _run("ruff", "check", ".")
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_strict_clean() -> None:
    proc = _run("mypy")  # files and strictness from pyproject.toml
    assert proc.returncode == 0, proc.stdout[-5000:] + proc.stderr[-2000:]
