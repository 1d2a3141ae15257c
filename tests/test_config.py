"""Swarm and robot files: every error names the file and the field (DESIGN.md section 3)."""

from __future__ import annotations

import copy
import dataclasses
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from swarmd.base.identity import write_identity
from swarmd.config import (
    ConfigError,
    ConfigUnreadable,
    SerialTransportConfig,
    SocketLinkConfig,
    SwarmConfig,
    Timing,
    UdpTransportConfig,
    XBeeTransportConfig,
    load_robot,
    load_swarm,
    parse_robot,
    parse_swarm,
)
from swarmd.core.params import Params, radio, udp

CONFIGS = Path(__file__).resolve().parent.parent / "configs"

Doc = dict[str, Any]

BASE: Doc = {
    "swarm": {"id": 1543, "name": "t"},
    "timing": {"preset": "udp"},
    "auth": "none",
    "functions": {
        "f1": {"kind": "slot", "position": [2.0, 0.0, 1.5]},
        "f2": {"kind": "slot", "position": [0.0, 2.0, 1.5]},
        "f3": {"kind": "slot", "position": [-2.0, 0.0, 1.5]},
        "f4": {"kind": "patrol", "waypoints": [[0, -2, 1.5], [1, -2, 1.5]], "speed": 0.5},
    },
    "robots": [
        {"id": 1, "state": "active", "function": "f1", "neighbors": [2, 4]},
        {"id": 2, "state": "active", "function": "f2", "neighbors": [1, 3]},
        {"id": 3, "state": "active", "function": "f3", "neighbors": [2, 4]},
        {"id": 4, "state": "active", "function": "f4", "neighbors": [1, 3]},
        {"id": 5, "state": "standby", "subs": [1, 4]},
        {"id": 6, "state": "standby", "subs": [2, 3]},
    ],
}


def _write(tmp_path: Path, doc: Doc | str, name: str = "swarm.yaml") -> Path:
    path = tmp_path / name
    path.write_text(doc if isinstance(doc, str) else yaml.safe_dump(doc))
    return path


def _edit(change: Callable[[Doc], object]) -> Doc:
    doc = copy.deepcopy(BASE)
    change(doc)
    return doc


def _set(path: tuple[str | int, ...], value: Any) -> Callable[[Doc], None]:
    def change(doc: Doc) -> None:
        target: Any = doc
        for part in path[:-1]:
            target = target[part]
        target[path[-1]] = value

    return change


def _drop(path: tuple[str | int, ...]) -> Callable[[Doc], None]:
    def change(doc: Doc) -> None:
        target: Any = doc
        for part in path[:-1]:
            target = target[part]
        del target[path[-1]]

    return change


