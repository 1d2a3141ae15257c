"""One answer everywhere (DESIGN section 2, "Convergence"), on virtual time.

Link faults that lose frames one way — a robot whose transmissions fade while it still
hears everyone, a standby deaf to one robot a little longer — must end, once the channel
heals, with every live robot holding the same (holder, epoch) for every slot and exactly
one robot executing each, in every authentication mode. The paper swarm: robots 1-4
hold f1-f4 in a ring (f2 watched by the holders of f1 and f3), standby 6 covers f2/f3.
"""

from __future__ import annotations

import itertools

import pytest
from harness import Net
from swarms import two_standbys

from sim.shared.fakeid import fake_identities
from swarmd.core import wire
from swarmd.core.auth import Identity
from swarmd.core.node import Node, Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

Paper = tuple[SwarmPlan, Params]
KEY = b"s" * 32
MODES = ("per-robot", "shared", "none")


def net(paper: Paper, auth: str, cuts: list[tuple[int | None, int | None, float, float]],
        seed: int = 0, loss: float = 0.0) -> Net:
    plan, params = paper
    ids: dict[int, Identity] = fake_identities(plan.robots) if auth == "per-robot" else {}
    keys = (KEY,) if auth in ("shared", "per-robot") else ()
    return Net(plan, params, keys=keys, identities=ids, cuts=cuts, seed=seed, loss=loss)


def settled(n: Net) -> None:
    """Every live robot that hears a slot (DESIGN section 2, "What a robot hears") holds
    the same view of it, and the slot is executed by exactly the robot that view names
    (rules 1, 2)."""
    executing = n.executing()
    for f in n.plan.functions:
        slot = n.plan.slot(f)
        views = {rid: n.nodes[rid].snapshot().known[f] for rid in sorted(n.alive)
                 if slot in n.plan.relevant(rid).slots or n.nodes[rid].snapshot().function == f}
        assert len(set(views.values())) == 1, (f, views)
        holder = next(iter(views.values()))[0]
        doers = sorted(r for r, g in executing.items() if g == f)
        assert doers == [holder], (f, doers, views, executing)


def fade(robot: int, at: float, dur: float) -> tuple[int | None, int | None, float, float]:
    return (robot, None, at, at + dur)


def deaf(robot: int, to: int, at: float, dur: float) -> tuple[int | None, int | None,
                                                               float, float]:
    return (to, robot, at, at + dur)


@pytest.mark.parametrize("auth", MODES)
def test_a_faded_holder_and_a_standby_deaf_a_little_longer_end_with_one_holder(
        paper: Paper, auth: str) -> None:
    """Robot 2's transmissions fade for 0.46 s (it still hears everyone); standby 6 stays
    deaf to robot 2 for 0.4 s longer. 6 takes f2 over while 2 refutes unheard; once the
    channel heals, one of them holds f2 everywhere and the other executes nothing."""
    n = net(paper, auth, [fade(2, 5.0, 0.46), deaf(6, 2, 5.0, 0.86)])
    n.run_until(5.0 + 0.86 + 3.0)
    settled(n)


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize(("fade_s", "extra_s"), list(itertools.product(
    (0.3, 0.46, 0.6, 0.8, 1.2, 2.5), (0.0, 0.2, 0.4, 1.0, 3.0))))
def test_fades_and_deafness_of_any_length_converge(paper: Paper, auth: str, fade_s: float,
                                                   extra_s: float) -> None:
    """The same shape over a grid of lengths around T_max (0.5 s) and claim_hold (0.2 s):
    whichever robot wins, the swarm agrees within a few T_max of the last heal."""
    n = net(paper, auth, [fade(2, 5.0, fade_s), deaf(6, 2, 5.0, fade_s + extra_s)])
    n.run_until(5.0 + fade_s + extra_s + 3.0)
    settled(n)


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize("who", [(1, 2), (3, 2), (2, 1), (6, 2), (2, 6), (1, 6)])
def test_one_way_deafness_of_a_pair_converges(paper: Paper, auth: str,
                                              who: tuple[int, int]) -> None:
    """R deaf to S for 2 s (S still hears R), for pairs of a holder, its watchers and its
    standby: a false suspicion or a takeover, then one view everywhere."""
    r, s = who
    n = net(paper, auth, [deaf(r, s, 5.0, 2.0)])
    n.run_until(10.0)
    settled(n)


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize("seed", range(8))
def test_fades_under_loss_converge(paper: Paper, auth: str, seed: int) -> None:
    """The fade with 20 % loss on every link until the heal, then a clean channel."""
    n = net(paper, auth, [fade(2, 5.0, 0.7), deaf(6, 2, 5.0, 1.1)], seed=seed, loss=0.2)
    n.run_until(6.5)
    n.loss = 0.0
    n.run_until(10.0)
    settled(n)


