"""A robot's heartbeats only from that robot (DESIGN section 2, "Who may say what",
"Heartbeats"): hash-chain links with signed anchors, per-robot mode, on virtual time.

What each mode answers to the same forger: per robot, a dead robot's heartbeats cannot
be made from what was heard, so its takeover comes on time; with a shared key (an
insider holding it) or unsigned (anyone), forged heartbeats keep a dead robot alive for
as long as they are sent, as DESIGN states. A revoked robot falls silent and its slot is
taken over like a dead robot's.
"""

from __future__ import annotations

import pytest
from harness import Net, signed_beat

from sim.shared.fakeid import FakeVerifier, fake_identities
from swarmd.core import wire
from swarmd.core.actions import Broadcast
from swarmd.core.auth import Identity
from swarmd.core.chain import (
    ANCHOR_RUN,
    CHAIN_LEN,
    HEADS,
    SLACK,
    WALK,
    OwnChain,
    PeerChains,
    anchor_every,
)
from swarmd.core.node import Node
from swarmd.core.params import Params, radio, udp
from swarmd.core.plan import SwarmPlan

Paper = tuple[SwarmPlan, Params]
KEY = b"k" * 32
MODES = ("per-robot", "per-robot+key", "shared", "none")
"""per-robot as shipped (configs/*.yaml: robot keys only), per-robot with a swarm key
beside the robot keys, the swarm key alone, nothing."""


def make_net(paper: Paper, mode: str, **kw: object) -> Net:
    plan, params = paper
    ids: dict[int, Identity] = fake_identities(plan.robots) if mode.startswith("per-robot") \
        else {}
    keys = (KEY,) if mode in ("per-robot+key", "shared") else ()
    return Net(plan, params, keys=keys, identities=ids, **kw)  # type: ignore[arg-type]


def beats(n: Net, robot: int) -> list[tuple[float, wire.Frame]]:
    """Robot `robot`'s heartbeats on the channel, decoded as a receiver would."""
    verifier = next(iter(n.identities.values())).verifier if n.identities else None
    out = []
    for t, sender, data in n.frames:
        if sender == robot:
            frame = wire.decode(data, n.keys, verifier)
            if isinstance(frame.msg, wire.Heartbeat):
                out.append((t, frame))
    return out


# ---------------------------------------------------------------- the chain itself
def _links(count: int) -> list[tuple[int, bytes, bool]]:
    ident = fake_identities([2])[2]
    chain = OwnChain(2, ident.signer, run=77)
    return [chain.next(0.01 * i, (2, 0, 1), 1e9) for i in range(count)]


def test_links_are_accepted_forward_only_and_within_the_walk() -> None:
    links = _links(400)
    assert [a for _, _, a in links[:ANCHOR_RUN + 1]] == [True] * ANCHOR_RUN + [False]
    peers = PeerChains(10.0)  # 10 Hz
    n0, l0, _ = links[0]
    assert not peers.check(2, n0, l0, 0.0, anchor=False)  # nothing to tie it to yet
    assert peers.check(2, n0, l0, 0.0, anchor=True)
    peers.commit(2, n0, l0, 0.0, anchor=True)
    n1, l1, _ = links[1]
    assert peers.check(2, n1, l1, 0.1, anchor=False)
    assert not peers.check(2, n0, l0, 0.1, anchor=False)  # revealed already: anyone has it
    assert not peers.check(2, n1, bytes(8), 0.1, anchor=False)  # made up
    assert not peers.check(3, n1, l1, 0.1, anchor=False)  # another robot's chain
    # No further ahead than the time since allows (a period's worth, twice, plus slack) ...
    n40, l40, _ = links[40]
    assert not peers.check(2, n40, l40, 0.5, anchor=False)
    assert peers.check(2, n40, l40, 2.0, anchor=False)
    # ... and never more than WALK: beyond, only the next anchor helps.
    nw, lw, _ = links[WALK]
    assert peers.check(2, nw, lw, 100.0, anchor=False)
    nf, lf, _ = links[WALK + 1]
    assert not peers.check(2, nf, lf, 100.0, anchor=False)
    peers.commit(2, nw, lw, 100.0, anchor=False)
    assert peers.check(2, nf, lf, 100.1, anchor=False)
    peers.forget([2])
    assert not peers.check(2, nf, lf, 100.1, anchor=False)


