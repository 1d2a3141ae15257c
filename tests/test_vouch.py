"""A holder heard alive after a suspicion of it is vouched for (DESIGN "Detection", "A
heartbeat heard is vouched for"; `swarmd/core/vouch.py`): with a shared key or unsigned,
a robot that heard a strong warning or a claim about a slot's holder relays that
holder's next heartbeat, once, so a standby whose own link to the holder faded hears it
through a third robot (rule 4). Per robot the holder's REFUTE does this (`signed.py`);
every check runs in every auth mode."""

from __future__ import annotations

import pytest
from harness import Radio

from sim.shared.faults import parse_fault
from sim.virtual.simulator import run_virtual
from swarmd.core.actions import Action, Broadcast
from swarmd.core.belief import level_byte
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.records import Holder
from swarmd.core.vouch import Vouches

MODES = ["none", "shared", "per-robot"]


# ---------------------------------------------------------------------- the bookkeeping
def test_a_suspicion_heard_calls_for_one_relay_of_that_holder_within_the_hold() -> None:
    v = Vouches(hold=1.0)
    holder = Holder(4, 0)
    assert not v.due("f4", holder, 0.0)  # nobody suspected it: nothing to answer
    v.suspected("f4", holder, 1.0)
    assert not v.due("f4", Holder(4, 1), 1.1)  # another entry: not what was suspected
    v.suspected("f4", holder, 1.0)
    assert v.due("f4", holder, 1.5)
    assert not v.due("f4", holder, 1.6)  # answered: the next relay waits for a suspicion
    v.suspected("f4", holder, 2.0)
    assert not v.due("f4", holder, 3.1)  # past the vote window: no standby counts it
    assert v.due("f4", holder, 3.2, own=True)  # our own watch suspected it


# ---------------------------------------------------------------------- one node
def sent(actions: list[Action]) -> list[bytes]:
    return [a.frame for a in actions if isinstance(a, Broadcast)]


@pytest.mark.parametrize("mode", MODES)
def test_a_heartbeat_after_a_warning_about_its_sender_is_relayed_once(
        paper_plan: SwarmPlan, udp_params: Params, mode: str) -> None:
    """Standby 6 hears f4's heartbeats (its slot f3's holder watches f4). After witness
    3's strong warning about robot 4, it relays 4's next heartbeat byte for byte, once;
    per robot it relays nothing (the REFUTE is the portable word there)."""
    radio = Radio(paper_plan, udp_params, mode)
    node = radio.node(6)
    first = radio.beat(4, "f4")
    assert sent(node.receive(first, 0.1)) == []  # no suspicion heard: nothing to answer
    strong = level_byte(udp_params.suspect_level)
    node.receive(radio.warn(3, 4, "f4", strong), 1.0)
    beat = radio.beat(4, "f4")
    relayed = sent(node.receive(beat, 1.05))
    assert relayed == ([] if mode == "per-robot" else [beat])
    assert sent(node.receive(radio.beat(4, "f4"), 1.15)) == []  # once per suspicion


@pytest.mark.parametrize("mode", MODES)
def test_a_doubt_or_a_stale_frame_is_not_relayed(paper_plan: SwarmPlan,
                                                 udp_params: Params, mode: str) -> None:
    """A doubt (a warning below `suspect_level`) is no suspicion a standby counts; a
    heartbeat older than one heard already (reordered, or played back) says nothing of
    now; a suspicion heard longer than a vote window ago is counted by nobody."""
    radio = Radio(paper_plan, udp_params, mode)
    node = radio.node(6)
    weak = level_byte(udp_params.suspect_level) - 1
    node.receive(radio.warn(3, 4, "f4", weak), 1.0)
    assert sent(node.receive(radio.beat(4, "f4"), 1.05)) == []
    strong = level_byte(udp_params.suspect_level)
    older = radio.beat(4, "f4")
    newer = radio.beat(4, "f4")
    node.receive(newer, 1.1)
    node.receive(radio.warn(3, 4, "f4", strong), 1.2)
    assert sent(node.receive(older, 1.25)) == []  # behind the top of 4's run
    node.receive(radio.warn(3, 4, "f4", strong), 2.0)
    late = 2.0 + udp_params.vote_window + 0.05
    assert sent(node.receive(radio.beat(4, "f4"), late)) == []


# ---------------------------------------------------------------------- the swarm
def takeovers_of(auth: str, paper: tuple[SwarmPlan, Params], spec: str,
                 f: str) -> list[float]:
    plan, params = paper
    res = run_virtual(plan, params, duration=16.0, faults=[parse_fault(spec)], auth=auth,
                      seed=1)
    assert res.violations == []
    return [e["t"] for e in res.events if e["event"] == "takeover" and e["function"] == f]


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_its_witnesses_and_standby_cannot_hear_is_vouched_for(
        paper: tuple[SwarmPlan, Params], auth: str) -> None:
    """Robot 4's radio fades to its witnesses 1 and 3 and its standby 5 for 3 s, not to
    standby 6 (which hears f4: its slot f3 watches it). All three links are silent at
    once: by their own ears, a crash. Robot 4 hears their warnings and 5's claim and
    answers; 6 heard the warnings and relays 4's answers, so 5's claim ends (rule 4)
    and f4 stays with 4. Unsigned and with a shared key 5 took f4 over 0.62 s in before
    (per robot, 4's REFUTE did the same)."""
    assert takeovers_of(auth, paper, "partition:4>1,3,5@10+3", "f4") == []


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_nobody_hears_is_still_taken_over(paper: tuple[SwarmPlan, Params],
                                                   auth: str) -> None:
    """Vouching needs somebody who hears the holder: robot 4's radio fading to everyone
    is a crash to the swarm, taken over within the clean channel's bound."""
    got = takeovers_of(auth, paper, "fade:4@10+3", "f4")
    assert got and got[0] - 10.0 <= paper[1].takeover_bound()
