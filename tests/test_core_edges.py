"""The node's rarer branches, each reached by the protocol situation it exists for.

Every branch of `swarmd.core` exercised through its public API (sans-IO: no mocks,
DESIGN section 2). `tests/test_node.py` covers the main rules; this file covers the edges:
misuse, a stopped node, late ticks, health changes while claiming, claim races that
only a swarm with two standbys per slot produces, epoch saturation, stalls while
claiming, restored state that no longer matches the plan, and the rejoin hold
(DESIGN rule 2). Everything runs on virtual time, driven as the runtime drives it.

The shared plan below differs from the paper's in one way: standbys 5 *and* 6 cover
f2, so two standbys can race for it (DESIGN rule 6) and one can miss the other's
takeover.
"""

from __future__ import annotations

from collections.abc import Sequence

import pytest
from test_node import Driven, events, frame, hb, own, past_grace, sent, started

from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Release
from swarmd.core.node import Node, NodeError, Restored
from swarmd.core.params import Params
from swarmd.core.plan import RobotPlan, SwarmPlan
from swarmd.core.roles import Health, Role


@pytest.fixture(scope="module")
def shared_plan(paper_plan: SwarmPlan) -> SwarmPlan:
    """The paper's ring, but standby 5 covers f1, f2, f4 and standby 6 covers f2, f3."""
    robots = dict(paper_plan.robots)
    robots[5] = RobotPlan(5, None, ("f1", "f2", "f4"))
    return SwarmPlan(paper_plan.swarm_id, paper_plan.functions, robots, paper_plan.watches)


def assigns(actions: Sequence[Action]) -> list[Assign]:
    return [a for a in actions if isinstance(a, Assign)]


def proof_of(plan: SwarmPlan, holder: int, epoch: int, failed: int) -> list[bytes]:
    """The proof of `holder`'s takeover of f2 at `epoch` from `failed`, as a robot
    that holds it shows it (`Proofs._show`): the warnings of f2's witnesses 1 and 3
    about `failed` at the epoch before, then `holder`'s CLAIM, each inside a CERT."""
    slot = plan.slot("f2")
    warn = wire.Warn(failed, slot, epoch - 1)
    inner = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))  # only `raw` goes on the wire
    return [frame(plan, 5, wire.Cert(slot, inner, raw))
            for raw in (frame(plan, 1, warn), frame(plan, 3, warn),
                        frame(plan, holder, wire.Claim(failed, slot, epoch)))]


def quorum_on(node: Driven, plan: SwarmPlan, suspect: int, f: str, epoch: int,
              t: float) -> list[Action]:
    """Both witnesses of `f` (the holders of f1 and f3 for f2, DESIGN rule 3) warn."""
    warn = wire.Warn(suspect, plan.slot(f), epoch)
    witnesses = [plan.initial_holder(g) for g in plan.watched_by(f)]
    out: list[Action] = []
    for i, w in enumerate(witnesses):
        assert w is not None
        out += node.receive(frame(plan, w, warn), t + 0.01 * i)
    return out


# ---------------------------------------------------------------------- construction
def test_a_robot_outside_the_plan_is_misuse(paper_plan: SwarmPlan,
                                            udp_params: Params) -> None:
    with pytest.raises(NodeError, match="robot 9 is not in the swarm plan"):
        Node(9, paper_plan, udp_params, 0.0)


def test_restored_state_about_a_function_the_plan_dropped_is_ignored(
        paper_plan: SwarmPlan, udp_params: Params) -> None:
    # Robot 2 held "f9" before the swarm file was edited and f9 removed: its persisted
    # state must neither enter `known` nor start a rejoin hold for a slot with no wire
    # index. Having persisted state, it starts as a standby (it may have been replaced).
    restored = Restored(known={"f9": (2, 4), "f2": (6, 3)}, held=("f9", 4))
    node, actions = started(paper_plan, udp_params, 2, restored=restored)
    assert set(node.snapshot().known) == set(paper_plan.functions)
    assert node.snapshot().known["f2"] == (6, 3)  # the entry the plan still has is kept
    # no hold: it tells how it started at once, and executes nothing
    assert [e.fields() for e in events(actions, ev.Started)] == [{"role": "standby",
                                                               "function": None}]
    assert not assigns(actions)
    assert node.next_deadline() == pytest.approx(udp_params.standby_heartbeat_interval)