def _chain_of(robot: int, run: int, count: int) -> list[tuple[int, bytes, bool]]:
    """`count` heartbeats of `robot`'s chain for run `run` (another run: another chain)."""
    chain = OwnChain(robot, fake_identities([robot])[robot].signer, run=run)
    return [chain.next(0.1 * i, (2, 0, 1), 1e9) for i in range(count)]


def test_an_anchor_of_another_chain_leaves_the_robots_own_chain_followed() -> None:
    """One anchor in a robot's name that continues none of its chains (another radio
    with its key) is followed beside the robot's own chain, never instead of it: the
    robot's next links still count as its liveness."""
    own, other = _chain_of(2, 77, 40), _chain_of(2, 78, 40)
    peers = PeerChains(10.0)
    n, link, _ = own[0]
    peers.commit(2, n, link, 0.0, anchor=True)
    for i in range(1, 10):
        n, link, _ = own[i]
        assert peers.check(2, n, link, 0.1 * i, anchor=False)
        peers.commit(2, n, link, 0.1 * i, anchor=False)
    fn, fl, _ = other[0]
    peers.commit(2, fn, fl, 1.0, anchor=True)  # the other radio's anchor
    for i in range(10, 20):
        n, link, _ = own[i]
        assert peers.check(2, n, link, 0.1 * i, anchor=False), i
        peers.commit(2, n, link, 0.1 * i, anchor=False)
    # The other chain is followed too (its anchor was signed with the robot's key) ...
    assert peers.check(2, other[1][0], other[1][1], 2.0, anchor=False)
    # ... and a link already revealed is refused on either chain.
    assert not peers.check(2, *own[19][:2], 2.0, anchor=False)
    assert not peers.check(2, fn, fl, 2.0, anchor=False)


def test_a_late_anchor_behind_its_chain_moves_nothing_and_heads_are_bounded() -> None:
    own = _chain_of(2, 77, 40)
    peers = PeerChains(10.0)
    for i in range(12):
        n, link, anchor = own[i]
        assert anchor or peers.check(2, n, link, 0.1 * i, anchor=False)
        peers.commit(2, n, link, 0.1 * i, anchor=anchor or i == 5)
    # Anchors of the same chain that come late (a reordering channel, a frame held in
    # the start-up grace): the head stays where it is, so the links it already passed
    # are still refused.
    for late in (own[11 - SLACK], own[1]):
        peers.commit(2, late[0], late[1], 1.2, anchor=True)
    assert not any(peers.check(2, *own[i][:2], 1.2, anchor=False) for i in range(2, 12))
    assert peers.check(2, *own[12][:2], 1.2, anchor=False)
    # Anchors of more chains than HEADS: the oldest head makes room, the newest stay.
    others = [_chain_of(2, 100 + k, 2) for k in range(HEADS)]
    for k, chain in enumerate(others):
        peers.commit(2, chain[0][0], chain[0][1], 1.3 + 0.01 * k, anchor=True)
    assert not peers.check(2, *own[12][:2], 1.4, anchor=False)
    assert all(peers.check(2, *chain[1][:2], 1.4, anchor=False) for chain in others)


def test_chains_follow_each_other_and_each_starts_with_anchors() -> None:
    links = _links(CHAIN_LEN + ANCHOR_RUN + 2)
    anchors = [i for i, (_, _, a) in enumerate(links) if a]
    assert anchors == [*range(ANCHOR_RUN), *range(CHAIN_LEN, CHAIN_LEN + ANCHOR_RUN)]
    assert len({link for _, link, _ in links}) == len(links)


def test_anchors_come_often_enough_for_a_receiver_that_starts() -> None:
    for p in (udp(), radio()):
        every = anchor_every(p)
        assert every <= p.startup_grace / 2 and every <= p.standby_timeout / 2


