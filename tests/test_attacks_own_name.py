"""Frames in a robot's own name that it did not send (DESIGN section 2, "Sequence
numbers"): a robot's counters move only on what it sends itself, and a receiver that
took a forged frame far ahead keeps hearing the robot's own next frames. Virtual time,
every auth mode; the same attack on real daemons: tests/test_attacks_realtime.py.

`forge:R@T:ahead` (sim/shared/forge.py): two heartbeats as R that anyone with the swarm
key (anyone at all, unsigned; per robot, an outsider: no signature, a made-up chain
link) can make, one 91 minutes ahead of R's counter and one 30 minutes ahead.
"""

from __future__ import annotations

import pytest
from test_attacks import HOLDERS, NOW_SEQ, Paper, _beat, _mode_node, drops, named, run, takeovers

from sim.shared.fakeid import fake_identities
from swarmd.core import wire
from swarmd.core.actions import Broadcast
from swarmd.core.chain import LINK_LEN
from swarmd.core.node import Node
from swarmd.core.replay import WINDOW, ReplayFilter

MODES = ["none", "shared", "per-robot"]


def _seq(frame: bytes) -> int:
    """A frame's sequence number (header bytes 5-10), whatever signs it."""
    return int.from_bytes(frame[wire.HEADER_LEN - 6:wire.HEADER_LEN], "big")


@pytest.mark.parametrize("auth", MODES)
def test_a_heartbeat_in_a_robots_name_far_ahead_mutes_nobody(paper: Paper, auth: str) -> None:
    """Row 1 (per robot with the swarm key beside: row 1b, an insider holding it).
    Before: robot 2 moved its own counter to the forged 91 minutes, every robot dropped
    its frames as `seq_jump`, standby 6 took f2 over and was fenced."""
    plan, params = paper
    res = run(plan, params, auth, "forge:2@4:ahead")
    assert res.violations == []  # no healthy robot replaced, fenced or muted
    assert takeovers(res) == [] and named(res, "fenced") == []
    assert res.holders() == HOLDERS
    assert drops(res, "seq_jump") >= 4  # the 91-minute one, beyond every clock bound
    assert res.drops[2].get("own", 0) >= 1  # robot 2 heard them and counted them


@pytest.mark.parametrize("auth", MODES)
def test_a_frame_ahead_in_every_name_delays_no_takeover(paper: Paper, auth: str) -> None:
    """Row 1c: one such pair in every robot's name, then robot 2 dies. Before: f2 was
    never taken over (every robot's counter was ahead of every receiver's bound)."""
    plan, params = paper
    forged = [f"forge:{r}@4:ahead" for r in sorted(plan.robots)]
    res = run(plan, params, auth, *forged, "crash:2@5")
    assert res.violations == []
    assert takeovers(res) == [(6, "f2", 2)]
    assert res.holders() == {**HOLDERS, "f2": [6]}


@pytest.mark.parametrize("mode", MODES)
def test_a_robot_does_not_follow_a_frame_in_its_own_name(paper: Paper, mode: str) -> None:
    """Its counter moves only on what it sends: its next frame is one above its last."""
    plan, params = paper
    node = _mode_node(plan, params, mode, 2, 0.0)
    sent = [a for a in node.tick(0.0) if isinstance(a, Broadcast)]
    last = max(_seq(a.frame) for a in sent) if sent else NOW_SEQ
    key = bytes(32) if mode != "none" else None
    linked = mode == "per-robot"
    # Per robot: a link nobody can check, no signature (the signer only lays out the
    # link: a heartbeat that is no anchor is not signed).
    layout = fake_identities(plan.robots)[2].signer if linked else None
    forged = wire.encode(wire.Frame(plan.swarm_id, 2, NOW_SEQ + 10**8, wire.Heartbeat(
        2, 0, 1, 0, 5 if linked else 0, bytes(LINK_LEN) if linked else b"")), key, layout)
    node.receive(forged, 0.05)
    assert node.drops["own"] == 1 and node.snapshot().seq <= last + 1
    out = [a for a in node.tick(0.3) if isinstance(a, Broadcast)]
    assert out and max(_seq(a.frame) for a in out) < NOW_SEQ + 10**6


@pytest.mark.parametrize("mode", ["none", "shared"])
@pytest.mark.parametrize("ahead", [1000, 10**8])
def test_a_receiver_that_took_a_forged_frame_still_hears_the_robot(
        paper: Paper, mode: str, ahead: int) -> None:
    """Where anyone (unsigned) or any key holder (shared) can say anything, a receiver
    takes a frame in robot 2's name ahead of it; robot 2's own next frames, all below
    it, are still heard (before: dropped as replays until robot 2 heard its name)."""
    plan, params = paper
    node = _mode_node(plan, params, mode, 1, 0.0)
    for i in range(5):
        node.receive(_beat(plan, mode, 2, NOW_SEQ + i), 0.1 * i)
    node.receive(_beat(plan, mode, 2, NOW_SEQ + ahead), 0.55)
    for i in range(5, 200):
        node.receive(_beat(plan, mode, 2, NOW_SEQ + i), 0.1 * i)
    assert node.drops["replay"] == 0
    assert node.snapshot().heard[2] == pytest.approx(19.9)
    # What it persists for a restart is robot 2's own run, not the forged seq.
    assert node.snapshot().peer_seq[2] == NOW_SEQ + 199


def test_replays_stay_replays_around_a_forged_frame() -> None:
    """The set keeps every seq accepted lately: the robot's frames and the forged one
    played back again are dropped; one older than the last WINDOW accepted is too."""
    f = ReplayFilter()
    for s in range(100, 110):
        assert f.accept(2, s)
    assert f.accept(2, 10**9)
    assert not f.accept(2, 10**9) and not f.accept(2, 105)
    for s in range(110, 110 + 2 * WINDOW):
        assert f.accept(2, s)
    assert not f.accept(2, 150) and not f.accept(2, 10**9)
    assert f.top(2) == 110 + 2 * WINDOW - 1 and f.tops() == {2: 110 + 2 * WINDOW - 1}


def test_a_flood_ahead_leaves_the_robot_a_hole_to_be_heard_in() -> None:
    """More than WINDOW frames in robot 2's name far ahead, between two of its own,
    push the floor over its next frames: the stretch jumped over (never accepted) is
    kept as a hole, where its next frames are heard and replays still dropped; three
    such floods, one after another, likewise."""
    f = ReplayFilter()
    assert all(f.accept(2, s) for s in range(100, 120))
    own = 120
    for flood in range(3):
        base = 10**6 * (flood + 1)
        assert all(f.accept(2, base + i) for i in range(3 * WINDOW))
        assert f.accept(2, own) and not f.accept(2, own)
        assert not f.accept(2, base) and not f.accept(2, base + 3 * WINDOW - 1)
        own += 1
    for _ in range(2 * WINDOW):  # the robot's own run goes on in its hole
        assert f.accept(2, own)
        own += 1
    assert not f.accept(2, 110) and not f.accept(2, own - 1)
    assert f.top(2) == own - 1  # what a restart persists: the stretch heard last


def test_a_robot_keeps_its_node_counter_across_own_frames_unsigned(paper: Paper) -> None:
    """The old rule's probe: a frame as robot 2 a little ahead moves its counter no more."""
    plan, params = paper
    node = Node(2, plan, params, 0.0, seq_start=5000)
    node.tick(0.0)
    node.receive(wire.encode(wire.Frame(plan.swarm_id, 2, 9000, wire.Heartbeat(2, 0, 1, 0))),
                 0.05)
    assert node.snapshot().seq < 9000 and node.drops["own"] == 1