# ---------------------------------------------------------------------- stopping
def test_a_stopped_node_ignores_frames_time_and_a_second_stop(
        paper_plan: SwarmPlan, udp_params: Params) -> None:
    node, _ = started(paper_plan, udp_params, 2)
    out = node.node.stop(1.0, handover=True)
    assert len(events(out, ev.Stopped)) == 1
    newer = frame(paper_plan, 6, hb(paper_plan, "f1", epoch=3))
    frames_in = node.snapshot().frames_in
    # what would fence a running node (f1 is a neighbour slot) changes nothing now
    assert node.node.receive(newer, 1.1) == []
    assert node.node.receive_frame(wire.decode(frame(paper_plan, 6, hb(paper_plan, "f2", 5))),
                                   1.2) == []
    assert node.snapshot().frames_in == frames_in
    assert node.snapshot().known["f1"] == (1, 0)
    assert node.snapshot().known["f2"] == (2, 0)
    # neighbours silent far past t_max and the grace time: no warning, no heartbeat
    assert node.node.tick(10.0) == []
    assert node.next_deadline() is None
    # the driver stopping twice (signal during shutdown) sends no second LEAVE
    assert node.node.stop(10.1, handover=True) == []


@pytest.mark.parametrize("handover", [True, False])
def test_stop_releases_and_leaves_only_when_asked(paper_plan: SwarmPlan, udp_params: Params,
                                                  handover: bool) -> None:
    node, _ = started(paper_plan, udp_params, 2)
    out = node.node.stop(1.0, handover=handover)
    assert Release("f2") in out and events(out, ev.Stopped)
    leave = wire.Leave(paper_plan.slot("f2"), 0, wire.LeaveReason.SHUTDOWN)
    # without handover the neighbours find out by timeout (handover_on_stop: false)
    assert sent(out) == ([leave] if handover else [])
    assert bool(events(out, ev.Leave)) is handover


# ---------------------------------------------------------------------- heartbeats
def test_a_late_tick_sends_one_heartbeat_not_a_burst(paper_plan: SwarmPlan,
                                                     udp_params: Params) -> None:
    node, _ = started(paper_plan, udp_params, 1)
    period = udp_params.heartbeat_interval
    # served 1.5 periods late (busy loop), yet less than t_max/2: not a stall
    late = 1.5 * period
    assert late < udp_params.t_max / 2
    out = node.tick(period + late)
    assert [m for m in sent(out) if isinstance(m, wire.Heartbeat)] == [hb(paper_plan, "f1")]
    # one period after the deadline is already past: the next one is a period from now,
    # not an immediate second heartbeat
    assert node.next_deadline() == pytest.approx(2 * period + late)


def test_back_from_a_fault_a_standby_heartbeats_at_once(paper_plan: SwarmPlan,
                                                        udp_params: Params) -> None:
    node, _ = started(paper_plan, udp_params, 6)  # heartbeat at 0, next at 0.5
    assert node.robot_health(Health.FAULTY, 0.05) == []
    assert node.next_deadline() is None  # faulty: silent (DESIGN rule 7)
    node.robot_health(Health.OK, 0.2)
    # rule 7 ends: watchers learn at once that a standby is back (rules 6, 8)
    assert node.next_deadline() == pytest.approx(0.2)
    assert sent(node.tick(0.2)) == [hb(paper_plan, None, role=Role.STANDBY)]


def test_degraded_is_reported_without_changing_the_schedule(paper_plan: SwarmPlan,
                                                            udp_params: Params) -> None:
    node, _ = started(paper_plan, udp_params, 6)
    assert node.robot_health(Health.DEGRADED, 0.1) == []
    assert node.next_deadline() == pytest.approx(0.5)  # not a recovery: no extra heartbeat
    degraded = wire.Heartbeat(0, 0, int(Role.STANDBY), int(Health.DEGRADED))
    assert sent(node.tick(0.5)) == [degraded]
    node.robot_health(Health.OK, 0.6)
    assert node.next_deadline() == pytest.approx(1.0)
    assert sent(node.tick(1.0)) == [hb(paper_plan, None, role=Role.STANDBY)]


# ---------------------------------------------------------------------- claims
def test_a_fault_while_claiming_abandons_the_claim(paper_plan: SwarmPlan,
                                                   udp_params: Params) -> None:
    node, _ = started(paper_plan, udp_params, 6)
    assert events(quorum_on(node, paper_plan, 2, "f2", 0, 0.1), ev.Claim)
    out = node.robot_health(Health.FAULTY, 0.15)
    assert not sent(out)  # nothing held, so no LEAVE
    assert node.snapshot().role is Role.STANDBY
    # a faulty robot must not take the slot over when the hold runs out (rule 7)
    out = node.tick(0.1 + udp_params.claim_hold) + node.run_to(3.0)
    assert not assigns(out) and not events(out, ev.Takeover) and not sent(out)