# ---------------------------------------------------------------- on the channel
@pytest.mark.parametrize("mode", ["per-robot", "per-robot+key"])
def test_heartbeats_carry_links_and_anchors_at_their_stated_pace(paper: Paper,
                                                                  mode: str) -> None:
    params = paper[1]
    n = make_net(paper, mode)
    n.run_until(20.0)
    got = beats(n, 1)  # an active robot: 10 Hz
    anchors = [t for t, f in got if isinstance(f.msg, wire.Heartbeat) and f.msg.anchor]
    assert len(anchors) >= ANCHOR_RUN
    gaps = [b - a for a, b in zip(anchors[ANCHOR_RUN - 1:-1], anchors[ANCHOR_RUN:],
                                  strict=True)]
    assert gaps and max(gaps) <= anchor_every(params) + params.heartbeat_interval + 1e-9
    assert len(anchors) < len(got) / 5  # most heartbeats are links: the airtime stays low
    size = 24 if mode == "per-robot" else 32
    sizes = {len(data) for _, s, data in n.frames if s == 1 and data[0] & 0x07 == 1}
    assert sizes == {size, 88}
    assert all(n.nodes[r].drops.get("unanchored", 0) == 0 for r in n.alive)
    assert n.named("suspect") == []


@pytest.mark.parametrize("mode", MODES)
def test_forged_heartbeats_of_a_dead_robot(paper: Paper, mode: str) -> None:
    """Robot 2 (f2) dies at 3 s; from then on a forger sends a heartbeat in its name every
    heartbeat period, the best it can make: its last frame again, at a fresh seq (per
    robot: the last link it heard, unsigned; with the swarm key: tagged)."""
    plan, params = paper
    n = make_net(paper, mode)
    n.run_until(3.0)
    n.crash(2)
    last = beats(n, 2)[-1][1]
    assert isinstance(last.msg, wire.Heartbeat)
    key = KEY if mode in ("per-robot+key", "shared") else None
    seq = last.seq
    t = 3.0
    while t < 8.0:
        t += params.heartbeat_interval
        seq += 1
        msg = last.msg
        if mode.startswith("per-robot"):
            data = signed_beat(None, plan.swarm_id, 2, seq, msg.function, msg.epoch,
                               key=key, link=msg.link, n=msg.n)
        else:
            data = wire.encode(wire.Frame(plan.swarm_id, 2, seq, msg), key)
        n.run_until(t)
        for r in sorted(n.alive):
            n.inject(r, n.nodes[r].receive(data, n.now))
    holders = {r: n.nodes[r].snapshot().known["f2"] for r in n.alive
               if plan.slot("f2") in plan.relevant(r).slots}
    if mode.startswith("per-robot"):
        # Taken over as a silent robot's slot, in the usual time.
        take = n.named("takeover")
        assert [(e["robot"], e["function"]) for e in take] == [(6, "f2")]
        assert take[0]["t"] - 3.0 <= params.takeover_bound() + params.heartbeat_interval
        assert set(holders.values()) == {(6, 1)}
        assert sum(n.nodes[r].drops.get("unanchored", 0) for r in n.alive) >= 40
    else:
        # What DESIGN says the swarm key's holder (anyone, unsigned) can do: delay.
        assert n.named("takeover") == []
        assert set(holders.values()) == {(2, 0)}


def _revoking(n: Net, robot: int) -> None:
    """Every robot but `robot` learns it is revoked (SIGHUP on each daemon)."""
    verifier = next(iter(n.identities.values())).verifier
    assert isinstance(verifier, FakeVerifier)
    verifier.revoke([robot])
    for r in sorted(n.alive):
        if r != robot:
            n.nodes[r].revoke([robot])


