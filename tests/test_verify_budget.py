"""Signature checks are bounded (swarmd/base/verify_budget.py, DESIGN "Who can still do
what"): cheap checks first (a played-back signed frame costs no signature check), then
a per-sender and a total budget of checks a second, so a flood of forged signed frames
cannot take a daemon's CPU; its figures on real daemons: bench/bench_verify_flood.py."""

from __future__ import annotations

from harness import signed_beat

from sim.shared.fakeid import fake_identities
from swarmd.base.identity import Keyring, generate_identity
from swarmd.base.verify_budget import VerifyBudget
from swarmd.core.node import Node
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

Paper = tuple[SwarmPlan, Params]


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_budget_per_sender_and_in_all() -> None:
    clock = _Clock()
    b = VerifyBudget(per_robot=10, per_robot_burst=10, total=15, total_burst=15, clock=clock)
    assert sum(b.take(1) for _ in range(100)) == 10  # one robot's name: its share
    assert sum(b.take(2) for _ in range(100)) == 5  # then the total runs out
    assert b.refused == 185
    clock.t = 1.0
    assert sum(b.take(3) for _ in range(100)) == 10  # refilled at its rate
    assert sum(b.take(1) for _ in range(100)) == 5


def test_a_keyring_with_a_budget_checks_no_more_than_it() -> None:
    priv, pub = generate_identity()
    clock = _Clock()
    ring = Keyring({1: pub}, budget=VerifyBudget(clock=clock))
    from swarmd.base.identity import Ed25519Signer

    data = b"frame"
    good = Ed25519Signer(1, priv).sign(data)
    verdicts = [ring.verify(1, data, good) for _ in range(1000)]
    assert sum(verdicts) == 80 and ring.budget is not None and ring.budget.refused == 920
    assert not ring.verify(9, data, good)  # unknown robot: no check, no budget spent
    clock.t = 10.0
    assert ring.verify(1, data, good)


class _Counting:
    """A verifier that counts its checks (and takes every signature)."""

    def __init__(self) -> None:
        self.calls = 0

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        self.calls += 1
        return True


def test_played_back_signed_frames_cost_no_signature_check(paper: Paper) -> None:
    """1,000 copies of one anchor of robot 2, and 1,000 anchors beyond the receiver's
    clock bound: one signature check in all (before, one each)."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    counting = _Counting()
    node = Node(1, plan, params, 0.0, seq_start=10**12,
                identity=ids[1].__class__(ids[1].signer, counting))
    node.tick(0.0)
    anchor = signed_beat(ids[2], plan.swarm_id, 2, 10**12 + 5, 2, 0)
    for i in range(1000):
        node.receive(anchor, 0.001 * i)
    ahead = [signed_beat(ids[2], plan.swarm_id, 2, 10**13 + i, 2, 0) for i in range(1000)]
    for i, frame in enumerate(ahead):
        node.receive(frame, 1.0 + 0.001 * i)
    assert counting.calls == 1
    assert node.drops["replay"] == 999 and node.drops["seq_jump"] == 1000


def test_past_the_budget_a_signed_frame_is_not_even_decoded(paper: Paper) -> None:
    """The daemon's receive filter: once robot 2's budget is spent, its signed frames
    are dropped before decoding; its chain-linked heartbeats (no signature) and other
    robots' frames pass."""
    plan, _params = paper
    ids = fake_identities(plan.robots)
    clock = _Clock()
    b = VerifyBudget(per_robot=1, per_robot_burst=1, total=100, total_burst=100, clock=clock)
    anchor2 = signed_beat(ids[2], plan.swarm_id, 2, 10**12, 2, 0)
    anchor3 = signed_beat(ids[3], plan.swarm_id, 3, 10**12, 3, 0)
    linked2 = signed_beat(None, plan.swarm_id, 2, 10**12 + 1, 2, 0)
    assert b.allows(anchor2) and b.take(2)
    assert not b.allows(anchor2) and b.allows(linked2) and b.allows(anchor3)
    clock.t = 1.0
    assert b.allows(anchor2)


def test_our_own_echoes_take_no_credit_and_a_forgery_in_our_name_still_spends() -> None:
    """A daemon hears every frame it sends back (multicast loopback) and its node drops
    those unchecked: were they credited, the credits would pile up to the burst and let
    one later flood forged in our name past the budget."""
    clock = _Clock()
    b = VerifyBudget(per_robot=10, per_robot_burst=10, total=100, total_burst=100,
                     clock=clock, own=7)
    anchor = bytes([0x08, 0, 0, 0, 7]) + bytes(80)  # signed bit, sender 7, signature-long
    assert all(b.allows(anchor) for _ in range(50))  # our echoes, dropped unchecked
    clock.t = 10.0  # long after: the bucket is full again
    assert sum(b.take(7) for _ in range(100)) == 10  # a forged flood: the burst, no more
    other = bytes([0x08, 0, 0, 0, 8]) + bytes(80)
    assert all(b.allows(other) for _ in range(20))  # anyone else's: credited as before
    assert sum(b.take(8) for _ in range(100)) == 10