# (case id, document, field path named, fragment of the message)
ERROR_CASES: list[tuple[str, Doc | str, str, str]] = [
    ("yaml syntax", "swarm: {id: 1\nrobots: [\n", "<yaml>", "YAML syntax error"),
    ("top not a mapping", "- 1\n- 2\n", "<top>", "expected a YAML mapping"),
    ("empty file", "", "<top>", "empty file"),
    ("duplicate yaml key",
     "swarm: {id: 1}\nfunctions:\n  f1: {kind: slot, position: [0, 0, 1]}\n"
     "  f1: {kind: slot, position: [1, 0, 1]}\nrobots: [{id: 1, state: active}]\n",
     "functions.f1", "key given twice"),
    ("unknown neighbour", _edit(_set(("robots", 0, "neighbors"), [2, 4, 9])),
     "robots[0].neighbors", "robot 9 is not in the swarm"),
    ("duplicate robot id", _edit(_set(("robots", 5, "id"), 5)),
     "robots[5].id", "robot id 5 is used twice"),
    ("duplicate holder", _edit(_set(("robots", 1, "function"), "f1")),
     "robots[1].function", "already held by robot 1"),
    ("function nobody holds", _edit(_set(("functions", "f9"), {"kind": "slot",
                                                             "position": [5, 5, 1.5]})),
     "functions.f9", "no active robot holds f9"),
    # An active robot without `function` holds f<id>: robot 7 -> f7, not defined here.
    ("default function undefined",
     _edit(lambda d: d["robots"].append({"id": 7, "state": "active", "neighbors": [1, 2]})),
     "robots[6].function", "'f7' (the default for an active robot) is not defined"),
    ("standby neighbour", _edit(_set(("robots", 0, "neighbors"), [2, 4, 5])),
     "robots[0].neighbors", "robot 5 is a standby"),
    ("self neighbour", _edit(_set(("robots", 0, "neighbors"), [1, 2, 4])),
     "robots[0].neighbors", "lists itself"),
    ("repeated neighbour", _edit(_set(("robots", 0, "neighbors"), [2, 2, 4])),
     "robots[0].neighbors", "listed twice"),
    ("under quorum", _edit(_set(("robots", 2, "neighbors"), [2])),
     "functions.f4", "fewer than the quorum of 2"),
    ("quorum override", _edit(_set(("timing", "quorum"), 3)),
     "functions.f1", "fewer than the quorum of 3"),
    ("t_max too short", _edit(_set(("timing", "t_max"), 0.15)),
     "timing.t_max", "shorter than two heartbeat intervals"),
    ("heartbeat too slow", _edit(_set(("timing", "heartbeat_interval"), 0.3)),
     "timing.heartbeat_interval", "shorter than two heartbeat intervals"),
    ("negative timing", _edit(_set(("timing", "claim_hold"), -1)),
     "timing.claim_hold", "positive"),
    ("unknown preset", _edit(_set(("timing", "preset"), "wifi")),
     "timing.preset", "'udp' or 'radio'"),
    ("typo in robot key", _edit(_set(("robots", 0, "neighbours"), [2])),
     "robots[0].neighbours", "did you mean 'neighbors'"),
    ("typo at top", _edit(_set(("timming",), {})), "timming", "did you mean 'timing'"),
    ("unknown kind", _edit(_set(("functions", "f1", "kind"), "circle")),
     "functions.f1", "unknown kind 'circle'"),
    ("missing kind", _edit(_drop(("functions", "f1", "kind"))),
     "functions.f1", "'kind' is missing"),
    ("short position", _edit(_set(("functions", "f1", "position"), [1, 2])),
     "functions.f1.position", "too few items"),
    ("one waypoint", _edit(_set(("functions", "f4", "waypoints"), [[0, 0, 1]])),
     "functions.f4.waypoints", "at least 2"),
    ("zero speed", _edit(_set(("functions", "f4", "speed"), 0)),
     "functions.f4.speed", "greater than 0"),
    ("slot field on patrol", _edit(_set(("functions", "f4", "position"), [0, 0, 1])),
     "functions.f4.position", "belongs to another kind"),
    ("bad function name", _edit(lambda d: d["functions"].update({"9x": d["functions"]["f1"]})),
     "functions.9x", "must start with a letter"),
    ("standby with function", _edit(_set(("robots", 4, "function"), "f1")),
     "robots[4].function", "is a standby and holds no function"),
    ("standby with neighbours", _edit(_set(("robots", 4, "neighbors"), [1])),
     "robots[4].neighbors", "standbys watch nobody"),
    ("active with subs", _edit(_set(("robots", 0, "subs"), [2])),
     "robots[0].subs", "only standby robots substitute"),
    ("subs unknown robot", _edit(_set(("robots", 4, "subs"), [1, 42])),
     "robots[4].subs", "robot 42 is not in the swarm"),
    ("subs a standby", _edit(_set(("robots", 4, "subs"), [1, 4, 6])),
     "robots[4].subs", "robot 6 is a standby"),
    ("subs unknown function", _edit(_set(("robots", 4, "subs"), ["f1", "f9"])),
     "robots[4].subs", "function 'f9' is not defined"),
    ("subs bad type", _edit(_set(("robots", 4, "subs"), [1.5])),
     "robots[4].subs[0]", "robot id or a function name"),
    ("bad state", _edit(_set(("robots", 0, "state"), "sleeping")),
     "robots[0].state", "'active' or 'standby'"),
    ("swarm id too big", _edit(_set(("swarm", "id"), 70000)),
     "swarm.id", "less than or equal to 65535"),
    ("swarm missing", _edit(_drop(("swarm",))), "swarm", "required field is missing"),
    ("no robots", _edit(_set(("robots",), [])), "robots", "at least 1"),
    ("recursive alias", "a: &b {c: *b}\n", "a.c", "recursive YAML alias"),
    ("nan timing", _edit(_set(("timing", "t_max"), float("nan"))),
     "timing.t_max", "finite number"),
    ("numeric function name", _edit(lambda d: d["functions"].update({1: {"kind": "slot"}})),
     "functions[1]", "valid string"),
    ("robot not a mapping", _edit(_set(("robots", 0), 1)), "robots[0]", "valid dictionary"),
    ("key file missing", _edit(_set(("auth",), {"mode": "shared", "key_file": "nope.key"})),
     "auth.key_file", "nope.key"),
    ("legacy key file missing", {k: v for k, v in BASE.items() if k != "auth"}
     | {"key_file": "nope.key"}, "key_file", "nope.key"),
]

