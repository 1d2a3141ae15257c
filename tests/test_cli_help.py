"""The CLI explains itself, and the docs name only commands and options that exist.

Contracts guarded here: every command and subcommand answers `--help` with exit 0, says
its exit codes and shows an example of itself; every option and argument has a help
text; every `swarmd ...` command line in README.md and docs/*.md resolves to a real
command whose options exist; the README's list of `swarmd sim` options is exactly the
options `swarmd sim` has (DESIGN section 3: the CLI is an outside contract).
"""

from __future__ import annotations

import re
import shlex
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.core import TyperGroup
from typer.testing import CliRunner

from swarmd.cli import app

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
runner = CliRunner()


# Typer vends its own copy of click: commands are typed loosely here on purpose.
def _walk(cmd: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], Any]]:
    """Every command of the tree with its path (`()` is `swarmd` itself)."""
    yield path, cmd
    if isinstance(cmd, TyperGroup):
        for name, sub in sorted(cmd.commands.items()):
            yield from _walk(sub, (*path, name))


ROOT_CMD = typer.main.get_command(app)
COMMANDS = dict(_walk(ROOT_CMD))


def _options(cmd: Any) -> set[str]:
    """Every option name of `cmd`, with the `--help` click adds to each command."""
    names = {o for p in cmd.params for o in (*p.opts, *p.secondary_opts) if o.startswith("-")}
    return names | {"--help"}


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=lambda p: " ".join(p) or "swarmd")
def test_help_exits_0_with_exit_codes_and_an_example(path: tuple[str, ...]) -> None:
    result = runner.invoke(app, [*path, "--help"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())  # rich wraps and pads; compare words
    assert "Example: swarmd " + " ".join(path) in text, text
    if not isinstance(COMMANDS[path], TyperGroup):
        assert "Exit codes: 0 " in text, text


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=lambda p: " ".join(p) or "swarmd")
def test_help_shows_brackets_it_was_given(path: tuple[str, ...]) -> None:
    """Help text is rich markup: an unescaped `[ros2]` vanishes from it. Every `[` a
    help string holds (`swarmd[ros2]`, `[--write]`) must reach the screen."""
    cmd = COMMANDS[path]
    said = [p.help or "" for p in cmd.params if hasattr(p, "help")] + [cmd.help or ""]
    wanted = {w for h in said for w in h.replace("\\[", "[").split() if "[" in w}
    text = runner.invoke(app, [*path, "--help"], env={"COLUMNS": "400"}).output
    for word in wanted:
        assert word.strip(".,;()") in text, (word, path)


@pytest.mark.parametrize("path", sorted(p for p, c in COMMANDS.items()
                                        if not isinstance(c, TyperGroup)),
                         ids=" ".join)
def test_every_option_and_argument_has_help(path: tuple[str, ...]) -> None:
    for param in COMMANDS[path].params:
        assert (getattr(param, "help", None) or "").strip(), (path, param.name)


def _command_lines(text: str) -> Iterator[str]:
    """`swarmd ...` command lines of a Markdown text: in fenced blocks (continuation
    lines joined, `$ ` / `sudo ` prompts dropped) and in inline code spans."""
    fenced = re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)
    for block in fenced:
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"^\s*(\$\s+)?(sudo\s+)?", "", line)
            if line.startswith("swarmd "):
                yield line.split(" #", 1)[0]
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    yield from re.findall(r"`(swarmd [^`]+)`", prose)


def _resolve(words: list[str]) -> tuple[tuple[str, ...], list[str]]:
    """The longest command path at the start of `words`, and the words after it."""
    path: tuple[str, ...] = ()
    while words and (*path, words[0]) in COMMANDS:
        path, words = (*path, words[0]), words[1:]
    return path, words


def test_documented_command_lines_name_real_commands_and_options() -> None:
    wrong: list[str] = []
    checked = 0
    for doc in DOCS:
        for line in _command_lines(doc.read_text(encoding="utf-8")):
            words = shlex.split(line.replace("[", " ").replace("]", " "))[1:]
            path, rest = _resolve(words)
            if rest and not path and not rest[0].startswith("-"):
                wrong.append(f"{doc.name}: {line!r}: no such command")
                continue
            known = _options(COMMANDS[path])
            for word in rest:
                flag = word.split("=", 1)[0]
                if re.fullmatch(r"--?[A-Za-z][\w-]*", flag) and flag not in known:
                    wrong.append(f"{doc.name}: {line!r}: {' '.join(path)} has no {flag}")
            checked += 1
    assert checked > 20  # the parser still finds the docs' command lines
    assert not wrong, "\n".join(wrong)


