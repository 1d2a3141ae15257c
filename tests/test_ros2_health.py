"""The ros2 link's pure parts on virtual time (docs/ros2.md, "In the field"): whose
health counts, what the link concludes before it heard its robot, the one-message
assignment, the robot file's default namespace and an honest /diagnostics."""

from __future__ import annotations

from pathlib import Path

import pytest
from swarms import unsigned_paper

from swarmd.link.ros2_assignment import Assignment
from swarmd.link.ros2_health import NEVER_HEARD, HealthFold, Publishers, StackWatch
from swarmd.link.ros2_status import ERROR, OK, STALE, WARN

OWN = "/swarmd/paper/robot2/swarmd_robot2"
STACK = "/swarmd/paper/robot2/robot_stack"


def watch(timeout: float = 2.0, startup: float = 30.0,
          health_node: str | None = None) -> StackWatch:
    fold = HealthFold((), "robot2", timeout)
    return StackWatch(fold, Publishers("/swarmd/paper/robot2", health_node, OWN),
                      started_at=0.0, startup_timeout=startup)


def test_only_nodes_of_the_robots_namespace_speak_for_it() -> None:
    p = Publishers("/swarmd/paper/robot2", None, OWN)
    assert p.accepts(STACK)
    assert not p.accepts(OWN)  # the daemon's own swarm statuses
    assert not p.accepts("/swarmd/other/robot2/robot_stack")  # another swarm's robot 2
    assert not p.accepts("/swarmd/paper/robot3/robot_stack")
    assert not p.accepts("/attacker")  # any node, whatever hardware_id it writes
    assert not p.accepts("/swarmd/paper/robot2/sub/deeper")
    named = Publishers("/swarmd/paper/robot2", "/px4/diag", OWN)
    assert named.accepts("/px4/diag") and not named.accepts(STACK)
    assert Publishers("", None, "/swarmd").accepts("/anyone")  # namespace "" asked for it


def test_two_publishers_of_one_status_never_flap() -> None:
    fold = HealthFold((), "robot2", 2.0)
    levels = []
    for i in range(20):  # two nodes publish robot2/flight, alternately OK and ERROR
        t = i * 0.25
        fold.hear("/ns/a" if i % 2 else "/ns/b", "robot2/flight", "robot2",
                  ERROR if i % 2 else OK, t)
        levels.append(fold.level(t + 0.1))
    assert levels[1:] == [ERROR] * 19


def test_a_stack_never_heard_is_waited_for_and_never_a_fault() -> None:
    w = watch(timeout=2.0, startup=30.0)
    for t in (0.0, 2.5, 10.0, 29.9):
        state = w.state(t)
        assert state.health is None and state.level == WARN and not state.alert
        assert "waiting for robot health" in state.message
        assert "/swarmd/paper/robot2" in state.message
    late = w.state(30.1)  # no publisher at all: an alert, the function kept
    assert late.health is None and late.level == ERROR and late.alert
    assert late.message.startswith(NEVER_HEARD)


def test_the_bound_counts_from_the_discovery_of_the_robots_publisher() -> None:
    w = watch(timeout=2.0)
    assert w.found(STACK, 12.0) and not w.found(STACK, 13.0)
    assert w.state(13.9).level == WARN and w.state(13.9).health is None
    silent = w.state(14.1)  # found 2.1 s ago, nothing sent: an alert, still no fault
    assert silent.health is None and silent.alert and NEVER_HEARD in silent.message
    w.fold.hear(STACK, "robot2/flight", "robot2", OK, 15.0)
    assert w.state(15.0).health == OK and w.state(15.0).level is None
    assert w.state(17.1).health == STALE  # heard once, then silent: now a fault


def test_a_robot_file_names_its_swarm_in_the_default_namespace(tmp_path: Path) -> None:
    from swarmd.config import parse_robot
    from swarmd.config.robot import ros2_namespace

    swarm = unsigned_paper(tmp_path)
    cfg = parse_robot(f"robot: 2\nswarm: {swarm}\nlink: {{kind: ros2}}\n", "r.yaml",
                      tmp_path / "r.yaml")
    assert getattr(cfg.link, "namespace", None) == "/swarmd/paper/robot2"
    cfg = parse_robot(f"robot: 2\nswarm: {swarm}\nlink: {{kind: ros2, namespace: ''}}\n",
                      "r.yaml", tmp_path / "r.yaml")
    assert getattr(cfg.link, "namespace", None) == ""  # the old global topics, if asked
    assert ros2_namespace("north-field 2", 3) == "/swarmd/north_field_2/robot3"
    assert ros2_namespace("7up", 1) == "/swarmd/swarm_7up/robot1"


def test_health_node_must_be_fully_qualified(tmp_path: Path) -> None:
    from swarmd.config import ConfigError, parse_robot

    swarm = unsigned_paper(tmp_path)
    with pytest.raises(ConfigError, match="health_node"):
        parse_robot(f"robot: 2\nswarm: {swarm}\nlink: {{kind: ros2, health_node: px4}}\n",
                    "r.yaml", tmp_path / "r.yaml")


def test_the_assignment_is_one_message_with_seq_boot_and_lease() -> None:
    a = Assignment("robot2", "map", lease=3.0, boot=42)
    assert a.message() == "no function yet" and a.seq == 0
    a.execute("f2", 1, {"kind": "slot", "position": [0, 2, 1.5]})
    v = dict(a.values())
    assert (v["function"], v["action"], v["epoch"], v["seq"], v["boot"], v["lease"]) == (
        "f2", "execute", "1", "1", "42", "3")
    assert (v["frame_id"], float(v["x"]), float(v["y"]), float(v["z"])) == ("map", 0, 2, 1.5)
    a.release("land")
    v = dict(a.values())
    assert (v["function"], v["action"], v["seq"]) == ("", "land", "2") and "x" not in v
    a.execute("p1", 2, {"kind": "patrol"})  # no single pose
    assert "x" not in dict(a.values()) and a.message() == "execute p1"


def test_a_function_its_robot_does_not_execute_is_never_shown_ok() -> None:
    from test_ros2 import _snap

    from swarmd.config import load_swarm
    from swarmd.link.ros2_status import SwarmStatus

    view = SwarmStatus(load_swarm(Path(__file__).parent.parent / "configs" / "paper.yaml")
                       .to_plan(), 1, "paper", t_max=0.5)
    waiting = (WARN, "waiting for robot health")
    by_name = {s.name: s for s in view.statuses(_snap(), 10.2, stack=waiting)}
    assert by_name["swarmd/paper/f1"].level == WARN
    assert "waiting for robot health" in by_name["swarmd/paper/f1"].message
    assert by_name["swarmd/paper/robot1"].level == WARN
    assert by_name["swarmd/paper/f2"].level == OK  # another holder's: unchanged
    never = (ERROR, f"{NEVER_HEARD}: no health publisher")
    assert {s.name: s.level for s in view.statuses(_snap(), 10.2, stack=never)}[
        "swarmd/paper/f1"] == ERROR

