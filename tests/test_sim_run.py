"""`swarmd sim` as options -> run -> result (sim.run): what is refused before anything
runs (bad options, output paths, the missing `sim` extra), through the CLI, each with its
exit code and its one line; and a virtual run's result with its events as a field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

import sim.run
from sim.run import EXTRA_HINT, SimError, SimOptions, run_sim
from swarmd.cli import app

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
runner = CliRunner()


def _sim(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, ["sim", str(PAPER), "--duration", "1", *args])
    return result.exit_code, result.stderr


@pytest.fixture
def nothing_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    """A refused run must not reach a simulator: reaching one fails the test."""
    def boom(*args: object, **kwargs: object) -> None:
        raise AssertionError("a simulator started")

    monkeypatch.setattr(sim.run, "_run_virtual", boom)
    monkeypatch.setattr(sim.run, "_run_realtime", boom)


def test_events_that_is_a_directory_is_refused(tmp_path: Path, nothing_runs: None) -> None:
    code, err = _sim("--virtual", "--events", str(tmp_path))
    assert code == 2
    assert err.strip() == f"--events: {tmp_path} is a directory; give a file name in it"


def test_events_under_a_file_is_refused(tmp_path: Path, nothing_runs: None) -> None:
    (tmp_path / "f").write_text("mine")
    code, err = _sim("--virtual", "--events", str(tmp_path / "f" / "events.jsonl"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{tmp_path / 'f'} is not a directory" in err
    assert (tmp_path / "f").read_text() == "mine"


@pytest.mark.skipif(not Path("/proc/version").exists(), reason="needs Linux /proc")
def test_unwritable_events_file_and_parent_are_refused(nothing_runs: None) -> None:
    # /proc refuses new files and writes to /proc/version, even for root (who passes
    # every permission check): only trying to write tells.
    code, err = _sim("--virtual", "--events", "/proc/version")
    assert code == 2 and err.startswith("--events: /proc/version cannot be written")
    code, err = _sim("--virtual", "--events", "/proc/swarmd-test/events.jsonl")
    assert code == 2
    assert err.startswith("--events: /proc/swarmd-test/events.jsonl cannot be written: /proc")


def test_report_under_a_file_is_refused_and_nothing_is_created(
        tmp_path: Path, nothing_runs: None) -> None:
    (tmp_path / "f").write_text("mine")
    code, err = _sim("--no-physics", "--report", str(tmp_path / "f" / "out"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith(f"--report: {tmp_path / 'f' / 'out'} cannot be written")


@pytest.mark.skipif(not Path("/proc/version").exists(), reason="needs Linux /proc")
def test_unwritable_report_parent_is_refused(nothing_runs: None) -> None:
    code, err = _sim("--virtual", "--report", "/proc/swarmd-test")
    assert code == 2 and err.startswith("--report: /proc/swarmd-test cannot be written")


def test_physics_without_the_extra_says_what_to_install(
        monkeypatch: pytest.MonkeyPatch, nothing_runs: None) -> None:
    monkeypatch.setattr(sim.run, "installed", lambda m: m != "mujoco")
    code, err = _sim()
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "flying MuJoCo quadrotors needs the simulation extra" in err
    assert EXTRA_HINT in err and EXTRA_HINT == "pip install 'swarmd[sim]'"


def test_report_pictures_without_the_extra_say_what_to_install(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, nothing_runs: None) -> None:
    monkeypatch.setattr(sim.run, "installed", lambda m: m != "matplotlib")
    code, err = _sim("--virtual", "--report", str(tmp_path / "out"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "pictures of --report" in err and EXTRA_HINT in err
    assert not (tmp_path / "out").exists()


def test_a_run_without_pictures_needs_no_extra(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The lean install: --virtual without --report imports none of the extra.
    monkeypatch.setattr(sim.run, "installed", lambda m: False)
    code, _ = _sim("--virtual", "--events", str(tmp_path / "e.jsonl"))
    assert code == 0
    lines = (tmp_path / "e.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    assert sorted(e["robot"] for e in records if e["event"] == "started") == [1, 2, 3, 4, 5, 6]
    assert [e["event"] for e in records[6:]] == ["stopped"] * 6  # the end of the run


@pytest.mark.parametrize(("kw", "words"), [
    ({"duration": 0.0}, "--duration: 0 is not above 0"),
    ({"loss": 1.5}, "--loss: 1.5 is not between 0 and 1"),
    ({"faults": ("crash:2",)}, "--fault: "),
    ({"virtual": True, "craft": "x2"}, "--craft: only with physics"),
])
def test_options_refuse_a_bad_value_when_built(kw: dict[str, object], words: str) -> None:
    with pytest.raises(SimError) as info:
        SimOptions(swarm=PAPER, **kw)  # type: ignore[arg-type]
    assert len(info.value.lines) == 1 and info.value.lines[0].startswith(words)


def test_a_virtual_run_returns_its_events_and_writes_them(tmp_path: Path) -> None:
    events = tmp_path / "deep" / "events.jsonl"
    result = run_sim(SimOptions(swarm=PAPER, virtual=True, duration=8.0, seed=1,
                                faults=("crash:2@2",), events=events))
    assert result.t0 is None and result.interrupted is None
    assert not any(k.startswith("_") for k in result.summary.extra)
    written = [json.loads(line) for line in events.read_text().splitlines()]
    assert written == json.loads(json.dumps(result.events))
    assert {"fault", "takeover"} <= {e["event"] for e in written}
