"""Frames held within a robot's start-up grace (`swarmd/core/held.py`; DESIGN section 2,
"Every proof is bound to its run"): a frame that would raise a view entry, numbered above
its sender's word here (or from a sender with no word yet), waits for a later word or for
the grace's end. The store is bounded per sender and in total, and counts what it pushes
out (`held_over`); a sender never heard within the grace has its frames taken as they
would have been. A holder does not execute its slot while a frame that would fence it
is held."""

from __future__ import annotations

import pytest

from swarmd.core import wire
from swarmd.core.actions import Assign, Release
from swarmd.core.held import HeldFrame, HeldFrames
from swarmd.core.node import Node
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Role

Paper = tuple[SwarmPlan, Params]
KEY = b"k" * 32


def held(sender: int, seq: int, slot: int = 2, epoch: int | None = None) -> HeldFrame:
    """`sender`'s heartbeat holding `slot`, a distinct frame per seq unless `epoch`."""
    hb = wire.Heartbeat(slot, seq if epoch is None else epoch, 1, 0)
    return HeldFrame(sender, seq, slot, wire.Frame(1, sender, seq, hb), b"")


def test_a_sender_keeps_its_highest_numbered_frames() -> None:
    """A flood of one sender's frames pushes out its lowest-numbered ones, counted: a
    recording is numbered below its sender's live frames, so it pushes out itself."""
    store = HeldFrames(per_sender=4, total=64)
    pushed = sum(store.hold(held(6, seq)) for seq in [50, 10, 40, 30, 20, 60])
    assert pushed == 2 and len(store) == 4
    assert [h.seq for h in store.waiting()] == [50, 40, 30, 60]


def test_the_same_frame_again_takes_the_place_of_the_one_held() -> None:
    """A new holder heartbeats the same entry ten times a second: one frame held, its
    latest copy, and nothing counted as pushed out."""
    store = HeldFrames(per_sender=4, total=64)
    pushed = sum(store.hold(held(6, seq, epoch=1)) for seq in [10, 12, 11, 13])
    assert pushed == 0 and [h.seq for h in store.waiting()] == [13]


def test_the_total_is_bounded_whatever_the_senders() -> None:
    """Past the total, the sender holding the most gives up its lowest-numbered frame."""
    store = HeldFrames(per_sender=4, total=6)
    pushed = sum(store.hold(held(s, seq)) for s in (5, 6) for seq in (3, 2, 1))
    pushed += store.hold(held(4, 9))
    assert pushed == 1 and len(store) == 6
    assert sorted((h.sender, h.seq) for h in store.waiting()) == [
        (4, 9), (5, 2), (5, 3), (6, 1), (6, 2), (6, 3)]


def test_a_word_releases_only_what_is_numbered_below_it() -> None:
    store = HeldFrames()
    for h in (held(6, 10, slot=3), held(6, 30), held(5, 5)):
        store.hold(h)
    judged = store.waiting(6, below=20)
    assert [h.seq for h in judged] == [10]
    store.forget(judged)
    assert store.about(2) and not store.about(3) and len(store) == 2


# ------------------------------------------------------------------ a node
def node(paper: Paper, rid: int, auth: str) -> Node:
    plan, params = paper
    n = Node(rid, plan, params, 0.0, keys=(KEY,) if auth == "shared" else ())
    n.tick(0.0)
    return n


def beat(paper: Paper, auth: str, sender: int, seq: int, f: str | None, epoch: int) -> bytes:
    """`sender`'s heartbeat: holding f at `epoch`, or as a standby (f None)."""
    plan = paper[0]
    hb = wire.Heartbeat(plan.slot(f), epoch, int(Role.ACTIVE), 0) if f is not None \
        else wire.Heartbeat(0, 0, int(Role.STANDBY), 0)
    return wire.encode(wire.Frame(plan.swarm_id, sender, seq, hb),
                       KEY if auth == "shared" else None)


@pytest.mark.parametrize("word_first", [False, True])
@pytest.mark.parametrize("auth", ["shared", "none"])
def test_a_flood_of_recorded_holds_is_bounded_and_outdated_by_the_live_word(
        paper: Paper, auth: str, word_first: bool) -> None:
    """100 recorded heartbeats of 6 holding f2 (each at another epoch, so that none
    takes another's place), at holder 2's start: 8 held (`PER_SENDER`), 92 pushed out and
    counted; 6's live standby heartbeat, numbered above them, makes the 8 `outdated`. 2
    keeps f2 at epoch 0 throughout: it stops executing f2 while they are held (the
    first would fence it) and executes it again once they are judged. Alike when a
    recorded standby heartbeat of 6, numbered below the flood, was played first
    (`word_first`): it is 6's word, but the flood is numbered above it."""
    two = node(paper, 2, auth)
    if word_first:
        assert two.receive(beat(paper, auth, 6, 999, None, 0), 0.005) == []
    outs = [two.receive(beat(paper, auth, 6, 1000 + i, "f2", 1 + i), 0.01 + i / 1000)
            for i in range(100)]
    assert outs[0] == [Release("f2")] and not any(outs[1:])
    assert two.drops["held_over"] == 92 and two.snapshot().known["f2"] == (2, 0)
    out = two.receive(beat(paper, auth, 6, 10**6, None, 0), 0.2)
    assert two.drops["outdated"] == 8 and two.snapshot().known["f2"] == (2, 0)
    assert two.snapshot().role == Role.ACTIVE and Assign("f2", 0) in out


@pytest.mark.parametrize("auth", ["shared", "none"])
def test_a_sender_never_heard_within_the_grace_is_taken_at_its_end(
        paper: Paper, auth: str) -> None:
    """6's heartbeat holding f2 at epoch 1, and nothing else of 6, within 2's start-up
    grace: held, and taken when the grace ends (a deadline of its own). 2 stops
    executing f2 while it is held (it would fence 2) but still holds and heartbeats its
    entry; once it is taken 2 is fenced (rule 2), with no second release."""
    params = paper[1]
    two = node(paper, 2, auth)
    assert two.receive(beat(paper, auth, 6, 1000, "f2", 1), 0.1) == [Release("f2")]
    assert two.snapshot().role == Role.ACTIVE and two.snapshot().known["f2"] == (2, 0)
    deadline = two.next_deadline()
    assert deadline is not None and deadline <= params.startup_grace
    t = 0.1
    while (d := two.next_deadline()) is not None and d < params.startup_grace:
        two.tick(d)
        t = d
    assert two.snapshot().role == Role.ACTIVE and t < params.startup_grace
    out = two.tick(params.startup_grace)
    assert two.snapshot().known["f2"] == (6, 1) and two.snapshot().role == Role.FENCED
    assert not any(isinstance(a, Assign | Release) for a in out)


def test_per_robot_nothing_is_held(paper: Paper) -> None:
    """Per robot a heartbeat moves no entry without its certificate: refused at once
    (`uncertified`), never held."""
    from harness import signed_beat

    from sim.shared.fakeid import fake_identities
    plan, params = paper
    ids = fake_identities(plan.robots)
    two = Node(2, plan, params, 0.0, identity=ids[2])
    two.tick(0.0)
    two.receive(signed_beat(ids[6], plan.swarm_id, 6, 1000, plan.slot("f2"), 1), 0.1)
    assert two.drops["uncertified"] == 1 and two.drops["held_over"] == 0
