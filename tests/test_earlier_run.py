"""Every proof is bound to its run (DESIGN section 2, "Who may say what"): frames recorded
in an earlier run prove nothing.

Run A: robot 2 reports a fault (its LEAVE of f2 at epoch 0) and standby 6 takes f2 over
(its CLAIM at epoch 1). Run B starts fresh (no state files) with the same keys, and an
outsider plays run A's frames back once the robots have heard each other. A robot's
seqs only rise, across restarts too, and within one run it never holds again an entry
it left; so a receiver that has heard 2 heartbeat f2 at epoch 0 at a seq above run A's
LEAVE refuses that LEAVE as `outdated` (`swarmd/core/words.py`), and one that has heard
6 heartbeat as a standby above run A's heartbeat of 6 holding f2 refuses that heartbeat,
before they back, start or move anything (run A's CLAIM is then uncertified): no epoch
change, no fence, nobody executes f2 but 2. In every mode alike: per robot, with a
shared key, and unsigned, where an outsider can forge anything anyway.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from harness import Net
from swarms import signed_paper

from sim.shared.fakeid import fake_identities
from swarmd.base.identity import Ed25519Signer, Keyring, private_key_path, read_private_key
from swarmd.config import load_robot, load_swarm
from swarmd.config.auth import public_keys
from swarmd.core import wire
from swarmd.core.actions import Assign
from swarmd.core.auth import Identity
from swarmd.core.node import Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Health
from swarmd.daemon.daemon import Daemon, run_daemon
from swarmd.link.none import NoneLink

Paper = tuple[SwarmPlan, Params]
KEY = b"r" * 32
MODES = ("per-robot", "shared", "none")
RUN_A, RUN_B = 10**8, 2 * 10**8
"""Where each run's sequence numbers start (a clock: run B is later)."""


def swarm(paper: Paper, auth: str, base: int, ids: dict[int, Identity] | None = None,
          key: bytes = KEY) -> Net:
    """The paper's swarm started fresh: no state files, counters from `base`."""
    plan, params = paper
    if ids is None:
        ids = fake_identities(plan.robots) if auth == "per-robot" else {}
    n = Net(plan, params, ids=[], keys=(key,) if auth != "none" else (), identities=ids)
    for r in sorted(plan.robots):
        n.boot(r, seq_start=base + 1000 * r)
    return n


def run_a(n: Net) -> dict[str, bytes]:
    """Run A: 2 reports a fault at 3 s, 6 takes f2 over. What an outsider recorded:
    2's LEAVE, 6's CLAIM and 6's first heartbeat as f2's holder."""
    n.run_until(3.0)
    n.inject(2, n.nodes[2].robot_health(Health.FAULTY, n.now))
    n.run_until(5.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]

    def first(sender: int, mtype: wire.MsgType, slot: int | None = None) -> bytes:
        return next(raw for _, s, raw in n.frames if s == sender
                    and (head := wire.peek(raw)) is not None and head.mtype == mtype
                    and (slot is None or head.slot == slot))

    return {"leave": first(2, wire.MsgType.LEAVE), "claim": first(6, wire.MsgType.CLAIM),
            "beat": first(6, wire.MsgType.HEARTBEAT, n.plan.slot("f2")),
            "standby": first(6, wire.MsgType.HEARTBEAT, 0)}


def cert(plan: SwarmPlan, raw: bytes, sender: int = 5) -> bytes:
    """`raw` wrapped in a CERT, as anyone can wrap a signed frame (the wrapper carries
    no signature of its own)."""
    inner = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
    return wire.encode(wire.Frame(plan.swarm_id, sender, 1, wire.Cert(plan.slot("f2"),
                                                                     inner, raw)))


def play(n: Net, *frames: bytes) -> None:
    """An outsider's radio: every live robot receives the frames now."""
    for raw in frames:
        for r in sorted(n.alive):
            n.inject(r, n.nodes[r].receive(raw, n.now))


def held_throughout(n: Net, robot: int, f: str) -> bool:
    """`robot` was told to execute f and never to stop."""
    out = n.outputs[robot]
    return bool(out) and all(isinstance(a, Assign) and a.function == f for a in out)