@pytest.mark.parametrize(
    ("doc", "field", "fragment"),
    [pytest.param(d, f, m, id=name) for name, d, f, m in ERROR_CASES],
)
def test_load_swarm_error_names_file_and_field(
    tmp_path: Path, doc: Doc | str, field: str, fragment: str
) -> None:
    path = _write(tmp_path, doc)
    with pytest.raises(ConfigError) as info:
        load_swarm(path)
    errors = info.value.errors
    assert errors, info.value.problems
    matching = [p for p in errors if p.field == field and fragment in p.message]
    assert matching, "\n".join(map(str, info.value.problems))
    assert str(matching[0]).startswith(f"{path}: {field}: ")


def test_errors_are_all_reported_at_once(tmp_path: Path) -> None:
    doc = _edit(_set(("robots", 0, "neighbors"), [2, 4, 9]))
    doc["robots"][5]["subs"] = [2, 77]
    with pytest.raises(ConfigError) as info:
        load_swarm(_write(tmp_path, doc))
    fields = {p.field for p in info.value.errors}
    assert {"robots[0].neighbors", "robots[5].subs"} <= fields


def test_error_carries_the_line_of_the_field(tmp_path: Path) -> None:
    text = (CONFIGS / "paper.yaml").read_text().replace("neighbors: [2, 4], home: [-0.5",
                                                         "neighbors: [2, 4, 9], home: [-0.5")
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_swarm(path)
    (problem,) = info.value.errors
    line = next(i for i, t in enumerate(text.splitlines(), 1) if "[2, 4, 9]" in t)
    assert (problem.field, problem.line) == ("robots[2].neighbors", line)
    assert str(problem).endswith(f"(line {line})")


def test_yaml_syntax_error_has_line(tmp_path: Path) -> None:
    path = _write(tmp_path, "swarm:\n  id: 1\nfunctions: {f1: [\n")
    with pytest.raises(ConfigError) as info:
        load_swarm(path)
    assert info.value.problems[0].line in (3, 4)


def test_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigUnreadable, match="cannot read"):
        load_swarm(tmp_path / "missing.yaml")
    with pytest.raises(ConfigUnreadable):
        load_swarm(tmp_path)  # a directory


def test_no_standby_is_a_warning_not_an_error(tmp_path: Path) -> None:
    cfg = load_swarm(_write(tmp_path, _edit(_set(("robots", 4, "subs"), [1]))))
    assert [(w.field, w.severity) for w in cfg.warnings] == [("functions.f4", "warning")]
    assert "no standby covers f4" in cfg.warnings[0].message


def test_close_homes_warn(tmp_path: Path) -> None:
    doc = _edit(_set(("robots", 0, "home"), [0.0, 0.0]))
    doc["robots"][1]["home"] = [0.2, 0.1]
    cfg = load_swarm(_write(tmp_path, doc))
    assert [w.field for w in cfg.warnings] == ["robots[1].home"]