@pytest.mark.parametrize("epoch", [1, 2])
def test_a_heartbeat_at_the_claimed_epoch_supersedes_the_claim(
        shared_plan: SwarmPlan, udp_params: Params, epoch: int) -> None:
    # 5 and 6 both claimed f2 after 2 died; 6 lost 5's CLAIM but is shown the proof of
    # 5's takeover (a robot that holds it shows it to one that acts on an older view)
    # and hears 5's heartbeat as the new holder: 6 backs off instead of executing f2
    # too (rule 2).
    node, _ = started(shared_plan, udp_params, 6)
    quorum_on(node, shared_plan, 2, "f2", 0, 0.1)
    assert node.snapshot().role is Role.CLAIMING
    out: list[Action] = []
    for raw in proof_of(shared_plan, 5, epoch, 2):
        out += node.receive(raw, 0.14)
    out += node.receive(frame(shared_plan, 5, hb(shared_plan, "f2", epoch=epoch)), 0.15)
    out += node.run_to(udp_params.startup_grace)
    assert [e.fields() for e in events(out, ev.Backoff)] == [
        {"subject": 2, "function": "f2", "winner": 5}]
    assert node.snapshot().role is Role.STANDBY
    assert node.snapshot().known["f2"] == (5, epoch)
    out += node.run_to(3.0)
    assert not assigns(out) and not events(out, ev.Takeover)


def test_a_stale_holder_does_not_cancel_a_claim_against_a_newer_one(
        shared_plan: SwarmPlan, udp_params: Params) -> None:
    # 6 missed 5's takeover of f2 (epoch 1); 5 then died and its witnesses warn about
    # (5, epoch 1). Meanwhile 2, the holder before 5, comes back from a long pause and
    # heartbeats f2 at epoch 0. That is not the suspect answering: the claim goes on.
    node, _ = started(shared_plan, udp_params, 6)
    t = past_grace(node, udp_params)
    out = quorum_on(node, shared_plan, 5, "f2", 1, t + 0.1)
    assert events(out, ev.Claim)[0].fields() == {"subject": 5, "function": "f2", "epoch": 2}
    out = node.receive(frame(shared_plan, 2, hb(shared_plan, "f2", epoch=0)), t + 0.15)
    assert not events(out, ev.Refute) and not events(out, ev.Backoff)
    assert node.snapshot().role is Role.CLAIMING
    out = node.run_to(t + 0.11 + udp_params.claim_hold)
    assert [e.fields() for e in events(out, ev.Takeover)] == [
        {"function": "f2", "epoch": 2, "replaced": 5}]
    assert assigns(out) == [Assign("f2", 2)]


def test_warnings_about_an_older_holder_are_not_counted(shared_plan: SwarmPlan,
                                                        udp_params: Params) -> None:
    node, _ = started(shared_plan, udp_params, 6)
    t = past_grace(node, udp_params)
    for raw in proof_of(shared_plan, 5, 1, 2):  # 5 took f2, and shows it
        node.receive(raw, t + 0.05)
    node.receive(frame(shared_plan, 5, hb(shared_plan, "f2", epoch=1)), t + 0.1)
    slot = shared_plan.slot("f2")
    # delayed warnings from before the takeover: about an entry below the slot's (the
    # slot table's order, `slots.py`: an older epoch is lower whoever it names)
    for stale in (wire.Warn(2, slot, 0), wire.Warn(4, slot, 0)):
        out = quorum_on(node, shared_plan, stale.suspect, "f2", stale.epoch, t + 0.2)
        assert not events(out, ev.Vote) and not events(out, ev.Claim)
    assert node.snapshot().votes == {} and node.snapshot().role is Role.STANDBY
    # control: a warning about the current holder does count
    out = node.receive(frame(shared_plan, 1, wire.Warn(5, slot, 1)), t + 0.3)
    assert [e.fields()["count"] for e in events(out, ev.Vote)] == [1]


