"""docs/DESIGN.md walks one failover with the times of a real run: they must stay true."""

from __future__ import annotations

import re
from pathlib import Path

from sim.shared.faults import parse_fault
from sim.virtual.simulator import run_virtual
from swarmd.config import load_swarm
from swarmd.core import params

ROOT = Path(__file__).resolve().parent.parent


def _walk() -> str:
    text = (ROOT / "docs" / "DESIGN.md").read_text(encoding="utf-8")
    return text[text.index("## One failover, crash to takeover"):text.index("## 1. Layout")]


def test_the_walked_failover_is_what_the_simulator_does() -> None:
    cfg = load_swarm(ROOT / "configs" / "paper.yaml")
    assert cfg.params() == params.udp()
    result = run_virtual(cfg.to_plan(), cfg.params(), duration=15.0, seed=1,
                         auth="per-robot", faults=[parse_fault("crash:2@5")])
    walk = _walk()
    for e in result.events:
        if e["t"] >= 5.0 and e["event"] in ("suspect", "vote", "claim", "takeover"):
            row = next((line for line in walk.splitlines()
                        if line.startswith(f"| {e['t']} |")), None)
            assert row is not None and f"`{e['event']}`" in row, e
    started = next(e["t"] for e in result.events if e["robot"] == 2 and e["event"] == "started")
    assert f"from its start at {started}" in walk
    p = params.udp()
    for name in ("heartbeat_interval", "t_max", "warn_interval", "vote_window",
                 "claim_hold"):
        cited = re.search(rf"{name}\s+([0-9.]+) s", walk)
        assert cited is not None and float(cited.group(1)) == getattr(p, name), name


def test_every_step_of_the_walk_names_code_that_exists() -> None:
    """The walk's "where" column names `file.py:Class.method` in swarmd/core (and bare
    `_method`s of the class named before them): each must exist, so the walk cannot
    drift from the code it points a reader to. The failover crosses at most six files."""
    import ast

    rows = [line for line in _walk().splitlines() if line.startswith("| ") and "`" in line]
    files: set[str] = set()
    for row in rows:
        where = row.rstrip(" |").rsplit(" | ", 1)[-1]
        if where.startswith("`sim/"):
            continue
        cls = ""
        for file, name in re.findall(r"`(?:([a-z_]+\.py):)?([A-Za-z_.]+)`", where):
            if file:
                current = file
                files.add(file)
            if "." in name:
                cls, name = name.split(".")
            tree = ast.parse((ROOT / "swarmd" / "core" / current).read_text(encoding="utf-8"))
            found = {f"{c.name}.{f.name}" for c in tree.body if isinstance(c, ast.ClassDef)
                     for f in c.body if isinstance(f, ast.FunctionDef)}
            assert f"{cls}.{name}" in found, (row, current, cls, name)
    assert 3 <= len(files) <= 6, files