def test_inactive_is_standby_and_subs_by_name_equal_subs_by_id(tmp_path: Path) -> None:
    by_id = load_swarm(_write(tmp_path, BASE, "a.yaml"))
    doc = _edit(_set(("robots", 4, "state"), "inactive"))
    doc["robots"][4]["subs"] = ["f1", "f4"]
    by_name = load_swarm(_write(tmp_path, doc, "b.yaml"))
    assert by_name.robots[4].state == "standby"
    assert by_name.to_plan() == by_id.to_plan()


def test_default_function_is_f_id(tmp_path: Path) -> None:
    doc = copy.deepcopy(BASE)
    for r in doc["robots"]:
        r.pop("function", None)
    cfg = load_swarm(_write(tmp_path, doc))
    assert [r.holds for r in cfg.robots] == ["f1", "f2", "f3", "f4", None, None]


def test_paper_plan() -> None:
    cfg = load_swarm(CONFIGS / "paper.yaml")
    plan = cfg.to_plan()
    assert plan.swarm_id == 1543
    assert plan.functions == ("f1", "f2", "f3", "f4")
    assert {f: set(plan.watched_by(f)) for f in plan.functions} == {
        "f1": {"f2", "f4"}, "f2": {"f1", "f3"}, "f3": {"f2", "f4"}, "f4": {"f1", "f3"},
    }
    assert {f: plan.covered_by(f) for f in plan.functions} == {
        "f1": (1, 5), "f2": (2, 6), "f3": (3, 6), "f4": (4, 5),
    }
    assert plan.standbys() == (5, 6)
    assert cfg.params() == udp()
    assert cfg.warnings == ()
    assert cfg.function_spec("f1") == {"kind": "slot", "position": [2.0, 0.0, 1.5]}


def test_paper_radio_same_plan_radio_timing() -> None:
    radio_cfg = load_swarm(CONFIGS / "paper-radio.yaml")
    assert radio_cfg.params() == radio()
    assert radio_cfg.to_plan() == load_swarm(CONFIGS / "paper.yaml").to_plan()


def test_timing_overrides(tmp_path: Path) -> None:
    cfg = load_swarm(_write(tmp_path, _edit(_set(("timing", "t_max"), 0.6))))
    assert cfg.params() == udp().with_overrides(t_max=0.6)


def test_timing_model_knows_every_params_field() -> None:
    # Timing lists Params' fields explicitly (typed, typo-proof): keep them in step.
    assert set(Timing.model_fields) - {"preset"} == {f.name for f in dataclasses.fields(Params)}


def test_ring12() -> None:
    cfg = load_swarm(CONFIGS / "ring12.yaml")
    assert cfg.warnings == ()
    plan = cfg.to_plan()
    assert all(len(plan.watched_by(f)) == 4 for f in plan.functions)
    assert all(len(plan.covered_by(f)) == 2 for f in plan.functions)  # holder + 1 standby
    assert {s.kind for s in cfg.functions.values()} == {"slot", "patrol"}


def test_grid100_matches_its_generator() -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_grid", CONFIGS / "make_grid.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.grid_yaml(10, 9) == (CONFIGS / "grid100.yaml").read_text()
    cfg = load_swarm(CONFIGS / "grid100.yaml")
    plan = cfg.to_plan()
    assert len(plan.robots) == 100 and len(plan.standbys()) == 10
    assert sorted({len(plan.watched_by(f)) for f in plan.functions}) == [2, 3, 4]
    assert all(len(plan.covered_by(f)) == 2 for f in plan.functions)
    assert cfg.warnings == ()


def test_every_example_swarm_loads_clean() -> None:
    for path in sorted(CONFIGS.glob("*.yaml")):
        if path.name.startswith("robot"):
            continue
        assert load_swarm(path).warnings == (), path


def test_parse_swarm_from_text() -> None:
    cfg = parse_swarm(yaml.safe_dump(BASE), "inline.yaml")
    assert isinstance(cfg, SwarmConfig) and cfg.source == "inline.yaml"


# -- robot files -------------------------------------------------------------------------


