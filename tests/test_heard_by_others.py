"""A holder heard alive after a suspicion of it keeps its slot even where its witnesses
and its standby cannot hear it (DESIGN "Detection"; rule 4 through a third robot's ears):
it answers each warning and claim with a REFUTE, which robots that hear it relay with
the proof of the slot (`proofs.py`), so the claim it voids ends. Every check runs in
every auth mode."""

from __future__ import annotations

import pytest

from sim.shared.faults import parse_fault
from sim.virtual.simulator import run_virtual
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

MODES = ["none", "shared", "per-robot"]


# ---------------------------------------------------------------------- the swarm
def takeovers_of(auth: str, paper: tuple[SwarmPlan, Params], spec: str,
                 f: str) -> list[float]:
    plan, params = paper
    res = run_virtual(plan, params, duration=16.0, faults=[parse_fault(spec)], auth=auth,
                      seed=1)
    assert res.violations == []
    return [e["t"] for e in res.events if e["event"] == "takeover" and e["function"] == f]


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_its_witnesses_and_standby_cannot_hear_keeps_its_slot(
        paper: tuple[SwarmPlan, Params], auth: str) -> None:
    """Robot 4's radio fades to its witnesses 1 and 3 and its standby 5 for 3 s, not to
    standby 6 (which hears f4: its slot f3 watches it). All three links are silent at
    once: by their own ears, a crash. Robot 4 hears their warnings and 5's claim and
    answers with REFUTEs; 6 relays them with the proof of f4, so 5's claim ends (rule 4)
    and f4 stays with 4."""
    assert takeovers_of(auth, paper, "partition:4>1,3,5@10+3", "f4") == []


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_nobody_hears_is_still_taken_over(paper: tuple[SwarmPlan, Params],
                                                   auth: str) -> None:
    """A refute needs somebody who hears the holder: robot 4's radio fading to everyone
    is a crash to the swarm, taken over within the clean channel's bound."""
    got = takeovers_of(auth, paper, "fade:4@10+3", "f4")
    assert got and got[0] - 10.0 <= paper[1].takeover_bound()
