"""DESIGN section 1: imports point one way, package by package.

    core  <-  base (files, keys, identity, functions, logs, notify, eventlog)
          <-  transport, link  <-  config  <-  services (runtime, state, metrics, budget,
    launch)  <-  daemon (daemon, monitor, check)  <-  simulators (sim.shared <- sim.virtual
    / sim.physics / sim.xbee_emu <- sim.realtime <- sim.run)  <-  commands (swarmd.commands,
    swarmd.cli)

`swarmd/core` is sans-IO: no I/O module, no clock, no randomness, no pydantic, nothing
else of the project. Only the config layer imports pydantic. Every import counts, also
one inside a function (a lazy import is still a dependency of the module).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CORE = ROOT / "swarmd" / "core"
BANNED = {"asyncio", "socket", "time", "random", "serial", "logging", "threading",
          "select", "selectors", "subprocess", "os", "secrets", "datetime", "pydantic"}
"""What the core never imports: I/O, clocks (`time`, `datetime`: the driver passes
`now`), randomness (`random`, `secrets`: the driver passes seeds and keys) and the
config layer's validation library."""

ONLY_IN: dict[str, str] = {"pydantic": "config"}
"""Outside libraries only one group may import (DESIGN section 2: config validates)."""

GROUPS: dict[str, tuple[str, ...]] = {
    "core": ("swarmd.core",),
    "base": ("swarmd.files", "swarmd.keys", "swarmd.identity", "swarmd.functions",
             "swarmd.logs", "swarmd.notify", "swarmd.eventlog", "swarmd.signals",
             "swarmd.verify_budget"),
    "transport": ("swarmd.transport",),
    "link": ("swarmd.link",),
    "config": ("swarmd.config",),
    "services": ("swarmd.runtime", "swarmd.state", "swarmd.metrics", "swarmd.budget",
                 "swarmd.launch", "swarmd.revocation"),
    "daemon": ("swarmd.daemon", "swarmd.monitor", "swarmd.monitor_ros2", "swarmd.check",
               "swarmd.monitor_claims",
               "swarmd.waiting"),
    "sim.shared": ("sim.shared",),
    "sim.virtual": ("sim.virtual",),
    "sim.physics": ("sim.physics",),
    "sim.xbee_emu": ("sim.xbee_emu",),
    "sim.realtime": ("sim.realtime",),
    "sim.run": ("sim.run",),
    "commands": ("swarmd.commands", "swarmd.cli", "swarmd.__main__"),
}
"""Every project module belongs to exactly one group (longest prefix wins)."""

_EDGE = {"core", "base", "transport", "link", "config", "services"}
_BELOW_SIM = _EDGE | {"daemon"}
MAY_IMPORT: dict[str, set[str]] = {
    "core": {"core"},
    "base": {"core", "base"},
    "transport": {"core", "base", "transport"},
    "link": {"core", "base", "link"},
    "config": {"core", "base", "transport", "config"},
    "services": _EDGE,
    "daemon": _BELOW_SIM,
    "sim.shared": _BELOW_SIM | {"sim.shared"},
    "sim.virtual": _BELOW_SIM | {"sim.shared", "sim.virtual"},
    "sim.physics": _BELOW_SIM | {"sim.shared", "sim.physics"},
    "sim.xbee_emu": _BELOW_SIM | {"sim.shared", "sim.xbee_emu"},
    "sim.realtime": _BELOW_SIM | {"sim.shared", "sim.physics", "sim.xbee_emu",
                                  "sim.realtime"},
    "sim.run": _BELOW_SIM | {"sim.shared", "sim.virtual", "sim.physics", "sim.xbee_emu",
                             "sim.realtime", "sim.run"},
    "commands": set(GROUPS),
}
"""Which groups a group may import: its own and those below it, never one above or
beside it (a transport knows no link, a link no transport)."""


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(path: Path, module: str | None = None) -> list[str]:
    """Absolute names of every module a file imports (relative imports resolved)."""
    module = module or module_name(path)
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    tree = ast.parse(path.read_text(), filename=str(path))
    out: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                if node.module:
                    out.append(".".join([*base, node.module]))
                else:
                    out.extend(".".join([*base, a.name]) for a in node.names)
            elif node.module:
                if node.module in {"swarmd", "sim"}:
                    # `from swarmd import daemon` imports a module, `from swarmd import
                    # __version__` the package root.
                    out.extend(f"{node.module}.{a.name}"
                               if _is_module(f"{node.module}.{a.name}") else node.module
                               for a in node.names)
                else:
                    out.append(node.module)
    return out


def _is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.is_dir() or path.with_suffix(".py").exists()


def group_of(module: str) -> str | None:
    """The group of a project module; None for the bare package roots and outside modules."""
    best: tuple[int, str] | None = None
    for group, prefixes in GROUPS.items():
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and (
                    best is None or len(prefix) > best[0]):
                best = (len(prefix), group)
    return best[1] if best else None


def wrong_way(module: str, imports: list[str]) -> list[str]:
    """The imports of `module` that point up or sideways (DESIGN section 1), or reach a
    library only another group may use (`ONLY_IN`)."""
    source = group_of(module)
    assert source is not None, f"{module} belongs to no layer: add it to GROUPS"
    bad = []
    for name in imports:
        top = name.split(".")[0]
        if top in ONLY_IN and ONLY_IN[top] != source:
            bad.append(f"{name} (only {ONLY_IN[top]})")
            continue
        if top not in {"swarmd", "sim"} or name in {"swarmd", "sim"}:
            continue
        target = group_of(name)
        if target is None or target not in MAY_IMPORT[source]:
            bad.append(f"{name} ({target})")
    return bad


