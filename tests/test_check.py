"""`swarmd check`: exit codes 0/1/2, the coverage table, JSON, extensible sections."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner, Result

from swarmd.base.identity import write_identity
from swarmd.cli import app
from swarmd.config import SwarmConfig
from swarmd.daemon import check as check_mod
from swarmd.daemon.check import Section, run_check

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
runner = CliRunner()


def _paper_with(tmp_path: Path, **robot_changes: dict[str, object]) -> Path:
    doc = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    for index, change in robot_changes.items():
        doc["robots"][int(index.removeprefix("r"))].update(change)
    path = tmp_path / "swarm.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_check_paper_ok_with_table() -> None:
    result = runner.invoke(app, ["check", str(CONFIGS / "paper.yaml")])
    assert result.exit_code == 0, result.output
    rows = [line for line in result.output.splitlines() if "│ f" in line]
    assert len(rows) == 4
    f1 = [cell.strip() for cell in rows[0].split("│")[1:-1]]
    assert f1 == ["f1", "slot", "1", "2, 4", "5", "OK"]
    assert "t_max" in result.output
    assert "t_max + vote_window + claim_hold = 1.7 s" in result.output


def test_check_warning_no_standby_still_exit_0(tmp_path: Path) -> None:
    path = _paper_with(tmp_path, r4={"subs": [1]})
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 0, result.output
    assert f"{path}: functions.f4: warning: no standby covers f4" in result.output
    assert "NO STANDBY" in result.output


def test_check_errors_exit_1_and_lists_them_all(tmp_path: Path) -> None:
    path = _paper_with(tmp_path, r2={"neighbors": [2]}, r5={"subs": [2, 3, 9]})
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 1, result.output
    assert f"{path}: robots[5].subs: robot 9 is not in the swarm" in result.output
    assert f"{path}: functions.f4: watched by 1 robot(s)" in result.output
    assert "UNDER QUORUM" in result.output  # the table still shows the bad swarm


def test_check_yaml_syntax_exit_1(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("swarm: {id: 1\n")
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 1
    assert "YAML syntax error" in result.output


def test_check_unreadable_exit_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["check", str(tmp_path / "missing.yaml")])
    assert result.exit_code == 2
    assert "cannot read the file" in result.output


def test_check_json(tmp_path: Path) -> None:
    result = runner.invoke(app, ["check", "--json", str(CONFIGS / "ring12.yaml")])
    assert result.exit_code == 0
    data = json.loads(result.output)
    assert data["ok"] is True and data["problems"] == []
    assert [row["status"] for row in data["coverage"]] == ["OK"] * 12
    assert data["coverage"][0] == {
        "function": "f1", "kind": "slot", "holder": 1, "watchers": [2, 3, 11, 12],
        "standbys": [13], "status": "OK",
    }
    assert data["timing"]["takeover_bound_s"] == pytest.approx(1.7)  # 0.5 + 1.0 + 0.2
    bad = runner.invoke(app, ["check", "--json", str(_paper_with(tmp_path, r0={"id": 2}))])
    assert bad.exit_code == 1
    assert json.loads(bad.output)["problems"][0]["field"] == "robots[1].id"


def test_check_robot_file_checks_its_swarm(tmp_path: Path) -> None:
    for name in ("paper.yaml", "robot-example.yaml"):
        shutil.copy(CONFIGS / name, tmp_path / name)
    for robot in range(1, 7):
        write_identity(tmp_path / "keys", robot)
    result = runner.invoke(app, ["check", str(tmp_path / "robot-example.yaml")])
    assert result.exit_code == 0, result.output
    assert "│ f2 " in result.output
    assert "auth: per-robot (Ed25519)" in result.output


def test_check_prints_the_auth_mode_and_flags_an_unsigned_swarm(tmp_path: Path) -> None:
    signed = run_check(CONFIGS / "paper.yaml")
    assert signed.as_json()["auth"]["mode"] == "per-robot"
    assert not [p for p in signed.problems if p.field == "auth"]
    doc = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    del doc["auth"]
    (tmp_path / "quiet.yaml").write_text(yaml.safe_dump(doc))
    quiet = runner.invoke(app, ["check", str(tmp_path / "quiet.yaml")])
    assert quiet.exit_code == 0, quiet.output  # usable: a warning, not an error
    text = " ".join(quiet.output.split())
    assert "auth: warning: the swarm is unsigned and does not say so" in text
    assert "swarmd start refuses it" in text
    doc["auth"] = "none"
    (tmp_path / "none.yaml").write_text(yaml.safe_dump(doc))
    explicit = run_check(tmp_path / "none.yaml")
    assert explicit.exit_code == 0 and not explicit.problems
    assert explicit.as_json()["auth"] == {"mode": "none", "explicit": True, "keys_dir": None,
                                          "key_file": None, "revoked": []}


def test_sections_can_be_appended(monkeypatch: pytest.MonkeyPatch) -> None:
    def extra(cfg: SwarmConfig) -> Section:
        return Section("extra", "Extra", ("robots",), ((str(len(cfg.robots)),),), {"n": 6})

    monkeypatch.setattr(check_mod, "SECTIONS", [*check_mod.SECTIONS, extra])
    report = run_check(CONFIGS / "paper.yaml")
    assert [s.key for s in report.sections] == ["coverage", "timing", "auth",
                                                "channel_budget", "flight", "extra"]
    assert report.as_json()["extra"] == {"n": 6}


def _under_ground(tmp_path: Path) -> Path:
    doc = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    doc["functions"]["f3"] = {"kind": "patrol", "speed": 1.0,
                              "waypoints": [[0.0, 0.0, 1.0], [2.0, 0.0, -1.0]]}
    path = tmp_path / "under.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_check_says_which_function_the_simulated_craft_cannot_fly(tmp_path: Path) -> None:
    result = runner.invoke(app, ["check", str(_under_ground(tmp_path)), "--json"])
    flight = json.loads(result.stdout)["flight"]
    assert flight["f1"] == [] and flight["f2"] == []
    assert len(flight["f3"]) == 1 and "waypoints[1]" in flight["f3"][0]
    assert "under the ground" in flight["f3"][0]


def test_sim_with_physics_refuses_an_unflyable_function_before_starting(
        tmp_path: Path) -> None:
    path = _under_ground(tmp_path)
    result = runner.invoke(app, ["sim", str(path), "--duration", "2"])
    assert result.exit_code == 2
    assert "functions.f3.waypoints[1]" in result.stderr
    # The protocol alone does not care: the bare and virtual runs still go.
    assert runner.invoke(app, ["sim", str(path), "--virtual", "--duration", "2"]).exit_code == 0


def test_sim_refuses_a_fault_after_the_end_of_the_run() -> None:
    result = runner.invoke(app, ["sim", str(CONFIGS / "paper.yaml"), "--virtual",
                                 "--duration", "5", "--fault", "crash:2@7"])
    assert result.exit_code == 2
    assert "--duration 5" in result.stderr


def test_sim_prints_problems_as_plain_text(tmp_path: Path) -> None:
    # A `[x, y]` in a message is text, not rich markup; one problem per line.
    doc = yaml.safe_load((CONFIGS / "paper.yaml").read_text())
    doc["functions"]["f2"]["position"] = [2.0, 0.0]
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(doc))
    result = runner.invoke(app, ["sim", str(path), "--virtual"])
    assert result.exit_code == 2
    assert "functions.f2" in result.stderr and "[" in result.stderr, result.stderr


def test_check_counts_per_robot_fragments_instead_of_refusing_digimesh() -> None:
    report = run_check(CONFIGS / "paper-radio.yaml")
    rows = {row["medium"]: row for row in report.as_json()["channel_budget"]}
    assert (rows["digimesh"]["warn_fragments"], rows["digimesh"]["cert_fragments"]) == (2, 2)
    assert (rows["802.15.4"]["warn_fragments"], rows["802.15.4"]["cert_fragments"]) == (1, 1)
    section = next(s for s in report.sections if s.key == "channel_budget")
    notes = "\n".join(section.notes)
    assert ("digimesh: warning/claim (81 B) in 2, certificate (93 B) in 2, heartbeat anchor "
            "(88 B) in 2 fragments of "
            "<= 73 B") in notes
    # A WARN's belief byte (DESIGN "Detection") takes a certificate one byte past Zigbee's
    # 92 B: split in two, counted.
    assert "zigbee: certificate (93 B) in 2 fragments of <= 92 B" in notes
    assert "not split" not in notes and "cannot be sent" not in notes


def _last_line(result: Result) -> str:
    return result.output.rstrip().splitlines()[-1]


def test_the_last_line_counts_every_warning_printed_and_says_ok_only_when_clean(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # The paper swarm overloads Zigbee and DigiMesh (channel budget): usable, not "OK".
    report = run_check(CONFIGS / "paper.yaml")
    budget = next(s for s in report.sections if s.key == "channel_budget")
    assert budget.warnings and report.warnings == len(budget.warnings)
    result = runner.invoke(app, ["check", str(CONFIGS / "paper.yaml")])
    assert result.exit_code == 0
    assert _last_line(result) == (f"{CONFIGS / 'paper.yaml'}: usable, with "
                                  f"{report.warnings} warning(s) above (exit 0)")
    for line in budget.warnings:
        assert line in " ".join(result.output.split())
    assert json.loads(runner.invoke(app, ["check", str(CONFIGS / "paper.yaml"), "--json"])
                      .stdout)["warnings"] == report.warnings
    # Without the radio budget the paper swarm has nothing to say: "OK".
    monkeypatch.setattr(check_mod, "SECTIONS", [check_mod.coverage_section,
                                                check_mod.timing_section])
    clean = runner.invoke(app, ["check", str(CONFIGS / "paper.yaml")])
    assert clean.exit_code == 0, clean.output
    assert _last_line(clean) == f"{CONFIGS / 'paper.yaml'}: OK, no errors or warnings (exit 0)"


def test_the_last_line_of_a_swarm_with_errors_says_not_usable(tmp_path: Path) -> None:
    path = _paper_with(tmp_path, r2={"neighbors": [2]})
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 1, result.output
    assert _last_line(result).startswith(f"{path}: NOT usable: ")
    assert _last_line(result).endswith("(exit 1)")
