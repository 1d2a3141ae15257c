"""Config problems: every one names the file, the field path and what is wrong.

DESIGN.md section 3: "pydantic validates both and every error names the file and the
field". A problem is data (file, field, message, severity, line) so `swarmd check` can
print all of them at once, as text or JSON, instead of stopping at the first.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

Severity = Literal["error", "warning"]
Loc = tuple[str | int, ...]


def format_loc(loc: Loc) -> str:
    """`("robots", 2, "neighbors")` -> `robots[2].neighbors` (empty path -> `<top>`)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else part
    return out or "<top>"


@dataclass(frozen=True, slots=True)
class Problem:
    """One thing wrong (or doubtful) in a config file."""

    file: str
    field: str
    """Dotted path of the field, list items as `[i]` (0-based): `robots[2].neighbors`."""
    message: str
    severity: Severity = "error"
    line: int | None = None
    """1-based line of the field in the file, when known."""

    def __str__(self) -> str:
        where = f" (line {self.line})" if self.line is not None else ""
        tag = "warning: " if self.severity == "warning" else ""
        return f"{self.file}: {self.field}: {tag}{self.message}{where}"

    def as_json(self) -> dict[str, str | int | None]:
        return {
            "file": self.file,
            "field": self.field,
            "message": self.message,
            "severity": self.severity,
            "line": self.line,
        }


class ConfigError(Exception):
    """A config file that cannot be used; carries every problem found (warnings too)."""

    def __init__(self, problems: Iterable[Problem]) -> None:
        self.problems: tuple[Problem, ...] = tuple(problems)
        super().__init__("\n".join(str(p) for p in self.problems))

    @property
    def errors(self) -> tuple[Problem, ...]:
        return tuple(p for p in self.problems if p.severity == "error")

    @property
    def warnings(self) -> tuple[Problem, ...]:
        return tuple(p for p in self.problems if p.severity == "warning")


class ConfigUnreadable(ConfigError):
    """The file could not be read at all (missing, a directory, no permission, not
    UTF-8). `swarmd check` exits 2 on this, 1 on any other error."""


def has_errors(problems: Sequence[Problem]) -> bool:
    return any(p.severity == "error" for p in problems)
