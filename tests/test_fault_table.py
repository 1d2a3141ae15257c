"""One source for the fault kinds, and help that reads at 80 columns.

sim/shared/faults.py holds every fault kind, its SPEC form and what it does;
`swarmd sim --help` prints that table and README.md, docs/DESIGN.md and docs/sim.md hold
it between markers (`scripts/fault_table.py` rewrites them). A kind added there shows up
in the help at once, and these tests fail until the docs are rewritten.
"""

from __future__ import annotations

import itertools
import subprocess
import sys
from pathlib import Path

import pytest
from test_cli_help import COMMANDS
from typer.testing import CliRunner

from sim.shared import faults
from swarmd.cli import app, unwrap

ROOT = Path(__file__).resolve().parent.parent
runner = CliRunner()
WIDTH = 80


def _help(*path: str) -> str:
    result = runner.invoke(app, [*path, "--help"], env={"COLUMNS": str(WIDTH),
                                                        "TERMINAL_WIDTH": str(WIDTH)})
    assert result.exit_code == 0, result.output
    return result.output


def test_every_kind_has_a_form_and_a_sentence() -> None:
    assert set(faults.WHAT) == set(faults.KINDS) == set(faults._FORMS)
    for kind in faults.KINDS:
        assert faults._short_form(kind).startswith(kind + ":")
        assert faults.WHAT[kind].strip()


def test_the_docs_hold_the_current_table() -> None:
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "fault_table.py"),
                           "--check"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for name in ("README.md", "docs/DESIGN.md", "docs/sim.md"):
        assert faults.markdown_table() in (ROOT / name).read_text(encoding="utf-8")


def test_sim_help_lists_every_kind_within_80_columns() -> None:
    text = _help("sim")
    table = text[text.index("Fault kinds (--fault SPEC):"):]
    starts = [line.split()[0] for line in table.splitlines()[1:] if line[:2] == " " + line[1:2]
              and line[1:2].strip()]
    for kind in faults.KINDS:
        assert any(s.startswith(kind + ":") for s in starts), (kind, table)


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=lambda p: " ".join(p) or "swarmd")
def test_help_reads_at_80_columns(path: tuple[str, ...]) -> None:
    lines = _help(*path).splitlines()
    assert all(len(line) <= WIDTH for line in lines), [x for x in lines if len(x) > WIDTH]
    # The prose above the first panel: a line broken where the next word would still
    # have fitted is a line break of the source, not a wrap (one word left on a line).
    prose = lines[:next((i for i, x in enumerate(lines) if x.startswith("╭")), len(lines))]
    for line, after in itertools.pairwise(prose):
        if line.strip() and after.strip() and not after.lstrip().startswith("- "):
            room = WIDTH - 2 - len(line.rstrip())
            assert len(after.split()[0]) >= room, (line, after)


def test_unwrap_joins_lines_but_keeps_paragraphs_and_lists() -> None:
    text = """First line
        goes on.

        Second paragraph
        - an item
        - another
          indented"""
    assert unwrap(text) == ("First line goes on.\n\nSecond paragraph\n- an item\n- another\n"
                            "  indented")