def test_a_revoked_robot_is_taken_over_like_a_silent_one(paper: Paper) -> None:
    """A stolen robot 2 keeps running, healthy, after its key is revoked at 4 s: its
    heartbeats (and refutations) count for nothing from then on, and standby 6 takes f2
    over within T_max and the usual takeover. Robot 2 itself was not told (it is in
    other hands): what it does no longer matters to the swarm."""
    plan, params = paper
    n = make_net(paper, "per-robot")
    n.run_until(4.0)
    _revoking(n, 2)
    n.run_until(4.0 + params.takeover_bound(lossy=True) + 1.0)
    take = n.named("takeover")
    assert [(e["robot"], e["function"]) for e in take] == [(6, "f2")]
    assert take[0]["t"] - 4.0 <= params.t_max + params.takeover_bound()
    assert {n.nodes[r].snapshot().known["f2"] for r in n.alive
            if r != 2 and plan.slot("f2") in plan.relevant(r).slots} == {(6, 1)}
    assert n.executing()[6] == "f2"
    assert sum(n.nodes[r].drops.get("auth", 0) for r in n.alive if r != 2) > 0


def test_without_revocation_the_same_robot_keeps_its_slot(paper: Paper) -> None:
    """The control: nothing revoked, nothing taken over."""
    n = make_net(paper, "per-robot")
    n.run_until(4.0 + paper[1].takeover_bound(lossy=True) + 1.0)
    assert n.named("takeover") == [] and n.executing()[2] == "f2"


@pytest.mark.parametrize("mode", ["per-robot", "per-robot+key"])
def test_a_restarted_watcher_is_anchored_before_it_suspects_anyone(paper: Paper,
                                                                    mode: str) -> None:
    """Robot 3 restarts at 5 s with no chain of anyone: it drops links until each robot's
    next anchor, well within its start-up grace, and warns about nobody."""
    n = make_net(paper, mode, loss=0.1, seed=3)
    n.run_until(5.0)
    n.crash(3)
    n.run_until(5.15)  # back before anyone's T_max runs out
    n.boot(3, seq_start=n.nodes[3].snapshot().seq + 100)
    n.run_until(30.0)
    assert n.named("suspect") == [] and n.named("warn") == []
    assert n.nodes[3].drops.get("unanchored", 0) > 0  # it did start unanchored


def test_chain_rotation_under_loss_costs_no_liveness(paper: Paper) -> None:
    """More than one chain's worth of heartbeats (a robot starts a new chain after
    CHAIN_LEN), at 20% loss: after the start no heartbeat is ever refused for want of
    an anchor, so every suspicion there is is the loss's own, as unsigned."""
    params = paper[1]
    signed = make_net(paper, "per-robot", loss=0.2, seed=5)

    def unanchored() -> int:
        return sum(signed.nodes[r].drops.get("unanchored", 0) for r in signed.alive)

    # At the start a receiver that lost a robot's first anchors waits for the next
    # one (within the start-up grace); after that, nobody ever does.
    signed.run_until(params.startup_grace)
    early = unanchored()
    signed.run_until(CHAIN_LEN * params.heartbeat_interval * 1.3)
    sent = [f.msg for _, f in beats(signed, 1) if isinstance(f.msg, wire.Heartbeat)]
    assert len(sent) > CHAIN_LEN + 100  # robot 1 is on its second chain
    assert unanchored() == early
    frames_in = sum(signed.nodes[r].snapshot().frames_in for r in signed.alive)
    assert frames_in > 5_000