def _robot(tmp_path: Path, extra: Doc | None = None, swarm: Doc | None = None) -> Path:
    _write(tmp_path, swarm if swarm is not None else BASE, "swarm.yaml")
    doc: Doc = {"robot": 2, "swarm": "swarm.yaml"} | (extra or {})
    return _write(tmp_path, doc, "robot.yaml")


def test_robot_example_without_keys_says_which_keygen_to_run() -> None:
    if (CONFIGS / "keys").exists():
        pytest.skip("configs/keys exists here (made by hand); the example then loads")
    with pytest.raises(ConfigError) as info:
        load_robot(CONFIGS / "robot-example.yaml")
    (problem,) = info.value.problems
    assert problem.field == "auth.keys_dir"
    assert (f"swarmd keygen --swarm {CONFIGS / 'paper.yaml'} {CONFIGS / 'keys'}"
            in problem.message)


def test_robot_example(tmp_path: Path) -> None:
    # The example as documented: the swarm's keys made first, beside the swarm file.
    for name in ("paper.yaml", "robot-example.yaml"):
        shutil.copy(CONFIGS / name, tmp_path / name)
    for robot in range(1, 7):
        write_identity(tmp_path / "keys", robot)
    cfg = load_robot(tmp_path / "robot-example.yaml")
    assert cfg.swarm.auth_mode == "per-robot"
    assert cfg.identity_file == tmp_path / "keys" / "robot-2.key"
    material = cfg.identity_material()
    assert material is not None and set(material.public_keys) == {1, 2, 3, 4, 5, 6}
    assert cfg.robot == cfg.robot_id == 2
    assert cfg.entry.holds == "f2"
    assert cfg.transport == UdpTransportConfig()
    assert cfg.transport.interface == "127.0.0.1" and cfg.transport.ttl == 1
    assert cfg.swarm.to_plan() == load_swarm(CONFIGS / "paper.yaml").to_plan()
    assert cfg.keys() == ()


def test_robot_defaults_and_relative_paths(tmp_path: Path) -> None:
    cfg = load_robot(_robot(tmp_path, {
        "event_log": "log/events.jsonl", "state_dir": "state",
        "link": {"kind": "socket", "path": "robot.sock"},
    }))
    assert cfg.swarm_path == tmp_path / "swarm.yaml"
    assert cfg.event_log == tmp_path / "log/events.jsonl"
    assert cfg.state_dir == tmp_path / "state"
    assert isinstance(cfg.link, SocketLinkConfig)
    assert cfg.link.path == str(tmp_path / "robot.sock") and cfg.link.health_timeout == 2.0
    assert cfg.handover_on_stop is True and cfg.metrics is None


def test_xbee_hex_pan_id_and_channel(tmp_path: Path) -> None:
    cfg = load_robot(_robot(tmp_path, {"transport": {
        "kind": "xbee", "port": "/dev/ttyUSB0", "pan_id": "0x607", "channel": "0x0C",
        "api_mode": 2, "protocol": "digimesh"}}))
    assert isinstance(cfg.transport, XBeeTransportConfig)
    assert (cfg.transport.pan_id, cfg.transport.channel, cfg.transport.baud) == (0x607, 12, 9600)


def test_serial_defaults(tmp_path: Path) -> None:
    cfg = load_robot(_robot(tmp_path, {"transport": {"kind": "serial", "port": "/dev/ttyS1"}}))
    assert cfg.transport == SerialTransportConfig(kind="serial", port="/dev/ttyS1", baud=57600)