def views_of_f2(n: Net) -> set[tuple[int, int]]:
    hears = [r for r in n.alive if n.plan.slot("f2") in n.plan.relevant(r).slots]
    return {(holder, epoch) for holder, epoch in
            (n.nodes[r].snapshot().known["f2"] for r in hears)}


def outdated(n: Net) -> int:
    return sum(n.nodes[r].drops["outdated"] for r in n.alive)


def uncertified(n: Net) -> int:
    return sum(n.nodes[r].drops["uncertified"] for r in n.alive)


def played_at_run_b(paper: Paper, auth: str, *names: str, wrap: bool = False,
                    dead: int | None = None) -> Net:
    """Run A recorded, run B started fresh with the same keys and settled for 2 s (the
    robots heard each other's anchors), then run A's frames `names` played (inside
    CERTs with `wrap`), `dead` crashed just before."""
    plan = paper[0]
    ids = fake_identities(plan.robots) if auth == "per-robot" else None
    tape = run_a(swarm(paper, auth, RUN_A, ids))
    n = swarm(paper, auth, RUN_B, ids)
    n.run_until(2.0)
    if dead is not None:
        n.crash(dead)
    play(n, *(cert(plan, tape[k]) if wrap else tape[k] for k in names))
    return n


def moved_nothing(n: Net) -> None:
    """Nobody fenced, claimed or took over; 2 executes f2 throughout, 6 never; every
    view of f2 still at epoch 0."""
    assert n.named("fenced") == [] and n.named("takeover") == [] and n.named("claim") == []
    assert held_throughout(n, 2, "f2")
    assert n.outputs[6] == []
    assert views_of_f2(n) == {(2, 0)}


# ------------------------------------------------------------------ recorded certificates
@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_takeover_moves_nothing(paper: Paper, auth: str) -> None:
    """Two CERTs wrapping run A's LEAVE of 2 and CLAIM of 6, at run B's start. Every
    receiver has heard 2's word holding f2 at epoch 0 above the recording's seqs (per
    robot an anchor): the LEAVE is `outdated` and backs nothing, so the CLAIM is
    uncertified (before, 2 refuted its own LEAVE and the slot's epoch moved 0 -> 2)."""
    params = paper[1]
    n = played_at_run_b(paper, auth, "leave", "claim", wrap=True)
    n.run_until(2.0 + 8 * params.t_max)
    moved_nothing(n)
    assert outdated(n) > 0


@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_takeover_just_after_the_holder_died_is_refused(
        paper: Paper, auth: str) -> None:
    """The same frames just after 2 died in run B: 2's last word still says it held f2
    at epoch 0 after run A's LEAVE, so the recording backs nothing and f2 is taken over
    as a silent robot's slot, at epoch 1, replacing 2 (before: the recording named 6 as
    f2's holder, the watchers warned about 6, and 6 took f2 at epoch 2)."""
    params = paper[1]
    n = played_at_run_b(paper, auth, "leave", "claim", wrap=True, dead=2)
    n.run_until(2.0 + params.claim_horizon + params.takeover_bound(lossy=False))
    assert [(e["robot"], e["epoch"], e["replaced"]) for e in n.named("takeover")] == [
        (6, 1, 2)]
    assert n.nodes[6].snapshot().function == "f2" and views_of_f2(n) == {(6, 1)}


def restarted_before_the_recording(paper: Paper, auth: str, robot: int,
                                   dead: int | None = None) -> Net:
    """Run A recorded and run B started fresh; `robot` restarts at 1.95 s, `dead`
    crashes at 2.0 s, and then run A's LEAVE and CLAIM are played inside CERTs: `robot`
    has heard no word of 2 since its start (per robot an anchor comes every
    `anchor_every`; otherwise within a heartbeat period, unless 2 is dead)."""
    plan = paper[0]
    ids = fake_identities(plan.robots) if auth == "per-robot" else None
    tape = run_a(swarm(paper, auth, RUN_A, ids))
    n = swarm(paper, auth, RUN_B, ids)
    n.run_until(1.95)
    n.crash(robot)
    n.boot(robot, seq_start=RUN_B + 10**6)
    n.run_until(2.0)
    if dead is not None:
        n.crash(dead)
    play(n, cert(plan, tape["leave"]), cert(plan, tape["claim"]))
    return n


