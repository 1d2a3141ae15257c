"""Role table (paper Fig. 5 with the wait state; swarmd.core.roles)."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarmd.core.roles import (
    REGENERATE,
    TRANSITIONS,
    Role,
    TransitionError,
    Trigger,
    markdown,
    mermaid,
    transition,
)

EXPECTED = {
    (Role.STANDBY, Trigger.QUORUM): Role.CLAIMING,
    (Role.STANDBY, Trigger.LEAVE_HEARD): Role.CLAIMING,
    (Role.STANDBY, Trigger.FAULT): Role.STANDBY,
    (Role.REJOINING, Trigger.REJOIN): Role.ACTIVE,
    (Role.REJOINING, Trigger.OUTDATED): Role.STANDBY,
    (Role.REJOINING, Trigger.FAULT): Role.STANDBY,
    (Role.CLAIMING, Trigger.CLAIM_HELD): Role.ACTIVE,
    (Role.CLAIMING, Trigger.BACKOFF): Role.STANDBY,
    (Role.CLAIMING, Trigger.REFUTED): Role.STANDBY,
    (Role.CLAIMING, Trigger.SUPERSEDED): Role.STANDBY,
    (Role.CLAIMING, Trigger.FAULT): Role.STANDBY,
    (Role.ACTIVE, Trigger.FENCE): Role.FENCED,
    (Role.ACTIVE, Trigger.FAULT): Role.STANDBY,
    (Role.FENCED, Trigger.FENCE_DONE): Role.STANDBY,
    (Role.FENCED, Trigger.FAULT): Role.FENCED,
}


@pytest.mark.parametrize(("src", "trig"), EXPECTED.keys(),
                         ids=[f"{s.name}-{t.name}" for s, t in EXPECTED])
def test_transition(src: Role, trig: Trigger) -> None:
    assert transition(src, trig) is EXPECTED[(src, trig)]


def test_table_is_exactly_the_expected_one() -> None:
    table = {(s, t): d for s, edges in TRANSITIONS.items() for t, d in edges.items()}
    assert table == EXPECTED


ILLEGAL = [(s, t) for s in Role for t in Trigger if (s, t) not in EXPECTED]


@pytest.mark.parametrize(("src", "trig"), ILLEGAL,
                         ids=[f"{s.name}-{t.name}" for s, t in ILLEGAL])
def test_illegal_transition_raises(src: Role, trig: Trigger) -> None:
    with pytest.raises(TransitionError, match=src.name):
        transition(src, trig)


def test_mermaid_mentions_every_state_and_trigger() -> None:
    text = mermaid()
    assert text.startswith("stateDiagram-v2")
    for role in Role:
        assert role.name in text
    for trig in Trigger:
        assert trig.name.lower() in text


def test_docs_roles_md_is_generated_from_the_table() -> None:
    path = Path(__file__).resolve().parent.parent / "docs" / "roles.md"
    assert path.read_text() == markdown(), f"docs/roles.md is stale; run `{REGENERATE}`"


def test_the_page_has_a_row_per_transition() -> None:
    text = markdown()
    for src, edges in TRANSITIONS.items():
        for trig, dst in edges.items():
            assert f"| {src.name} | `{trig.name.lower()}` | {dst.name} |" in text
    assert mermaid() in text
