"""Swarm plan (DESIGN rule 1: functions are the unit), on the paper's swarm."""

from __future__ import annotations

import pytest

from swarmd.core.plan import PlanError, RobotPlan, SwarmPlan


def test_paper_plan_relations(paper_plan: SwarmPlan) -> None:
    p = paper_plan
    assert p.functions == ("f1", "f2", "f3", "f4")
    assert [p.initial_holder(f) for f in p.functions] == [1, 2, 3, 4]
    assert p.standbys() == (5, 6)
    # ring: each slot watched by its two neighbours, which is the quorum
    assert set(p.watched_by("f2")) == {"f1", "f3"}
    assert set(p.watched("f1")) == {"f2", "f4"}
    # 5 covers f1 and f4, 6 covers f2 and f3; the home robot covers its own slot
    assert [p.covered_by(f) for f in p.functions] == [(1, 5), (2, 6), (3, 6), (4, 5)]


def test_slots_on_the_wire(paper_plan: SwarmPlan) -> None:
    assert [paper_plan.slot(f) for f in paper_plan.functions] == [1, 2, 3, 4]
    assert paper_plan.function_at(2) == "f2"
    assert paper_plan.function_at(0) is None
    assert paper_plan.function_at(5) is None


def _plan(**kw: object) -> SwarmPlan:
    base: dict[str, object] = {
        "swarm_id": 1,
        "functions": ("a", "b"),
        "robots": {1: RobotPlan(1, "a"), 2: RobotPlan(2, "b"), 3: RobotPlan(3, None, ("a",))},
        "watches": {"a": ("b",), "b": ("a",)},
    }
    base.update(kw)
    return SwarmPlan(**base)  # type: ignore[arg-type]


def test_valid_small_plan() -> None:
    p = _plan()
    assert p.covered_by("a") == (1, 3)
    assert p.covered_by("b") == (2,)


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"swarm_id": 0x10000}, "16 bits"),
        ({"functions": ("a", "a")}, "duplicate"),
        ({"functions": ()}, "1 to 65535"),
        ({"robots": {1: RobotPlan(2, "a")}}, "robot id"),
        ({"robots": {1: RobotPlan(1, "zz")}}, "unknown function"),
        ({"robots": {1: RobotPlan(1, "a"), 2: RobotPlan(2, "a")}}, "held by robots"),
        ({"robots": {1: RobotPlan(1, None, ("zz",))}}, "substitutes unknown"),
        ({"watches": {"a": ("zz",)}}, "unknown function"),
    ],
)
def test_inconsistent_plans_raise(kw: dict[str, object], needle: str) -> None:
    with pytest.raises(PlanError, match=needle):
        _plan(**kw)


def test_self_watch_is_ignored() -> None:
    p = _plan(watches={"a": ("a", "b"), "b": ("a",)})
    assert p.watched("a") == ("b",)
    assert p.watched_by("a") == ("b",)


def test_a_robot_naming_its_own_slot_in_subs_covers_it_once() -> None:
    # A launch file may list a robot's own slot among its subs; it is still one robot
    # that may take the slot back (a claim race is decided per robot, DESIGN rule 6).
    p = _plan(robots={1: RobotPlan(1, "a", ("a", "b")), 2: RobotPlan(2, "b"),
                      3: RobotPlan(3, None, ("a",))})
    assert p.covered_by("a") == (1, 3)
    assert p.covered_by("b") == (1, 2)


def test_a_vacant_slot_has_no_initial_holder() -> None:
    # A slot nobody executes at start (only standbys cover it): its watchers suspect it
    # after the start-up grace (rule 5); there is no robot to name as its holder.
    p = _plan(robots={1: RobotPlan(1, "a"), 3: RobotPlan(3, None, ("a", "b"))})
    assert p.initial_holder("a") == 1
    assert p.initial_holder("b") is None
    assert p.standbys() == (3,)