@pytest.mark.parametrize("auth", MODES)
def test_a_receiver_that_started_after_the_last_anchor_converges(
        paper: Paper, auth: str) -> None:
    """A receiver that restarted just before the recording was played has heard no
    anchor of 2 since (nothing to tell it by): within its start-up grace it refuses the
    LEAVE (`_outdated`), so f2 is never fenced nor taken over, and every view stays at
    (2, 0)."""
    params = paper[1]
    n = restarted_before_the_recording(paper, auth, 6)
    n.run_until(2.0 + params.claim_horizon + 16 * params.t_max)
    assert n.named("fenced") == [] and n.named("takeover") == []
    assert held_throughout(n, 2, "f2") and n.outputs[6] == []
    assert views_of_f2(n) == {(2, 0)}


@pytest.mark.parametrize("auth", MODES)
def test_a_watcher_in_its_grace_refuses_a_recorded_leave_of_a_dead_holder(
        paper: Paper, auth: str) -> None:
    """Watcher 1 restarts just before run A's LEAVE and CLAIM are played, and 2 dies
    then. 1 has heard no word of 2 since its start, so it cannot judge the LEAVE, and
    within its start-up grace it refuses it (`NodeBase._outdated`). Had it taken it, its
    view would name 6 at epoch 1 for good: 2 is dead and refutes nothing, so no
    reassertion settles the slot, and every other robot refuses the recording, so 1
    would warn about 6 and the others about 2, and no standby would count a quorum:
    f2 never taken over. Refused, f2 is taken over at epoch 1 as a silent robot's
    slot, and every view that hears f2 agrees."""
    params = paper[1]
    n = restarted_before_the_recording(paper, auth, 1, dead=2)
    n.run_until(2.0 + params.startup_grace + params.claim_horizon
                + params.takeover_bound(lossy=False))
    assert [(e["robot"], e["epoch"], e["replaced"]) for e in n.named("takeover")] == [
        (6, 1, 2)]
    assert views_of_f2(n) == {(6, 1)}


@pytest.mark.parametrize("auth", MODES)
def test_a_receiver_that_missed_every_word_of_the_holder_converges(
        paper: Paper, auth: str) -> None:
    """What is left: standby 6 hears nothing of 2 for its whole start-up grace (2 -> 6
    cut until 3 s), so at 2.5 s it cannot tell run A's LEAVE from a live one and takes
    the recorded takeover; 2 refutes its LEAVE, which moves 6 on to 2's reassertion
    (2, 2). Once it hears 2 again, 6 shows 2 its view with a doubt (`_older_beat`);
    2 then reasserts, and the robots that refused the LEAVE take it as the void backer
    of that reassertion: f2 is never fenced nor taken over, and every view ends at
    (2, 2)."""
    plan, params = paper
    ids = fake_identities(plan.robots) if auth == "per-robot" else {}
    tape = run_a(swarm(paper, auth, RUN_A, ids))
    n = Net(plan, params, ids=[], keys=(KEY,) if auth != "none" else (), identities=ids)
    n.cuts.append((2, 6, 0.0, 3.0))
    for r in sorted(plan.robots):
        n.boot(r, seq_start=RUN_B + 1000 * r)
    n.run_until(2.5)
    play(n, cert(plan, tape["leave"]), cert(plan, tape["claim"]))
    n.run_until(2.5 + params.claim_horizon + 30 * params.t_max)
    assert n.named("fenced") == [] and n.named("takeover") == []
    assert held_throughout(n, 2, "f2") and n.outputs[6] == []
    assert views_of_f2(n) == {(2, 2)}


