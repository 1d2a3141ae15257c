"""Rewrite the fault tables of the docs from sim/shared/faults.py, the one source.

    python scripts/fault_table.py          rewrite README.md, docs/DESIGN.md, docs/sim.md
    python scripts/fault_table.py --check  exit 1, naming the files, when one differs

Each file holds the table between a `<!-- fault-table -->` line and a
`<!-- /fault-table -->` line; what is between them is replaced, nothing else.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.shared.faults import markdown_table  # noqa: E402  (the checkout's, not an install's)

FILES = ("README.md", "docs/DESIGN.md", "docs/sim.md")
BLOCK = re.compile(r"(<!-- fault-table -->\n).*?(<!-- /fault-table -->)", re.S)


def synced(text: str) -> str:
    """`text` with every fault-table block holding the current table."""
    return BLOCK.sub(lambda m: m.group(1) + markdown_table() + "\n" + m.group(2), text)


def stale(root: Path = ROOT) -> list[str]:
    """Files whose table differs from the source, or that have no table."""
    out = []
    for name in FILES:
        text = (root / name).read_text(encoding="utf-8")
        if not BLOCK.search(text) or synced(text) != text:
            out.append(name)
    return out


def main(argv: list[str]) -> int:
    if "--check" in argv:
        bad = stale()
        for name in bad:
            print(f"{name}: fault table differs from sim/shared/faults.py "
                  "(run: python scripts/fault_table.py)")
        return 1 if bad else 0
    for name in FILES:
        path = ROOT / name
        text = path.read_text(encoding="utf-8")
        if not BLOCK.search(text):
            print(f"{name}: no <!-- fault-table --> block", file=sys.stderr)
            return 1
        path.write_text(synced(text), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