def test_readme_lists_exactly_the_sim_options() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    paragraph = re.search(r"^`swarmd sim` options:(.*?)\n\n", readme, flags=re.S | re.M)
    assert paragraph is not None, "README lost its paragraph of `swarmd sim` options"
    listed = set(re.findall(r"--[a-z][a-z-]*", paragraph.group(1)))
    assert listed == _options(COMMANDS[("sim",)]) - {"--help"}


def test_install_script_help_is_its_header_only() -> None:
    result = subprocess.run(["bash", str(ROOT / "deploy" / "install.sh"), "--help"],
                            capture_output=True, text=True, timeout=10, check=False)
    assert result.returncode == 0, result.stderr
    assert "--root DIR" in result.stdout and "--uninstall" in result.stdout
    assert "set -" not in result.stdout  # the usage text stops before the code


def test_version_prints_the_package_version() -> None:
    from swarmd import __version__

    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and result.stdout.strip() == f"swarmd {__version__}"


def test_emulating_no_radio_is_a_usage_error() -> None:
    result = runner.invoke(app, ["xbee", "emulate", "0"])
    assert result.exit_code == 2 and "count" in result.output


def test_start_refuses_an_unknown_log_level_as_a_usage_error() -> None:
    result = runner.invoke(app, ["start", "-c", str(ROOT / "configs" / "robot-example.yaml"),
                                 "--log-level", "bogus"])
    assert result.exit_code == 2 and "'bogus' is not one of" in result.output


@pytest.mark.parametrize(("args", "words"), [
    (["--transport", "bogus"], "'bogus' is not one of udp, xbee, serial"),
    (["--virtual", "--transport", "xbee"], "--virtual has no channel"),
    (["--no-physics", "--craft", "x2"], "--craft: only with physics"),
    (["--virtual", "--no-physics"], "give one of the two"),
])
def test_sim_refuses_an_option_its_mode_would_ignore(args: list[str], words: str) -> None:
    result = runner.invoke(app, ["sim", str(ROOT / "configs" / "paper.yaml"), "--duration", "1",
                                 *args])
    assert result.exit_code == 2 and words in result.stderr


PAPER_ARGS = ["sim", str(ROOT / "configs" / "paper.yaml"), "--virtual"]


@pytest.mark.parametrize(("args", "option"), [
    ([*PAPER_ARGS, "--duration", "inf"], "--duration"),
    ([*PAPER_ARGS, "--duration", "1e400"], "--duration"),
    ([*PAPER_ARGS, "--duration", "nan"], "--duration"),
    ([*PAPER_ARGS, "--duration", "-5"], "--duration"),
    ([*PAPER_ARGS, "--seed", "-1"], "--seed"),
    ([*PAPER_ARGS, "--loss", "1"], "--loss"),
    ([*PAPER_ARGS, "--loss", "-0.1"], "--loss"),
    ([*PAPER_ARGS, "--loss", "nan"], "--loss"),
    ([*PAPER_ARGS, "--refuse-arm", "0"], "--refuse-arm"),
    (["monitor", "--swarm", str(ROOT / "configs" / "paper.yaml"), "--duration", "-5"],
     "--duration"),
    (["monitor", "--swarm", str(ROOT / "configs" / "paper.yaml"), "--duration", "0"],
     "--duration"),
    (["monitor", "--swarm", str(ROOT / "configs" / "paper.yaml"), "--duration", "inf"],
     "--duration"),
    (["monitor", "--swarm", str(ROOT / "configs" / "paper.yaml"), "--port", "70000"],
     "--port"),
    (["xbee", "emulate", "2", "--loss", "1.5"], "--loss"),
    (["xbee", "emulate", "2", "--delay", "-1"], "--delay"),
    (["xbee", "emulate", "2", "--delay", "inf"], "--delay"),
    (["xbee", "emulate", "2", "--seed", "-2"], "--seed"),
    (["xbee", "emulate", "2", "--api-mode", "3"], "--api-mode"),
    (["xbee", "info", "--port", "/dev/null", "--baud", "0"], "--baud"),
])
def test_a_bad_number_is_a_usage_error_naming_the_option(args: list[str], option: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert f"Invalid value for '{option}'" in " ".join(result.output.split())


def test_a_motor_fault_needs_a_flying_craft() -> None:
    result = runner.invoke(app, [*PAPER_ARGS, "--fault", "motor:2@5"])
    assert result.exit_code == 2
    assert "unhealthy:2@5 is what a failed motor does" in result.stderr