PROJECT_FILES = sorted(p for d in ("swarmd", "sim") for p in (ROOT / d).rglob("*.py"))
CORE_FILES = sorted(CORE.glob("*.py"))


def test_core_has_modules() -> None:
    assert {p.name for p in CORE_FILES} >= {"node.py", "wire.py", "params.py", "plan.py"}


@pytest.mark.parametrize("path", CORE_FILES, ids=lambda p: p.name)
def test_core_module_is_sans_io(path: Path) -> None:
    bad = [name for name in imported_modules(path)
           if name.split(".")[0] in BANNED or group_of(name) not in {None, "core"}]
    assert not bad, f"{path.name} imports {bad} (DESIGN section 1: core does no I/O)"


@pytest.mark.parametrize("path", PROJECT_FILES, ids=lambda p: module_name(p))
def test_imports_point_one_way(path: Path) -> None:
    module = module_name(path)
    if module in {"swarmd", "sim"}:
        assert not [m for m in imported_modules(path) if m.split(".")[0] in {"swarmd", "sim"}]
        return
    bad = wrong_way(module, imported_modules(path))
    assert not bad, f"{module} ({group_of(module)}) imports {bad}: DESIGN section 1 layering"


def test_checker_catches_a_banned_import(tmp_path: Path) -> None:
    sample = tmp_path / "x.py"
    sample.write_text("import time\nfrom swarmd import daemon\nfrom ..transport import udp\n")
    assert imported_modules(sample, "swarmd.core.x") == [
        "time", "swarmd.daemon", "swarmd.transport"]


def test_checker_catches_an_import_the_wrong_way(tmp_path: Path) -> None:
    # The shape of the mistake the layout exists to prevent: the daemon's config check
    # reaching into the physics simulator (a robot install has no MuJoCo), a shared
    # summary importing the real-time orchestrator, a transport importing the emulator.
    sample = tmp_path / "check.py"
    sample.write_text("def f():\n    from sim.physics.model import CRAFTS\n")
    assert wrong_way("swarmd.check", imported_modules(sample, "swarmd.check")) == [
        "sim.physics.model (sim.physics)"]
    assert wrong_way("sim.shared.summary", ["sim.realtime.orchestrator"]) == [
        "sim.realtime.orchestrator (sim.realtime)"]
    assert wrong_way("swarmd.transport.xbee", ["sim.xbee_emu.radio"]) == [
        "sim.xbee_emu.radio (sim.xbee_emu)"]
    assert wrong_way("sim.virtual.simulator", ["sim.physics.robot"]) != []
    assert wrong_way("sim.realtime.orchestrator", ["sim.physics.link", "swarmd.core"]) == []
    # Package by package: a transport never reaches a link, nor the config layer a
    # runtime; pydantic stays in the config layer.
    assert wrong_way("swarmd.transport.udp", ["swarmd.link.base"]) == [
        "swarmd.link.base (link)"]
    assert wrong_way("swarmd.config.robot", ["swarmd.runtime"]) == [
        "swarmd.runtime (services)"]
    assert wrong_way("swarmd.monitor", ["pydantic"]) == ["pydantic (only config)"]
    assert wrong_way("swarmd.config.robot", ["pydantic", "swarmd.transport.media"]) == []


def test_core_bans_clocks_randomness_and_pydantic(tmp_path: Path) -> None:
    sample = tmp_path / "x.py"
    sample.write_text("import secrets\nfrom datetime import datetime\nimport pydantic\n")
    assert [n for n in imported_modules(sample, "swarmd.core.x")
            if n.split(".")[0] in BANNED] == ["secrets", "datetime", "pydantic"]


def _core_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle among the modules of `graph` (name -> names it imports), or []."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str]:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                return [*stack[stack.index(n):], n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return []

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return []


def test_core_imports_form_no_cycle() -> None:
    """Inside swarmd.core every import points one way, lazy ones included: a module that
    needs another's name imports it, never the other way round at run time."""
    graph = {module_name(p): {n for n in imported_modules(p)
                              if n.startswith("swarmd.core.") and n != module_name(p)}
             for p in CORE_FILES if p.name != "__init__.py"}
    assert _core_cycle(graph) == []


def test_the_cycle_finder_finds_one() -> None:
    assert _core_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _core_cycle({"a": {"b"}, "b": set()}) == []


SIZE_LIMITS = (40, 600)
"""Lines of one function, and of one module, in swarmd/ and sim/ (DESIGN section 1: a
module a newcomer reads in one sitting; a function that does one thing)."""


def oversized(paths: list[Path]) -> list[str]:
    """The functions and modules of `paths` over `SIZE_LIMITS`, as `path:name lines`."""
    fn_max, mod_max = SIZE_LIMITS
    out = []
    for p in paths:
        text = p.read_text()
        name = p.relative_to(ROOT) if p.is_relative_to(ROOT) else p
        if text.count("\n") > mod_max:
            out.append(f"{name} {text.count(chr(10))}")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = (node.end_lineno or node.lineno) - node.lineno + 1
                if lines > fn_max:
                    out.append(f"{name}:{node.name} {lines}")
    return out


def test_no_function_or_module_is_over_the_size_limits() -> None:
    paths = sorted([*(ROOT / "swarmd").rglob("*.py"), *(ROOT / "sim").rglob("*.py")])
    assert oversized(paths) == []


def test_the_size_check_finds_a_long_function(tmp_path: Path) -> None:
    long = tmp_path / "long.py"
    long.write_text("def f() -> None:\n" + "    x = 1\n" * 40)
    assert oversized([long]) != []
    long.write_text("def f() -> None:\n" + "    x = 1\n" * 39)
    assert oversized([long]) == []