def test_the_epoch_saturates_instead_of_wrapping(paper_plan: SwarmPlan,
                                                 udp_params: Params) -> None:
    # The 65536th takeover of one slot: the epoch field is 16 bits on the wire, so the
    # claim saturates rather than wrap to 0 (which would rank below every entry). At
    # the last epoch the slot table has nowhere forward to go but a lower id (`slots.py`):
    # standby 6 cannot outrank holder 2 there, and no certificate backs a claim that
    # does not move the epoch forward, so the claim ends in its wait state (logged as
    # refuted) instead of taking over a slot whose every view would fence it at once.
    node, _ = started(paper_plan, udp_params, 6)
    t = past_grace(node, udp_params)
    out = quorum_on(node, paper_plan, 2, "f2", 0xFFFF, t + 0.1)
    assert events(out, ev.Claim)[0].fields()["epoch"] == 0xFFFF
    assert own(out) == [wire.Claim(2, paper_plan.slot("f2"), 0xFFFF)]
    out = node.run_to(t + 0.11 + udp_params.claim_hold)
    assert assigns(out) == [] and not events(out, ev.Takeover)
    assert [e.fields() for e in events(out, ev.Refute)] == [{"subject": 2, "function": "f2"}]
    assert node.snapshot().role is Role.STANDBY


@pytest.mark.parametrize("suspect_alive", [True, False])
def test_a_stall_while_claiming_listens_again_before_taking_over(
        paper_plan: SwarmPlan, udp_params: Params, suspect_alive: bool) -> None:
    node, _ = started(paper_plan, udp_params, 6)
    quorum_on(node, paper_plan, 2, "f2", 0, 0.1)
    assert node.snapshot().role is Role.CLAIMING
    # The process froze (SIGSTOP) past the claim hold. Whatever came meanwhile (a lower
    # claimant, the suspect's refutation) is still queued: hold a full claim_hold again.
    resumed = 2.0
    out = node.tick(resumed)
    assert not assigns(out) and not events(out, ev.Takeover)
    assert wire.Claim(2, paper_plan.slot("f2"), 1) in sent(out)  # the claim is repeated
    if suspect_alive:
        out = node.receive(frame(paper_plan, 2, hb(paper_plan, "f2")), resumed + 0.05)
        assert events(out, ev.Refute)
        assert not assigns(node.run_to(resumed + 2.0))
        assert node.snapshot().role is Role.STANDBY
    else:
        assert not assigns(node.run_to(resumed + udp_params.claim_hold - 0.01))
        out = node.run_to(resumed + udp_params.claim_hold)
        assert assigns(out) == [Assign("f2", 1)]


# ---------------------------------------------------------------------- rejoin (rule 2)
@pytest.mark.parametrize(("rid", "known_f2", "held"), [
    (2, (6, 1), ("f2", 0)),  # persisted: replaced at a higher epoch
    (6, (2, 1), ("f2", 1)),  # persisted: same epoch held by a lower id (rule 2's tie)
])
def test_restored_knowledge_of_a_newer_holder_ends_the_hold_as_standby(
        paper_plan: SwarmPlan, udp_params: Params, rid: int, known_f2: tuple[int, int],
        held: tuple[str, int]) -> None:
    # The hold's certificate kept with it (a hold at epoch 1 is provable only with it,
    # `Restart._verified_hold`): the warnings of f2's witnesses about 2 at epoch 0.
    warn = wire.Warn(2, paper_plan.slot("f2"), 0)
    proof = (frame(paper_plan, 1, warn), frame(paper_plan, 3, warn)) if held[1] else ()
    restored = Restored(known={"f2": known_f2}, held=held, certificate=proof)
    node, out = started(paper_plan, udp_params, rid, restored=restored)
    assert not events(out, ev.Started)  # the hold still runs: others may know more
    out += node.run_to(udp_params.rejoin_hold + 0.05)
    assert not assigns(out)
    assert [e.fields() for e in events(out, ev.Started)] == [{"role": "standby",
                                                           "function": None}]
    assert node.snapshot().role is Role.STANDBY


# A robot in its rejoin hold has the STANDBY role, so it also acts as a standby (counts
# votes, answers LEAVE). `_finish_rejoin` assumes nothing happened meanwhile.
# The rejoin hold (node.py `_finish_rejoin`, `_rejoin_superseded`, `_standing_by`): a
# robot that claimed or took over during its hold raised TransitionError at the hold's end
# or logged started{standby} while ACTIVE; a WARN or CLAIM at a newer epoch did not end
# the hold; a fault during the hold meant no `started`. The tests below reproduced each.

Feed = tuple[float, int | Health, wire.Message | None]


