"""DESIGN section 1: swarmd/core is sans-IO and imports nothing else of the project."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parent.parent / "swarmd" / "core"
BANNED = {"asyncio", "socket", "time", "random", "serial", "logging", "threading",
          "select", "selectors", "subprocess", "os"}


def imported_modules(path: Path) -> list[str]:
    """Absolute names of every module a file imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ["swarmd", "core"][: max(0, 2 - (node.level - 1))]
                out.append(".".join([*base, node.module] if node.module else base))
            elif node.module:
                out.append(node.module)
    return out


CORE_FILES = sorted(CORE.glob("*.py"))


def test_core_has_modules() -> None:
    assert {p.name for p in CORE_FILES} >= {"node.py", "wire.py", "params.py", "plan.py"}


@pytest.mark.parametrize("path", CORE_FILES, ids=lambda p: p.name)
def test_core_module_is_sans_io(path: Path) -> None:
    bad = []
    for name in imported_modules(path):
        top = name.split(".")[0]
        outside_core = top in {"swarmd", "sim"} and not name.startswith("swarmd.core.") \
            and name != "swarmd.core"
        if top in BANNED or outside_core:
            bad.append(name)
    assert not bad, f"{path.name} imports {bad} (DESIGN section 1: core does no I/O)"


def test_checker_catches_a_banned_import(tmp_path: Path) -> None:
    sample = tmp_path / "x.py"
    sample.write_text("import time\nfrom swarmd import daemon\nfrom ..transport import udp\n")
    assert imported_modules(sample) == ["time", "swarmd", "swarmd.transport"]
