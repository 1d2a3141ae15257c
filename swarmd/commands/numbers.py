"""The check typer's `min=` / `max=` cannot make: a range check compares, and `inf`
passes `min=0.1` (`--duration inf` would run forever). Every number option of the CLI
has a range (`min=`, `max=`) and every float one a callback here as well, so
a bad number is a usage error (exit 2) in one line, never a hang or a traceback."""

from __future__ import annotations

import math

import typer


def finite(value: float | None) -> float | None:
    """A float option that must be a real number: not `nan`, `inf` or `1e400`."""
    if value is not None and not math.isfinite(value):
        raise typer.BadParameter(f"{value} is not a finite number")
    return value



def positive(value: float | None) -> float | None:
    """A finite number of seconds above 0 (typer has no open lower bound)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"{value} is not a number of seconds above 0")
    return value


def probability(value: float) -> float:
    """A loss probability from 0 up to, not including, 1 (at 1 nothing gets through)."""
    if not 0.0 <= value < 1.0:  # also refuses nan: every comparison with it is False
        raise typer.BadParameter(f"{value} is not a probability from 0 to below 1")
    return value