def test_a_takeover_the_refutes_void_is_outranked_not_undone(paper: Paper) -> None:
    """Per-robot mode: 6 took f2 over while robot 2, faded, refuted unheard; 6's claim
    was certified at the watchers before 2's refutes reached them. Once they do, nothing
    moves back (the slot table only moves forward, DESIGN "Convergence"): the refutes
    make 2's reassertion, the entry (2, 2), which outranks 6's (6, 1) everywhere, so 6
    is fenced (rule 2) and 2, alive all along, holds f2 on. A heartbeat in 2's name at
    epoch 0 afterwards (one frame, swarm key only) pulls no view back."""
    plan, _ = paper
    n = net(paper, "per-robot", [fade(2, 5.0, 0.8), deaf(6, 2, 5.0, 1.8)])
    n.run_until(10.0)
    settled(n)
    assert [(e["robot"], e["epoch"], e["replaced"]) for e in n.named("takeover")] == [
        (6, 1, 2)]
    assert {"robot": 2, "subject": 2, "function": "f2"}.items() <= next(
        e for e in reversed(n.named("refute", 2))).items()
    assert n.nodes[1].snapshot().known["f2"] == (2, 2)
    assert [e["epoch"] for e in n.named("fenced", 6)] == [2]  # 6 stepped down
    assert n.named("fenced", 2) == []
    forged = wire.encode(wire.Frame(plan.swarm_id, 2, 10**12,
                                    wire.Heartbeat(plan.slot("f2"), 0, 1, 0)), KEY)
    for rid in sorted(n.alive):
        if rid != 2:
            n.inject(rid, n.nodes[rid].receive(forged, n.now))
    n.run_until(12.0)
    settled(n)
    assert n.nodes[1].snapshot().known["f2"] == (2, 2)
    assert n.named("fenced", 2) == []