ROBOT_CASES: list[tuple[str, Doc, str, str]] = [
    ("robot not in swarm", {"robot": 9}, "robot", "robot 9 is not in swarm file"),
    ("swarm file missing", {"swarm": "nope.yaml"}, "swarm", "cannot read the file"),
    ("not multicast", {"transport": {"kind": "udp", "group": "10.0.0.1"}},
     "transport.group", "not a multicast group"),
    ("bad interface", {"transport": {"kind": "udp", "interface": "eth0"}},
     "transport.interface", "not an IPv4 interface address"),
    ("bad pan id", {"transport": {"kind": "xbee", "port": "/dev/x", "pan_id": "zz"}},
     "transport.pan_id", "not a number"),
    ("pan id range", {"transport": {"kind": "xbee", "port": "/dev/x", "pan_id": 70000}},
     "transport.pan_id", "65535"),
    ("bad api mode", {"transport": {"kind": "xbee", "port": "/dev/x", "api_mode": 0}},
     "transport.api_mode", ""),
    ("unknown transport", {"transport": {"kind": "lora"}}, "transport", "unknown kind 'lora'"),
    ("serial needs port", {"transport": {"kind": "serial"}}, "transport.port", "required"),
    ("exec needs on_assign", {"link": {"kind": "exec"}}, "link.on_assign", "required"),
    ("metrics off loopback", {"metrics": {"host": "0.0.0.0"}}, "metrics.host",
     "allow_remote"),
    ("missing key file", {"key_files": ["k1"]}, "key_files[0]", "k1"),
    ("typo", {"handover_on_stopp": True}, "handover_on_stopp", "did you mean"),
]


@pytest.mark.parametrize(
    ("extra", "field", "fragment"),
    [pytest.param(e, f, m, id=name) for name, e, f, m in ROBOT_CASES],
)
def test_load_robot_error_names_file_and_field(
    tmp_path: Path, extra: Doc, field: str, fragment: str
) -> None:
    path = _robot(tmp_path, extra)
    with pytest.raises(ConfigError) as info:
        load_robot(path)
    matching = [p for p in info.value.errors if p.field == field and fragment in p.message]
    assert matching, "\n".join(map(str, info.value.problems))
    assert str(matching[0]).startswith(f"{path}: {field}: ")


def test_robot_file_reports_swarm_file_problems(tmp_path: Path) -> None:
    path = _robot(tmp_path, swarm=_edit(_set(("robots", 0, "neighbors"), [2, 4, 9])))
    with pytest.raises(ConfigError) as info:
        load_robot(path)
    (problem,) = info.value.errors
    assert problem.file == str(tmp_path / "swarm.yaml")
    assert problem.field == "robots[0].neighbors"


def test_metrics_remote_allowed_when_asked(tmp_path: Path) -> None:
    cfg = load_robot(_robot(tmp_path, {"metrics": {"host": "0.0.0.0", "allow_remote": True}}))
    assert cfg.metrics is not None and cfg.metrics.port == 9477


def test_keys_signing_key_first(tmp_path: Path) -> None:
    swarm_key, old_key = bytes(range(32)), bytes(range(32, 64))
    for name, key in (("swarm.key", swarm_key), ("old.key", old_key)):
        (tmp_path / name).write_bytes(key)
        os.chmod(tmp_path / name, 0o600)
    cfg = load_robot(_robot(tmp_path, {"key_files": ["old.key"]},
                            swarm=BASE | {"auth": {"mode": "shared", "key_file": "swarm.key"}}))
    assert cfg.keys() == (swarm_key, old_key)


def test_robot_file_given_as_swarm_file_says_so() -> None:
    """`swarmd sim robot2.yaml` used to print four schema errors (`swarm` is not a
    mapping, `functions`/`robots` missing, `robot` unknown); one problem says what to do."""
    with pytest.raises(ConfigError) as info:
        parse_swarm("robot: 2\nswarm: paper.yaml\ntransport: {kind: udp}\n", "r2.yaml")
    assert [str(p) for p in info.value.problems] == [
        "r2.yaml: <top>: this is a robot file (it has `robot:`); give the swarm file it "
        "names: paper.yaml (line 1)"]


def test_swarm_file_given_as_robot_file_says_so() -> None:
    """`swarmd start -c paper.yaml` printed seven schema errors; one problem says what to do."""
    text = (Path(__file__).resolve().parent.parent / "configs" / "paper.yaml").read_text()
    with pytest.raises(ConfigError) as info:
        parse_robot(text, "paper.yaml")
    [problem] = info.value.problems
    assert "this is a swarm file" in str(problem) and "robot: <id>" in str(problem)