def test_an_extra_heartbeat_is_an_anchor(paper: Paper) -> None:
    """A refutation may go to a watcher that lost the chain: it is signed."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    node = Node(2, plan, params, 0.0, identity=ids[2])
    node.tick(0.0)
    for t in (0.1, 0.2, 0.3, 0.4):
        node.tick(t)
    warn = wire.encode(wire.Frame(plan.swarm_id, 3, 500, wire.Warn(2, 2, 0)), None,
                       ids[3].signer)
    out = [a.frame for a in node.receive(warn, 0.45) if isinstance(a, Broadcast)]
    msgs = [wire.decode(d, (), ids[1].verifier).msg for d in out]
    hb = [m for m in msgs if isinstance(m, wire.Heartbeat)]
    assert len(hb) == 1 and hb[0].anchor


def test_a_peer_back_from_a_long_silence_gets_anchors(paper: Paper) -> None:
    """Robot 2 hears robot 3 for a while, then nothing for longer than robot 3 could
    walk its chain, then a heartbeat it cannot check (3 lost 2's chain too, as on both
    sides of a partition): 2's next heartbeats are anchors, not the next scheduled
    anchor's second later; a flood of such frames does not make it sign at will."""
    plan = paper[0]
    # Scheduled anchors a minute apart, so that any anchor seen here is the answer.
    params = paper[1].with_overrides(startup_grace=120.0, standby_timeout=120.0)
    ids = fake_identities(plan.robots)
    two = Node(2, plan, params, 0.0, identity=ids[2])
    three = Node(3, plan, params, 0.0, identity=ids[3])

    def beats_of(node: Node, t: float) -> list[wire.Heartbeat]:
        out = [wire.decode(a.frame, (), ids[1].verifier).msg
               for a in node.tick(t) if isinstance(a, Broadcast)]
        return [m for m in out if isinstance(m, wire.Heartbeat)]

    t = 0.0
    while t < 3.0:
        for a in three.tick(t):
            if isinstance(a, Broadcast):
                two.receive(a.frame, t)
        beats_of(two, t)
        t = round(t + params.heartbeat_interval, 6)
    silence = WALK * params.heartbeat_interval + 2.0  # 3 lost what 2 knew of its chain
    while t < 3.0 + silence:  # both sides go on, unheard by each other
        three.tick(t)
        beats_of(two, t)
        t = round(t + params.heartbeat_interval, 6)
    assert [m.anchor for m in beats_of(two, t)] == [False]  # the second in between
    t = round(t + params.heartbeat_interval, 6)
    frames = [a.frame for a in three.tick(t) if isinstance(a, Broadcast)
              and isinstance(wire.decode(a.frame, (), ids[1].verifier).msg, wire.Heartbeat)]
    two.receive(frames[0], t)
    assert two.drops["unanchored"] == 1
    t = round(t + params.heartbeat_interval, 6)
    assert [m.anchor for m in beats_of(two, t)] == [True]
    for _ in range(ANCHOR_RUN):  # the run, then links again however often 3 is heard
        for a in three.tick(t):
            if isinstance(a, Broadcast):
                two.receive(a.frame, t)
        t = round(t + params.heartbeat_interval, 6)
        beats_of(two, t)
    got = []
    for _ in range(5):
        t = round(t + params.heartbeat_interval, 6)
        got += [m.anchor for m in beats_of(two, t)]
    assert got == [False] * 5


class _Ring:
    """A keyring that accepts each robot's listed secrets (old and new during a
    rotation), as `swarmd.base.identity.Keyring` does with several public keys."""

    def __init__(self, secrets: dict[int, list[bytes]]) -> None:
        self.secrets = secrets

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        return any(FakeVerifier({robot: s}).verify(robot, data, signature)
                   for s in self.secrets.get(robot, []))


def test_rotating_a_robots_key_keeps_the_swarm_running(paper: Paper) -> None:
    """docs/operations.md: the new public key goes to every robot (both accepted), then
    the robot signs with its new key, then the old one is dropped. Robot 2's chain goes
    on across it (links need no key) and its anchors verify all along: nobody is
    suspected, and robot 2's crash afterwards is taken over as usual."""
    import hashlib

    from sim.shared.fakeid import FakeSigner

    plan, params = paper
    secrets = {r: [hashlib.sha256(b"old-%d" % r).digest()] for r in plan.robots}
    ring = _Ring(secrets)
    signers = {r: FakeSigner(r, secrets[r][0]) for r in plan.robots}
    n = Net(plan, params, identities={r: Identity(signers[r], ring) for r in plan.robots})
    n.run_until(4.0)
    new = hashlib.sha256(b"new-2").digest()
    secrets[2].append(new)  # installed everywhere, SIGHUP
    n.run_until(6.0)
    signers[2]._secret = new  # robot 2 signs with its new key, SIGHUP
    n.run_until(8.0)
    secrets[2].pop(0)  # the old key dropped everywhere
    n.run_until(12.0)
    assert n.named("suspect") == [] and n.named("takeover") == []
    n.crash(2)
    n.run_until(12.0 + params.takeover_bound(lossy=True) + 1.0)
    take = n.named("takeover")
    assert [(e["robot"], e["function"]) for e in take] == [(6, "f2")]