def _rejoin(plan: SwarmPlan, params: Params, rid: int, known: dict[str, tuple[int, int]],
            held: tuple[str, int], feed: Sequence[Feed]) -> tuple[Driven, list[Action]]:
    node, out = started(plan, params, rid, restored=Restored(known=known, held=held))
    for t, who, msg in feed:
        out += node.run_to(t)
        if isinstance(who, Health):
            out += node.robot_health(who, t)
        else:
            assert msg is not None
            out += node.receive(frame(plan, who, msg), t)
    out += node.run_to(3.0)
    return node, out


def _one_consistent_start(node: Driven, out: list[Action]) -> None:
    """Exactly one `started` per boot, told before the robot acts as a standby or holder,
    and the robot executes at most one function at a time, the one its state names."""
    names = [e.name for e in out if isinstance(e, ev.Event)]
    assert names.count("started") == 1, names
    first = names.index("started")
    assert not {"claim", "takeover"} & set(names[:first]), names
    held: list[str] = []
    for a in out:
        if isinstance(a, Assign):
            assert not held, f"{a} while executing {held}"
            held.append(a.function)
        elif isinstance(a, Release):
            held.remove(a.function)
    snap = node.snapshot()
    assert held == ([snap.function] if snap.role is Role.ACTIVE else [])


def _base(plan: SwarmPlan) -> dict[str, tuple[int, int]]:
    return {f: (plan.initial_holder(f) or 0, 0) for f in plan.functions}


@pytest.mark.parametrize("at", [0.1, 0.55], ids=["claim-done-in-hold", "claim-spans-end"])
def test_a_quorum_during_the_hold_gives_one_consistent_start(
        paper_plan: SwarmPlan, udp_params: Params, at: float) -> None:
    # 2 crashed holding f2 at epoch 0; 6 took it over (epoch 1) and died too. 2 reboots
    # and, in its hold, hears both witnesses warn about (6, f2, 1): proof of a newer
    # epoch (so no resuming at 0, `_on_warn`), and a quorum to claim f2 again.
    slot = paper_plan.slot("f2")
    feed: list[Feed] = [(at, 1, wire.Warn(6, slot, 1)), (at + 0.01, 3, wire.Warn(6, slot, 1))]
    node, out = _rejoin(paper_plan, udp_params, 2, _base(paper_plan), ("f2", 0), feed)
    _one_consistent_start(node, out)
    assert Assign("f2", 0) not in out


def test_a_leave_during_the_hold_gives_one_consistent_start(paper_plan: SwarmPlan,
                                                            udp_params: Params) -> None:
    # 6 reboots holding f2 (epoch 1); in its hold 3 reports a fault and leaves f3,
    # which 6 also covers: 6 takes f3 over, then the hold ends on f2.
    known = {**_base(paper_plan), "f2": (6, 1)}
    feed: list[Feed] = [(0.1, 3, wire.Leave(paper_plan.slot("f3"), 0, wire.LeaveReason.FAULT))]
    node, out = _rejoin(paper_plan, udp_params, 6, known, ("f2", 1), feed)
    _one_consistent_start(node, out)


def test_a_fault_during_the_hold_still_tells_how_the_robot_started(
        paper_plan: SwarmPlan, udp_params: Params) -> None:
    feed: list[Feed] = [(0.1, Health.FAULTY, None), (1.0, Health.OK, None)]
    node, out = _rejoin(paper_plan, udp_params, 2, _base(paper_plan), ("f2", 0), feed)
    _one_consistent_start(node, out)
    assert node.snapshot().role is Role.STANDBY


def test_a_claim_at_a_newer_epoch_ends_the_hold(paper_plan: SwarmPlan,
                                                udp_params: Params) -> None:
    # `_rejoin_superseded`: "Someone holds or claims our old slot at a newer epoch: stay
    # a standby." 6's CLAIM for f2 at epoch 1 arrives after the witnesses' warnings
    # that certify it; its heartbeats are lost.
    slot = paper_plan.slot("f2")
    feed: list[Feed] = [(0.05, 1, wire.Warn(2, slot, 0)), (0.06, 3, wire.Warn(2, slot, 0)),
                        (0.1, 6, wire.Claim(2, slot, 1))]
    _, out = _rejoin(paper_plan, udp_params, 2, _base(paper_plan), ("f2", 0), feed)
    assert Assign("f2", 0) not in out
    assert [e.fields() for e in events(out, ev.Started)] == [{"role": "standby",
                                                           "function": None}]
