"""Every proof is bound to its run (DESIGN section 2, "Who may say what"): frames recorded
in an earlier run prove nothing.

Run A: robot 2 reports a fault (its signed LEAVE of f2 at epoch 0) and standby 6 takes
f2 over (its signed CLAIM at epoch 1). Run B starts fresh (no state files) with the
same keys, and an outsider plays run A's frames back. Before, two CERTs wrapping that
LEAVE and that CLAIM fenced live holder 2 at once: f2 ran nowhere for 0.9 s. Now robot
2, which holds the very entry that LEAVE left, refutes its own LEAVE (within one run of
a daemon a robot never holds again the entry it left), and that one signed frame voids
the recorded takeover wherever it reaches: 2 holds f2 throughout.

Unsigned or with a shared key a frame carries nothing of its run: the replay filter's
memory is all these modes check (DESIGN, "Sequence numbers").
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
            "beat": first(6, wire.MsgType.HEARTBEAT, n.plan.slot("f2"))}


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


# ------------------------------------------------------------------ per robot
def test_per_robot_a_recorded_takeover_fences_no_live_holder(paper: Paper) -> None:
    """The issue's frames: two CERTs wrapping run A's LEAVE of 2 and CLAIM of 6, at run
    B's start. 2 refutes its own LEAVE (signed), so the recorded takeover is void at
    every robot: 2 executes f2 throughout, nobody is fenced or takes over. Robots that
    had already merged the recorded entry (6, 1) move forward to 2's reassertion (2, 2)
    — the slot table only moves forward (DESIGN, "Convergence") — and all agree."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    tape = run_a(swarm(paper, "per-robot", RUN_A, ids))
    n = swarm(paper, "per-robot", RUN_B, ids)
    n.run_until(2.0)
    play(n, cert(plan, tape["leave"]), cert(plan, tape["claim"]))
    n.run_until(2.0 + 8 * params.t_max)
    assert n.named("fenced") == [] and n.named("takeover") == []
    assert held_throughout(n, 2, "f2")
    assert any(e["subject"] == 2 for e in n.named("refute", 2))
    assert views_of_f2(n) == {(2, 2)}


def test_per_robot_a_recorded_takeover_naming_a_live_standby_gets_f2_a_holder(
        paper: Paper) -> None:
    """The same frames just after 2 died in run B: the swarm learns that 6 holds f2,
    which 6 does not. 6 hears the warnings about itself and, as f2's standby, takes it
    over at the next epoch (it used to ignore them: f2 was left to nobody while 6
    lived)."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    tape = run_a(swarm(paper, "per-robot", RUN_A, ids))
    n = swarm(paper, "per-robot", RUN_B, ids)
    n.run_until(2.0)
    n.crash(2)
    play(n, cert(plan, tape["leave"]), cert(plan, tape["claim"]))
    n.run_until(2.0 + params.claim_horizon + params.takeover_bound(lossy=False))
    assert [(e["robot"], e["epoch"], e["replaced"]) for e in n.named("takeover")] == [
        (6, 2, 6)]
    assert n.nodes[6].snapshot().function == "f2" and views_of_f2(n) == {(6, 2)}


@pytest.mark.parametrize("auth", MODES)
def test_a_recorded_leave_played_at_a_fresh_start_replaces_nobody(paper: Paper,
                                                                  auth: str) -> None:
    """Run A's LEAVE of 2 played raw at run B's start, to receivers that have not heard
    64 of 2's frames yet (no floor: DESIGN, "Sequence numbers"): standby 6 starts a
    claim, and 2, alive, stops it (rule 4: its heartbeat, and per robot the refute of
    its own LEAVE). In every mode, 2 executes f2 throughout."""
    plan, params = paper
    ids = fake_identities(plan.robots) if auth == "per-robot" else {}
    tape = run_a(swarm(paper, auth, RUN_A, ids))
    n = swarm(paper, auth, RUN_B, ids)
    n.run_until(2.0)
    play(n, tape["leave"])
    n.run_until(2.0 + 4 * params.t_max)
    assert n.named("takeover") == [] and n.named("fenced") == []
    assert held_throughout(n, 2, "f2")
    assert len(views_of_f2(n)) == 1


def test_per_robot_a_recorded_heartbeat_moves_no_view(paper: Paper) -> None:
    """Run A's heartbeat of 6 as f2's holder at epoch 1 (an anchor, signed): per robot a
    heartbeat never moves an epoch or a holder without its certificate (`uncertified`)."""
    plan = paper[0]
    ids = fake_identities(plan.robots)
    tape = run_a(swarm(paper, "per-robot", RUN_A, ids))
    n = swarm(paper, "per-robot", RUN_B, ids)
    n.run_until(2.0)
    play(n, tape["beat"])
    n.run_until(3.0)
    assert n.named("fenced") == [] and held_throughout(n, 2, "f2")
    assert views_of_f2(n) == {(2, 0)}


@pytest.mark.parametrize("auth", ["shared", "none"])
def test_without_robot_keys_a_recording_is_checked_by_the_filters_memory_only(
        paper: Paper, auth: str) -> None:
    """Unsigned or with a shared key, what a receiver can check of an old frame is its
    replay filter's memory. Run A's heartbeat of 6 at epoch 1, played at run B's start:
    a robot that has heard fewer than 64 of 6's frames takes it and 2 is fenced (what
    these modes cannot check, DESIGN "Who can still do what"); a robot whose state file
    remembers 6 (its floor) drops it as a replay; with a shared key, a new key for the
    new run makes the recording worthless (`auth`)."""
    plan, params = paper
    tape = run_a(swarm(paper, auth, RUN_A))
    fresh = swarm(paper, auth, RUN_B)
    fresh.run_until(2.0)
    play(fresh, tape["beat"])
    fresh.run_until(2.1)
    assert [e["robot"] for e in fresh.named("fenced")] == [2]
    # A receiver that remembers 6 (its state file's peer_seq, from the run that sent
    # the recording).
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
    2 keeps f2 (its link is never released), nobody is fenced or takes over, and every
    daemon that hears f2 ends at 2's reassertion."""
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

    try:
        await _until(lambda: len(daemons) == 6, 20.0, "six daemons ready")
        await asyncio.sleep(3 * params.startup_grace / 2)
        assert links[2].function == "f2"
        radio = daemons[5].runtime
        assert radio is not None
        for raw in (tape["leave"], tape["claim"]):
            assert radio.send_raw(cert(plan, raw))
        await _until(lambda: views() == {(2, 2)}, 10.0, "views of f2 at 2's reassertion")
        await asyncio.sleep(params.t_max)
        got = [(e["robot"], e["event"], e.get("function")) for e in events]
        assert not [e for e in got if e[1] in ("fenced", "takeover")], got
        assert links[2].function == "f2"
        assert ("release", "f2", None) not in links[2].history
    finally:
        stop.set()
        await asyncio.wait_for(asyncio.gather(*tasks, return_exceptions=True), 30.0)