@pytest.mark.parametrize("auth", MODES)
def test_a_restored_hold_needs_a_certificate_that_backs_it(paper: Paper, auth: str) -> None:
    """A state file that says `held: f2 at epoch 3` with no certificate (or one that
    does not back it) restores a standby, not a holder of f2, in every mode: nobody
    could be shown the proof of that hold."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    bare = Node(6, plan, params, 0.0, identity=ids[6] if auth == "per-robot" else None,
                keys=(KEY,) if auth == "shared" else (),
                restored=Restored(known={"f2": (6, 3)}, held=("f2", 3)))
    bare.tick(0.0)
    bare.tick(params.rejoin_hold + 0.1)
    snap = bare.snapshot()
    assert snap.function is None and snap.known["f2"] == (2, 0)


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize("who", [2, 6])
def test_a_robot_that_left_and_restarts_is_heard_again(paper: Paper, auth: str,
                                                       who: int) -> None:
    """`leave:R@3` then `restart:R@6`: the robot that left comes back above its last
    sequence number (what its daemon persisted on the way out), so nobody drops its
    frames as replays and the checker finds it muted nowhere; a holder that left is
    not the holder when it comes back."""
    from sim.shared.faults import parse_fault
    from sim.virtual.simulator import run_virtual

    plan, params = paper
    res = run_virtual(plan, params, duration=15.0, auth=auth,
                      faults=[parse_fault(f"leave:{who}@3"), parse_fault(f"restart:{who}@6")])
    assert res.violations == []
    assert sum(d.get("replay", 0) for d in res.drops.values()) == 0
    assert res.holders()["f2"] == [6 if who == 2 else 2]


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize("pause_s", [2.2, 2.6, 3.0])
def test_a_handover_that_ends_past_alert_after_still_alerts(paper: Paper, auth: str,
                                                            pause_s: float) -> None:
    """Standby 5 is dead; robots 2 and 3 report faults at once (two LEAVEs), and standby
    6 can take only one slot: f3 stays unheld. Its watcher 4 heard 3's LEAVE (a
    handover, with a live standby then) and freezes for longer than alert_after: the
    handover's deadline fires on resume as a new suspicion that is past alert_after
    already. The alert comes with it, so the warning ends in one (rule 8; invariant 4)
    instead of in nothing."""
    from sim.shared.faults import parse_fault
    from sim.virtual.simulator import run_virtual

    plan, params = paper
    res = run_virtual(plan, params, duration=14.0, auth=auth, faults=[
        parse_fault("crash:5@2.5"), parse_fault("unhealthy:2,3@3"),
        parse_fault(f"pause:4@3.1+{pause_s}")])
    assert [v.kind for v in res.violations] == []
    alerts = [e for e in res.events if e["event"] == "alert" and e["robot"] == 4]
    assert [(e["function"], e["reason"]) for e in alerts] == [("f3", "no claim")]
    assert alerts[0]["t"] == pytest.approx(3.1 + pause_s)


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize(("lower", "holder", "takeovers"), [
    ("unhealthy:5@4", 6, [(5, 1), (6, 1), (6, 2)]),   # 5 reports a fault; 1 hears its LEAVE
    ("deaf:1:5@3.9+3 unhealthy:5@4", 6, [(5, 1), (6, 1), (6, 2)]),  # ... nobody hears it
    ("deaf:1:5@3.9+1.5", 5, [(5, 1), (6, 1)]),     # 5 lives on, unheard by 1 for a while
])
def test_two_holders_of_one_epoch_end_with_the_one_that_executes(
        paper: Paper, auth: str, lower: str, holder: int,
        takeovers: list[tuple[int, int]]) -> None:
    """Robots 2, 3, 4 and 6 do not hear 1 and 5 for 2 s (1 and 5 hear them). Robot 2
    leaves: standbys 5 and 6 both take f2 over at epoch 1, each on its side (6 never
    hears 5's claim; 5 hears 6's but wins the race by its lower id). The entry (5, 1)
    outranks (6, 1) (slots.py), and views only move forward: once it reaches 6, 6 fences
    itself. If 5 stopped before the heal, the slot's watchers then suspect 5 and a
    standby takes f2 over at epoch 2 (here 6 again); if 5 lives, every view names 5."""
    from sim.shared.faults import parse_fault
    from sim.virtual.simulator import run_virtual

    _, params = paper
    specs = ["partition:1,5>2,3,4,6@3+2", "leave:2@3.2", *lower.split()]
    res = run_virtual(two_standbys(), params, duration=14.0, auth=auth,
                      faults=[parse_fault(s) for s in specs])
    assert sorted((e["robot"], e["epoch"]) for e in res.events
                  if e["event"] == "takeover") == takeovers
    assert [v.kind for v in res.violations] == []
    assert res.holders()["f2"] == [holder]


@pytest.mark.parametrize("seed", [45, 51, 0, 1, 2, 3])
def test_two_holders_of_one_epoch_on_a_lossy_channel_end_within_the_bound(
        paper: Paper, seed: int) -> None:
    """The race above at 25% loss, 5 living on (per robot: 6 fences itself only once it
    has 5's CLAIM, which its own evidence then certifies). 5 relays its claim to a rival
    of its own epoch every other heartbeat period, not every T_max: seeds 45 and 51 kept
    both executing past the checker's bound when it relayed once per T_max. (Unsigned
    and with a shared key, 6 fences on 5's first heartbeat: no certificate to wait for.)"""
    from sim.shared.faults import parse_fault
    from sim.virtual.simulator import run_virtual

    _, params = paper
    specs = ["partition:1,5>2,3,4,6@3+2", "leave:2@3.2"]
    res = run_virtual(two_standbys(), params, duration=12.0, auth="per-robot", loss=0.25,
                      seed=seed, faults=[parse_fault(s) for s in specs])
    assert [v.kind for v in res.violations] == []
    assert res.holders()["f2"] == [5]


def _run(paper: Paper, auth: str, specs: list[str], duration: float = 15.0):  # type: ignore[no-untyped-def]
    from sim.shared.faults import parse_fault
    from sim.virtual.simulator import run_virtual

    plan, params = paper
    return run_virtual(plan, params, duration=duration, auth=auth,
                       faults=[parse_fault(s) for s in specs])


@pytest.mark.parametrize("auth", MODES)
def test_a_new_holder_gone_before_a_cut_off_watcher_heard_it_is_replaced(
        paper: Paper, auth: str) -> None:
    """Watcher 1 is cut off from 3 s to 6 s. Robot 2 crashes: 6 takes f2 over at epoch
    1 (robot 3's warnings and its own ears, rule 9) and crashes too, before robot 1
    heard it; robot 2 restarts as a standby (it hears 6's takeover in the warnings).
    After the heal robot 1 warns about 2 at epoch 0, robot 3 about 6 at epoch 1: robot
    1's view must rise to 6's takeover (per robot: the certificate, relayed whole; with
    no signatures: robot 3's warning), so that 2, the one robot left that covers f2,
    counts two witnesses of one episode and takes f2 back at epoch 2."""
    res = _run(paper, auth, ["partition:1|2,3,4,5,6@3+3", "crash:2@3", "crash:6@4.5",
                             "restart:2@5"])
    assert [v.kind for v in res.violations] == []
    assert [(e["robot"], e["epoch"]) for e in res.events
            if e["event"] == "takeover" and e["function"] == "f2"] == [(6, 1), (2, 2)]
    assert res.holders()["f2"] == [2]


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_cut_off_through_its_takeover_holds_it_again_when_the_new_holder_died(
        paper: Paper, auth: str) -> None:
    """Robot 2 is cut off from 3 s to 5 s and executes on: 6 takes f2 over at epoch 1
    on the others' side, and crashes at 4.5 s. Views never move back (DESIGN
    "Convergence"). 6's certificate reaches 2 when 2 heartbeats epoch 0; 2, alive all
    along, refutes the warnings in it, and its reassertion (2, 2) outranks (6, 1)
    everywhere: 2 holds f2 on, in every mode."""
    res = _run(paper, auth, ["partition:2|1,3,4,5,6@3+2", "crash:6@4.5"])
    assert [v.kind for v in res.violations] == []
    assert [(e["robot"], e["epoch"]) for e in res.events
            if e["event"] == "takeover"] == [(6, 1)]
    assert res.holders()["f2"] == [2]
    assert res.final[2] == ("active", "f2", 2)


@pytest.mark.parametrize("auth", MODES)
def test_a_standby_alone_ahead_of_a_stale_holder_whose_new_holder_died_converges(
        paper: Paper, auth: str) -> None:
    """Standbys 5 and 6 both cover f2. Robot 2 is cut off both ways from 1 s to 8 s and
    executes on; 5 takes f2 over at epoch 1, but its heartbeats reach neither watcher
    (1 and 3) before it crashes at 5 s: standby 6 alone holds (5, 1), the watchers
    and 2 hold (2, 0), and nobody warns about 5. After the heal only 6 can carry the
    entry, with its proof (`Proofs._show`, DESIGN "Convergence"), in every mode; the
    digest alone only makes 2 heartbeat its older entry at 6. Without that proof, 6's
    view stays (5, 1) against (2, 0) for good."""
    _, params = paper
    res = _run((two_standbys(), params), auth, [
        "partition:2|1,3,4,5,6@1+7", "partition:5>1,3@1+5", "crash:5@5"], duration=30.0)
    assert [v.kind for v in res.violations] == []
    assert len(res.holders()["f2"]) == 1


@pytest.mark.parametrize("auth", MODES)
def test_a_stalled_holder_that_answers_out_of_its_buffer_does_not_pull_views_back(
        paper: Paper, auth: str) -> None:
    """Robot 2 freezes from 3 s to 5.5 s; 6 takes f2 over and crashes at 4.3 s. On
    resume 2 answers the buffered warnings about it with a heartbeat at epoch 0, then
    reads 6's epoch 1 in the same buffer and fences itself (rule 2). That one heartbeat
    must not bring the watchers' views back to 2 (they would then warn about a robot
    that no longer holds f2, and 2 would never count them): 2 takes f2 back at epoch 2."""
    res = _run(paper, auth, ["pause:2@3+2.5", "crash:6@4.3"])
    assert [v.kind for v in res.violations] == []
    assert [(e["robot"], e["epoch"]) for e in res.events
            if e["event"] == "takeover"] == [(6, 1), (2, 2)]
    assert res.holders()["f2"] == [2]


OVERLAPPING_CUTS = ("partition:9,7,15,1,6,11,8,12,13>2,3,4,5,10,14@14.95+1.92",
                    "partition:9>1,2,3,4,5,6,7,8,10,11,12,13,14,15@13.36+2.58",
                    "deaf:4:5@3.15+3.98", "crash:8@18.88")


@pytest.mark.parametrize("auth", MODES)
def test_overlapping_one_way_cuts_end_with_one_holder_and_one_view(auth: str) -> None:
    """Robot 9 is heard by nobody for 2.6 s, then a group is cut one way while that lasts
    (0 % loss, no attacker): standby 12 takes f9 over at epoch 1 and 14 takes it from 12
    at epoch 2 on its side of the second cut. Before the slot table, robots 9 and 14
    executed f9 from 14.0 s to the end of the run, the views split 9@0 against 14@2 for
    good. Now every view of f9 is one entry at the end, and one robot executes f9."""
    from pathlib import Path

    from sim.shared.faults import parse_fault
    from sim.virtual.simulator import run_virtual
    from swarmd.config import load_swarm

    cfg = load_swarm(Path(__file__).parent / "fixtures" / "chaos-overlapping-cuts.yaml")
    res = run_virtual(cfg.to_plan(), cfg.params(), duration=30.9, seed=40140, auth=auth,
                      faults=[parse_fault(s) for s in OVERLAPPING_CUTS])
    assert [v.kind for v in res.violations] == []
    assert len(res.holders()["f9"]) == 1