def crashed_run_a(n: Net) -> list[bytes]:
    """Run A where 2 crashes at 3 s: 1 and 3 warn, 6 takes f2 over on their warnings.
    What an outsider recorded: 6's first CLAIM and the CERTs it sent before it (the
    warnings that back it)."""
    n.run_until(3.0)
    n.crash(2)
    n.run_until(6.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    sent = [raw for _, s, raw in n.frames if s == 6]
    claim = next(i for i, raw in enumerate(sent)
                 if (head := wire.peek(raw)) is not None and head.mtype == wire.MsgType.CLAIM)
    certs = [raw for raw in sent[:claim]
             if (head := wire.peek(raw)) is not None and head.mtype == wire.MsgType.CERT]
    assert len(certs) >= 2
    return [*certs, sent[claim]]


@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_takeover_backed_by_warnings_moves_nothing(paper: Paper, auth: str) -> None:
    """Run A's takeover backed by warnings (CERTs wrapping 1's and 3's warnings about 2,
    then 6's CLAIM), at run B's start. A warning is no word of its signer about itself,
    but the CLAIM is its claimant's: 6 heartbeats as a standby above it, so it backs no
    takeover (`outdated`). Before, every receiver merged (6, 1) before 2's refutes, and
    f2's epoch moved 0 -> 2 (2's reassertion)."""
    plan, params = paper
    ids = fake_identities(plan.robots) if auth == "per-robot" else None
    tape = crashed_run_a(swarm(paper, auth, RUN_A, ids))
    n = swarm(paper, auth, RUN_B, ids)
    n.run_until(2.0)
    play(n, *tape)
    n.run_until(2.0 + 8 * params.t_max)
    moved_nothing(n)
    assert outdated(n) > 0


@pytest.mark.parametrize("auth", MODES)
def test_a_certificate_outlives_its_signers_restarts(paper: Paper, auth: str) -> None:
    """A certificate is not voided by its signers' restarts: 2 crashes and 6 takes f2
    over on 1's and 3's warnings; then 1, 3 and 6 restart on their state files (6 is a
    standby, rejoining, for its rejoin hold) and 5 starts afresh with no state file.
    Its certificate relayed to 5 while 6 still heartbeats as a standby is refused (6's
    claim is below that word), but 6 resumes f2 at epoch 1, its claim counts again
    above its hold's heartbeats, and every view reaches (6, 1)."""
    plan, params = paper
    n = swarm(paper, auth, RUN_B, fake_identities(plan.robots) if auth == "per-robot" else None)
    n.run_until(2.5)
    n.crash(2)
    n.run_until(2.5 + params.claim_horizon + params.takeover_bound())
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    proof = [cert(plan, raw) for _, s, raw in n.frames if s == 6 and (
        head := wire.peek(raw)) is not None and head.mtype == wire.MsgType.CLAIM][:1]
    snaps = {r: n.nodes[r].snapshot() for r in (1, 3, 6)}
    for r in (1, 3, 5, 6):
        n.crash(r)
    for r, snap in snaps.items():
        n.boot(r, seq_start=RUN_B + 10**6 * r, restored=Restored(
            known=dict(snap.known), held=(snap.function, snap.epoch) if snap.function else None,
            peer_seq=snap.peer_seq, certificate=snap.certificate))
    restart = n.now
    n.boot(5, seq_start=RUN_B + 10**7)
    n.run_until(restart + params.rejoin_hold - params.heartbeat_interval)
    assert n.nodes[6].snapshot().function is None and proof
    n.inject(5, n.nodes[5].receive(proof[0], n.now))
    assert n.nodes[5].drops["outdated"] == 1
    n.run_until(restart + params.startup_grace + 16 * params.t_max)
    assert n.executing().get(6) == "f2" and n.named("fenced") == []
    assert views_of_f2(n) == {(6, 1)}


@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_word_moves_no_view(paper: Paper, auth: str) -> None:
    """Run A's heartbeat of 6 as f2's holder at epoch 1 (per robot an anchor), played
    raw: 6's later word says it is a standby, so it is `outdated` (a heartbeat never
    moves an epoch without its certificate anyway)."""
    n = played_at_run_b(paper, auth, "beat")
    n.run_until(3.0)
    assert n.named("fenced") == [] and held_throughout(n, 2, "f2")
    assert views_of_f2(n) == {(2, 0)} and outdated(n) > 0


# ------------------------------------------------------------------ every mode
@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_takeover_played_raw_at_a_fresh_start_moves_nothing(
        paper: Paper, auth: str) -> None:
    """Run A's LEAVE of 2, CLAIM of 6 and 6's first heartbeat as f2's holder at epoch 1,
    played raw at run B's start to receivers that have heard fewer than 64 of their
    senders' frames (no replay floor yet: DESIGN, "Sequence numbers"). Before, with a
    shared key or none, the heartbeat fenced live holder 2 at once and the LEAVE started
    6's claim; now all three are `outdated` in every mode."""
    params = paper[1]
    n = played_at_run_b(paper, auth, "leave", "claim", "beat")
    n.run_until(2.0 + 8 * params.t_max)
    moved_nothing(n)
    assert outdated(n) > 0


@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_hold_played_before_its_sender_is_heard_moves_nothing(
        paper: Paper, auth: str) -> None:
    """Run A's heartbeat of 6 holding f2 at epoch 1, played the moment run B starts,
    before any robot has heard 6's own heartbeat (nothing to tell the recording by yet).
    A heartbeat moves no entry without its certificate, in every mode: `uncertified`,
    and 2 executes f2 throughout."""
    plan, params = paper
    ids = fake_identities(plan.robots) if auth == "per-robot" else None
    tape = run_a(swarm(paper, auth, RUN_A, ids))
    n = swarm(paper, auth, RUN_B, ids)
    play(n, tape["beat"])
    n.run_until(params.startup_grace + 8 * params.t_max)
    moved_nothing(n)
    assert uncertified(n) > 0


@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_word_played_before_the_recorded_hold_makes_it_no_word(
        paper: Paper, auth: str) -> None:
    """Run A's heartbeat of 6 as a standby, then its heartbeat holding f2 at epoch 1
    (numbered above it), played in that order the moment run B starts. The first raises
    nothing and is taken as 6's word; the second, numbered above that word, still moves
    no entry without its certificate (`uncertified`)."""
    plan, params = paper
    ids = fake_identities(plan.robots) if auth == "per-robot" else None
    tape = run_a(swarm(paper, auth, RUN_A, ids))
    n = swarm(paper, auth, RUN_B, ids)
    play(n, tape["standby"], tape["beat"])
    n.run_until(params.startup_grace + 8 * params.t_max)
    moved_nothing(n)
    assert uncertified(n) > 0


def both_execute_f2(n: Net, until: float, step: float = 0.001) -> float:
    """Runs `n` to `until` in steps of `step`: how long 2 and 6 both executed f2."""
    both = 0.0
    while n.now < until:
        n.run_until(n.now + step)
        running = n.executing()
        both += step if running.get(2) == running.get(6) == "f2" else 0.0
    return both


def restarted_fresh_takes_f2_back(n: Net, params: Params) -> None:
    """2, down since 6 took f2 over at epoch 1, starts again now without its state file:
    it refutes what names its hold and reasserts, 6 is fenced, and both execute f2 for
    at most a heartbeat period; then 2 alone, and every view of f2 at (2, 2)."""
    restart = n.now
    n.boot(2, seq_start=RUN_B + 10**6)
    both = both_execute_f2(n, restart + params.startup_grace + 6 * params.t_max)
    assert both <= params.heartbeat_interval, both
    assert [r for r, f in n.executing().items() if f == "f2"] == [2]
    assert [e["robot"] for e in n.named("fenced")] == [6]
    assert views_of_f2(n) == {(2, 2)}


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_restarted_without_its_state_file_is_one_of_two_executors_for_ms(
        paper: Paper, auth: str) -> None:
    """2 crashes, 6 takes f2 over at epoch 1, and 2 restarts without its state file: the
    plan makes it f2's holder at epoch 0 and it executes at once. Its first heartbeat
    gets 6's proof; the warnings in it name 2's hold, which 2 (holding it, not stalled)
    refutes, so 6's takeover is voided and 2 holds on at its reassertion (DESIGN,
    "Convergence"), 6 fenced: two executors for a few ms, then one, and every view of
    f2 the same."""
    params = paper[1]
    ids = fake_identities(paper[0].robots) if auth == "per-robot" else None
    n = swarm(paper, auth, RUN_B, ids)
    n.run_until(2.5)
    n.crash(2)
    n.run_until(2.5 + params.claim_horizon + params.takeover_bound())
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    restarted_fresh_takes_f2_back(n, params)


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_that_left_and_restarted_without_its_state_file_refutes_its_leave_at_once(
        paper: Paper, auth: str) -> None:
    """2 reports a fault (its LEAVE of f2 at epoch 0) and 6 takes f2 over on it; 2 then
    restarts without its state file: the plan makes it f2's holder at epoch 0, and 6's
    proof rests on 2's own LEAVE, from before this start. 2 cannot tell it from a
    recording of an earlier run, so it refutes it as one (`Episode._record_evidence`),
    at once: its own LEAVE is no word of another robot to wait a start-up grace for.
    Two executors for a few ms, not the grace (2.1 s before), then 2 alone, and every
    view of f2 the same."""
    params = paper[1]
    ids = fake_identities(paper[0].robots) if auth == "per-robot" else None
    n = swarm(paper, auth, RUN_B, ids)
    n.run_until(3.0)
    n.inject(2, n.nodes[2].robot_health(Health.FAULTY, n.now))
    n.run_until(5.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    n.crash(2)
    restarted_fresh_takes_f2_back(n, params)


@pytest.mark.parametrize("auth", MODES)
def test_a_restarted_old_holder_learns_the_takeover_within_its_grace_and_never_resumes(
        paper: Paper, auth: str) -> None:
    """2 crashes, 6 takes f2 over at epoch 1, and 2 restarts on its state file (its
    hold of f2 at epoch 0). 6's heartbeats at (6, 1), uncertified at 2 until it is
    shown 6's proof, already tell its rejoin of f2 that it is superseded (rule 2 across
    a reboot): 2 never executes f2 again, and its view reaches (6, 1) within its
    start-up grace."""
    params = paper[1]
    n = swarm(paper, auth, RUN_B)
    n.run_until(2.5)
    snap = n.nodes[2].snapshot()
    n.crash(2)
    n.run_until(2.5 + params.claim_horizon + params.takeover_bound())
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    restart, before = n.now, len(n.outputs[2])
    n.boot(2, seq_start=RUN_B + 10**6, restored=Restored(
        known=dict(snap.known), held=("f2", 0), peer_seq=snap.peer_seq,
        certificate=snap.certificate))
    n.run_until(restart + params.startup_grace + params.heartbeat_interval)
    assert n.nodes[2].snapshot().known["f2"] == (6, 1)
    assert n.outputs[2][before:] == [] and n.named("fenced") == []
    n.run_until(restart + params.startup_grace + 4 * params.t_max)
    assert n.outputs[2][before:] == [] and views_of_f2(n) == {(6, 1)}
    assert n.executing()[6] == "f2"


@pytest.mark.parametrize("auth", MODES)
def test_a_leave_of_this_run_still_hands_over(paper: Paper, auth: str) -> None:
    """What a robot says in its current run is its latest word: 2's LEAVE in run B,
    above every heartbeat it sent before it, hands f2 to 6 at once, in every mode."""
    n = swarm(paper, auth, RUN_B)
    n.run_until(2.0)
    n.inject(2, n.nodes[2].robot_health(Health.FAULTY, n.now))
    n.run_until(4.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    assert outdated(n) == 0 and views_of_f2(n) == {(6, 1)}


@pytest.mark.parametrize("auth", MODES)
def test_a_robot_restarted_legitimately_is_heard_in_its_new_run(paper: Paper,
                                                                 auth: str) -> None:
    """A new run of a robot starts above anything it sent before (its seq reservation):
    6 crashes and restarts with no state file in run B, and its new frames are its
    word; then 2's LEAVE hands f2 to it as before."""
    n = swarm(paper, auth, RUN_B)
    n.run_until(2.0)
    n.crash(6)
    n.run_until(2.5)
    n.boot(6, seq_start=RUN_B + 10**6)
    n.run_until(5.0)
    n.inject(2, n.nodes[2].robot_health(Health.FAULTY, n.now))
    n.run_until(7.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    assert outdated(n) == 0


@pytest.mark.parametrize("auth", ["shared", "none"])
def test_without_robot_keys_a_receiver_that_remembers_drops_a_recording_as_a_replay(
        paper: Paper, auth: str) -> None:
    """Unsigned or with a shared key, a receiver whose state file remembers 6 (its
    floor) drops run A's heartbeat of 6 as a replay before anything else; with a shared
    key, a new key for the new run makes the recording worthless (`auth`)."""
    plan, params = paper
    tape = run_a(swarm(paper, auth, RUN_A))
    fresh = swarm(paper, auth, RUN_B)
    from swarmd.core.node import Node, Restored
    from swarmd.core.replay import header_seq

    again = Node(2, plan, params, 0.0, keys=fresh.keys, seq_start=RUN_B + 5000,
                 restored=Restored(known={"f2": (2, 0)}, held=("f2", 0),
                                   peer_seq={6: header_seq(tape["beat"]) + 10}))
    again.tick(0.0)
    again.receive(tape["beat"], 0.1)
    assert again.drops["replay"] == 1 and again.snapshot().known["f2"] == (2, 0)
    if auth == "shared":
        rekeyed = swarm(paper, auth, RUN_B, key=b"n" * 32)
        rekeyed.run_until(2.0)
        play(rekeyed, tape["beat"])
        rekeyed.run_until(2.1)
        assert rekeyed.named("fenced") == []
        assert sum(rekeyed.nodes[r].drops["auth"] for r in rekeyed.alive) > 0


# ------------------------------------------------------------------ real daemons
async def _until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        await asyncio.sleep(0.02)


def _key_identities(keys: Path, swarm_file: Path) -> dict[int, Identity]:
    """The swarm's real Ed25519 identities, read from its keys dir."""
    cfg = load_swarm(swarm_file)
    ring = Keyring(public_keys(cfg))
    return {r: Identity(Ed25519Signer(r, read_private_key(private_key_path(keys, r))), ring)
            for r in cfg.robot_ids()}


@pytest.mark.slow
async def test_a_recorded_takeover_fences_no_live_holder_on_real_daemons(
        paper: Paper, tmp_path: Path, udp_port: int) -> None:
    """Six `run_daemon` tasks over UDP on loopback, started fresh with the keys run A
    used ten minutes before (its frames made here with the same key files, counters
    from its clock then). Once they settle, robot 5's radio plays the two CERTs: holder
    2 keeps f2 (its link is never released), nobody is fenced, claims or takes over,
    every daemon that hears f2 keeps it at epoch 0, and those that heard the CERTs count
    them `outdated`."""
    swarm_file, keys = signed_paper(tmp_path)
    plan, params = paper
    then = wire.seq_seed(time.time() - 600)
    tape = run_a(swarm(paper, "per-robot", then, _key_identities(keys, swarm_file)))
    events: list[dict[str, Any]] = []
    daemons: dict[int, Daemon] = {}
    links = {r: NoneLink() for r in range(1, 7)}
    stop = asyncio.Event()
    tasks = []
    for r in range(1, 7):
        path = tmp_path / f"robot{r}.yaml"
        path.write_text(f"robot: {r}\nswarm: {swarm_file}\nstate_dir: {tmp_path / 'state'}\n"
                        f"identity_file: keys/robot-{r}.key\n"
                        f"transport: {{kind: udp, port: {udp_port}}}\n")
        tasks.append(asyncio.create_task(run_daemon(
            load_robot(path), link=links[r], event_sink=events.append, stop_event=stop,
            on_ready=lambda d, r=r: daemons.__setitem__(r, d))))  # type: ignore[misc]

    def views() -> set[tuple[int, int]]:
        return {tuple(daemons[r].runtime.snapshot().known["f2"])  # type: ignore[union-attr]
                for r in (1, 2, 3, 5, 6)}

    def outdated_at(robots: tuple[int, ...]) -> int:
        counts = [rt.drop_counts().get("outdated", 0) for r in robots
                  if (rt := daemons[r].runtime) is not None]
        return sum(counts)

    try:
        await _until(lambda: len(daemons) == 6, 20.0, "six daemons ready")
        await asyncio.sleep(3 * params.startup_grace / 2)
        assert links[2].function == "f2"
        radio = daemons[5].runtime
        assert radio is not None
        for raw in (tape["leave"], tape["claim"]):
            assert radio.send_raw(cert(plan, raw))
        await _until(lambda: outdated_at((1, 3, 6)) >= 2, 10.0, "the CERTs outdated")
        await asyncio.sleep(4 * params.t_max)
        got = [(e["robot"], e["event"], e.get("function")) for e in events]
        assert not [e for e in got if e[1] in ("fenced", "takeover", "claim")], got
        assert views() == {(2, 0)}
        assert links[2].function == "f2"
        assert ("release", "f2", None) not in links[2].history
    finally:
        stop.set()
        await asyncio.wait_for(asyncio.gather(*tasks, return_exceptions=True), 30.0)

