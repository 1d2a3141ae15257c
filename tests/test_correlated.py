"""Faults that come together (DESIGN rules 9 and 10), on virtual time.

- Rule 9: when watchers of a function fail with its holder, the standby's own ears stand
  in for them, so every function with a live covering standby is still taken over; a
  single liar still replaces nobody, because the standby hears the live suspect itself.
- Rule 10: a CLAIM is believed for `claim_hold + t_max`; a claimant that dies or never
  takes over does not silence the watchers for longer, and its repeats change nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from harness import Net

from sim.shared.faults import parse_fault
from sim.virtual.simulator import VirtualResult, run_virtual
from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.params import Params, udp
from swarmd.core.plan import RobotPlan, SwarmPlan

BOUND = udp().takeover_bound()
"""Crash -> takeover bound for correlated failures at the udp preset, s: the one bound
(`Params.takeover_bound`, 1.7 s) holds for them too, since the standby's own ears (rule
9) stand in for the dead watcher once it has been silent for the same `t_max` as the
holder."""


def ring8() -> SwarmPlan:
    """Eight actives in a ring (each watches its two ring neighbours: exactly the quorum
    of 2), standby 9 covers f1-f4, 10 covers f5-f8, 11 covers all eight."""
    functions = tuple(f"f{i}" for i in range(1, 9))
    robots = {i: RobotPlan(i, f"f{i}") for i in range(1, 9)}
    robots[9] = RobotPlan(9, None, functions[:4])
    robots[10] = RobotPlan(10, None, functions[4:])
    robots[11] = RobotPlan(11, None, functions)
    watches = {f"f{i}": (f"f{(i - 2) % 8 + 1}", f"f{i % 8 + 1}") for i in range(1, 9)}
    return SwarmPlan(808, functions, robots, watches)


def run(plan: SwarmPlan, *faults: str, duration: float = 10.0, loss: float = 0.0,
        seed: int = 0, params: Params | None = None, auth: str = "per-robot") -> VirtualResult:
    return run_virtual(plan, params or udp(), duration=duration, loss=loss, seed=seed,
                       faults=[parse_fault(f) for f in faults], auth=auth)


def takeover_times(res: VirtualResult) -> dict[str, float]:
    return {e["function"]: e["t"] for e in res.events if e["event"] == "takeover"}


PHASES = (0.0, 0.025, 0.05, 0.075)
"""Offsets inside the udp heartbeat period (0.1 s): every phase of the grid."""


@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("first", range(1, 9))
def test_two_adjacent_robots_crashing_together_are_both_taken_over(first: int,
                                                                   phase: float) -> None:
    second = first % 8 + 1
    at = 5.0 + phase
    res = run(ring8(), f"crash:{first}@{at}", f"crash:{second}@{at}")
    assert res.violations == []
    took = takeover_times(res)
    assert set(took) == {f"f{first}", f"f{second}"}, res.events[-20:]
    assert max(took.values()) - at <= BOUND, took


@pytest.mark.parametrize("offset", [0.25, 0.5, 1.0])
def test_adjacent_crashes_a_little_apart_are_both_taken_over(offset: float) -> None:
    res = run(ring8(), "crash:1@5", f"crash:2@{5 + offset}")
    assert res.violations == []
    took = takeover_times(res)
    assert took["f1"] - 5.0 <= BOUND and took["f2"] - (5.0 + offset) <= BOUND, took


@pytest.mark.parametrize("phase", PHASES)
def test_a_robot_and_its_first_standby_crashing_together(phase: float) -> None:
    at = 5.0 + phase
    res = run(ring8(), f"crash:1@{at}", f"crash:9@{at}")
    assert res.violations == []
    assert [(e["robot"], e["function"]) for e in res.events if e["event"] == "takeover"] \
        == [(11, "f1")]
    assert takeover_times(res)["f1"] - at <= BOUND


def test_a_watcher_and_its_standby_crashing_with_the_holder() -> None:
    # f1 loses its holder, one of its two watchers (robot 2, holder of f2) and its first
    # standby (9): standby 11 is left for both f1 and f2, so one of them is taken over
    # and the other one alerts; the checker accepts that (the standby was consumed).
    res = run(ring8(), "crash:1@5", "crash:2@5", "crash:9@5")
    assert res.violations == []
    took = takeover_times(res)
    assert len(took) == 1 and next(iter(took.values())) - 5.0 <= BOUND
    lost = ({"f1", "f2"} - set(took)).pop()
    assert any(e["event"] == "alert" and e["function"] == lost for e in res.events)


def test_every_watcher_but_one_lost_on_a_wider_ring() -> None:
    # Robot 3 fails with both its watchers (2 and 4): nobody warns about f3, so it is
    # not detected by warnings; f2 and f4 keep one live watcher each (1 and 5), whose
    # warning plus the standby's own ears make the quorum.
    res = run(ring8(), "crash:2@5", "crash:3@5", "crash:4@5")
    assert res.violations == []
    took = takeover_times(res)
    # Three functions, two standbys for f2-f4 (9 and 11): two are taken over, one alerts.
    assert len(took) == 2 and max(took.values()) - 5.0 <= BOUND, took


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("liar", [1, 2, 9])
@pytest.mark.parametrize("loss", [0.0, 0.2])
def test_a_single_liar_replaces_nobody_on_the_ring(liar: int, loss: float, seed: int) -> None:
    res = run(ring8(), f"liar:{liar}@2", duration=12.0, loss=loss, seed=seed)
    assert res.violations == []
    assert not takeover_times(res)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("liar", [1, 3, 5])
@pytest.mark.parametrize("loss", [0.0, 0.2])
def test_a_single_liar_replaces_nobody_on_the_paper_swarm(
        paper: tuple[SwarmPlan, Params], liar: int, loss: float, seed: int) -> None:
    plan, params = paper
    res = run(plan, f"liar:{liar}@2", duration=12.0, loss=loss, seed=seed, params=params)
    assert res.violations == []
    assert not takeover_times(res)


def test_a_liar_with_a_dead_co_watcher_replaces_nobody() -> None:
    # Robot 1 lies about f2 (which it watches) while f2's other watcher, robot 3, is dead:
    # the quorum can only be met with the standby's own ears, and they hear robot 2.
    res = run(ring8(), "crash:3@3", "liar:1@4", duration=12.0)
    assert res.violations == []
    assert set(takeover_times(res)) == {"f3"}


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
def test_a_partition_that_looks_like_a_collision_is_taken_over_then_settled(
        paper: tuple[SwarmPlan, Params], auth: str) -> None:
    # {1,2} | {3,4,5,6}: the standbys' side cannot tell it from robots 1 and 2 colliding.
    # When it heals one of each pair stops (DESIGN rule 9): the cut-off holders refute
    # the warnings in the standbys' certificates, and their reassertions at the next
    # epoch outrank the standbys' takeovers, which are fenced (DESIGN "Convergence": the
    # slot table only moves forward).
    plan, params = paper
    res = run(plan, "partition:1,2|3,4,5,6@2+3", duration=8.0, params=params, auth=auth)
    assert res.violations == []
    takeovers = {e["function"]: e for e in res.events if e["event"] == "takeover"}
    assert {f: e["robot"] for f, e in takeovers.items()} == {"f1": 5, "f2": 6}
    fenced = {e["robot"]: e["t"] for e in res.events if e["event"] == "fenced"}
    assert min(fenced.values()) >= 5.0  # after the heal
    assert set(fenced) == {5, 6}
    assert res.holders() == {"f1": [1], "f2": [2], "f3": [3], "f4": [4]}


# -- rule 10: claims believed for a bounded time -------------------------------------------

def two_standbys_for_f2(plan: SwarmPlan) -> SwarmPlan:
    robots = dict(plan.robots)
    robots[7] = RobotPlan(7, None, ("f2",))
    return SwarmPlan(plan.swarm_id, plan.functions, robots, plan.watches)


def first(net: Net, name: str, **fields: Any) -> dict[str, Any] | None:
    return next((e for e in net.events if e["event"] == name
                 and all(e.get(k) == v for k, v in fields.items())), None)


def run_until_event(net: Net, name: str, limit: float, **fields: Any) -> dict[str, Any]:
    while net.now < limit:
        net.run_until(net.now + 0.005)
        found = first(net, name, **fields)
        if found is not None:
            return found
    raise AssertionError(f"no {name} {fields} before t={limit}")


def test_a_claimant_that_dies_after_its_claim_is_replaced_by_the_next_standby(
        paper: tuple[SwarmPlan, Params]) -> None:
    plan, params = paper
    net = Net(two_standbys_for_f2(plan), params)
    net.run_until(3.0)
    net.crash(2)
    claim = run_until_event(net, "claim", 6.0, robot=6, function="f2")
    net.run_until(claim["t"] + 0.05)
    net.crash(6)
    net.run_until(claim["t"] + 4.0)
    took = first(net, "takeover", function="f2")
    assert took is not None and took["robot"] == 7
    # Believed for the claim horizon, then warned about again (and logged), then the
    # next standby's quorum and claim hold.
    bound = params.claim_horizon + params.vote_window + params.claim_hold
    assert took["t"] - claim["t"] <= bound, (took, claim)
    again = [e for e in net.events if e["event"] == "suspect" and e["function"] == "f2"
             and e["t"] > claim["t"]]
    assert again, "the watchers did not log a new suspicion after the claim lapsed"


def spam_claims(net: Net, spammer: int, function: str, failed: int, until: float,
                every: float = 0.3) -> None:
    plan = net.plan
    while net.now < until:
        node = net.nodes[spammer]
        net.inject(spammer, node.send_message(
            wire.Claim(failed, plan.slot(function), 1), net.now))
        net.run_until(net.now + every)


def test_repeated_claims_for_a_dead_robot_do_not_silence_the_watchers(
        paper: tuple[SwarmPlan, Params]) -> None:
    # Robot 5 (a standby that does not cover f2) claims f2 every 0.3 s and never takes
    # it over. Standby 6 still takes f2 over; the watchers log `suspect`. No certificate
    # backs 5's claims, so they silence nobody (`uncertified`).
    plan, params = paper
    net = Net(plan, params)
    net.run_until(3.0)
    net.crash(2)
    spam_claims(net, 5, "f2", 2, until=8.0)
    took = first(net, "takeover", function="f2")
    assert took is not None and took["robot"] == 6
    assert took["t"] - 3.0 <= 2 * params.claim_horizon + params.vote_window
    assert {e["robot"] for e in net.events if e["event"] == "suspect"
            and e["function"] == "f2"} == {1, 3}
    assert net.nodes[1].snapshot().drops.get("uncertified", 0) > 0


def test_repeated_claims_with_no_standby_left_end_in_an_alert(
        paper: tuple[SwarmPlan, Params]) -> None:
    plan, params = paper
    net = Net(plan, params)
    net.run_until(3.0)
    net.crash(2)
    net.crash(6)  # f2's only standby
    spam_claims(net, 5, "f2", 2, until=9.0)
    assert first(net, "takeover", function="f2") is None
    alert = first(net, "alert", function="f2")
    assert alert is not None
    assert alert["t"] - 3.0 <= params.t_max + params.claim_horizon + params.alert_after
    assert first(net, "suspect", function="f2") is not None


@pytest.mark.parametrize("auth", ["per-robot", "shared", "none"])
@pytest.mark.parametrize("heal", [10.28, 10.33, 10.38])
def test_own_ears_give_up_a_claim_when_the_lost_watcher_is_heard_again(
        auth: str, heal: float) -> None:
    """Rule 9's premise is that the watchers silent to the standby failed with the
    suspect. The paper swarm: robot 3's transmissions fade to witness 2 and standby 6,
    and robot 4's (f3's other watcher) to 6 only, until `heal`, within 6's claim hold.
    2 warns, 6 counts its own ears as the second witness and claims f3; then 6 hears
    watcher 4 heartbeat again: its link had faded, 4 did not fail, and the claim rests
    on 6's silence alone. 6 gives it up; nobody takes the live robot 3's slot over.
    (Per robot this took f3 over at 10.44 s and fenced 3; with a shared key or unsigned
    4's relay of 3's heartbeat, once heard, already stopped the claim.)"""
    cfg = load_swarm(Path(__file__).resolve().parent.parent / "configs" / "paper.yaml")
    faults = [parse_fault("partition:3>2,6@9.8+3"),
              parse_fault(f"partition:4>6@9.5+{heal - 9.5:.2f}")]
    res = run_virtual(cfg.to_plan(), cfg.params(), duration=16.0, faults=faults, seed=1,
                      auth=auth)
    claims = [e for e in res.events if e["event"] == "claim" and e["t"] > 9.0]
    assert [(e["robot"], e["function"]) for e in claims] == [(6, "f3")]
    assert not [e for e in res.events if e["event"] in ("takeover", "fenced")]
    assert res.violations == []
