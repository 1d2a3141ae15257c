"""One insider attacks the swarm, on virtual time (DESIGN section 2, "Who may say what").

Each attack is a `forge:R@T:ATTACK` fault (sim.shared.forge) or frames built here,
sent with the insider's own key in per-robot mode and with the swarm key in shared-key
mode. In every mode a heartbeat or a claim proves nothing without its certificate: no
live holder fenced and no dead robot kept unreplaced by one. Per-robot mode besides: no
healthy robot replaced, no robot muted, a dead robot taken over within the normal bound
plus one T_max, every attack counted as drops. Shared-key and unsigned modes: what
DESIGN says still gets through does (frames in other robots' names).

Paper swarm: robots 1-4 hold f1-f4 in a ring (f2 watched by the holders of f1 and f3),
standby 5 covers f1/f4, standby 6 covers f2/f3.
"""

from __future__ import annotations

from typing import Any

import pytest
from harness import signed_beat

from sim.shared.fakeid import FakeVerifier, fake_identities
from sim.shared.faults import parse_fault
from sim.virtual.simulator import VirtualResult, run_virtual
from swarmd.core import wire
from swarmd.core.actions import Broadcast
from swarmd.core.auth import SIGNATURE_LEN, Identity
from swarmd.core.node import Node, Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

Paper = tuple[SwarmPlan, Params]


def run(plan: SwarmPlan, params: Params, auth: str, *faults: str,
        duration: float = 10.0) -> VirtualResult:
    return run_virtual(plan, params, duration=duration, auth=auth,
                       faults=[parse_fault(f) for f in faults])


def drops(res: VirtualResult, reason: str) -> int:
    return sum(d.get(reason, 0) for d in res.drops.values())


def takeovers(res: VirtualResult) -> list[tuple[int, str, int]]:
    return [(e["robot"], e["function"], e["replaced"]) for e in res.events
            if e["event"] == "takeover"]


def named(res: VirtualResult, name: str) -> list[dict[str, Any]]:
    return [e for e in res.events if e["event"] == name]


HOLDERS = {"f1": [1], "f2": [2], "f3": [3], "f4": [4]}


# ---------------------------------------------------------------- a forged max epoch
@pytest.mark.parametrize("auth", ["none", "shared", "per-robot"])
def test_a_forged_max_epoch_heartbeat_fences_nobody(paper: Paper, auth: str) -> None:
    """A heartbeat at a new epoch moves no view without the certificate of a takeover,
    whoever may make it (DESIGN, "Convergence")."""
    plan, params = paper
    res = run(plan, params, auth, "forge:1@4:epoch")
    assert res.violations == []
    assert named(res, "fenced") == [] and takeovers(res) == []
    assert res.holders() == HOLDERS
    assert drops(res, "uncertified") >= 5  # every robot that hears f2 counted it
    # Nor is robot 1 muted: per robot the forged anchors, signed with its key, start a
    # chain beside its own at the receivers (`PeerChains`), whose links are still
    # heard, so nobody suspects it and no standby races its refutation.
    assert drops(res, "unanchored") == 0
    assert [e for e in res.events if e["event"] in ("suspect", "claim")] == []


# ---------------------------------------------------------------- a max seq
@pytest.mark.parametrize("auth", ["none", "shared", "per-robot"])
def test_a_max_seq_mutes_nobody(paper: Paper, auth: str) -> None:
    plan, params = paper
    res = run(plan, params, auth, "forge:2@4:seq")
    assert res.violations == []  # `muted` included
    assert takeovers(res) == [] and res.holders() == HOLDERS
    assert drops(res, "seq_jump") >= 4


# ---------------------------------------------------------------- CLAIM spam
def _normal_takeover(plan: SwarmPlan, params: Params, auth: str) -> float:
    res = run(plan, params, auth, "crash:2@3")
    (t,) = [e["t"] for e in named(res, "takeover")]
    return float(t)


@pytest.mark.parametrize("auth", ["none", "shared", "per-robot"])
@pytest.mark.parametrize("insider", [1, 3, 5, 6])
def test_claim_spam_does_not_delay_a_takeover(paper: Paper, insider: int, auth: str) -> None:
    """A claim without its certificate silences nobody (rule 10 bounds one claim; a
    stream of them at new epochs would silence the slot's watchers for ever)."""
    plan, params = paper
    normal = _normal_takeover(plan, params, auth)
    res = run(plan, params, auth, "crash:2@3", f"forge:{insider}@3.2:claim")
    assert res.violations == []
    got = [(e["robot"], e["function"], e["t"]) for e in named(res, "takeover")]
    assert [(r, f) for r, f, _ in got] == [(6, "f2")]
    assert got[0][2] <= normal + params.t_max
    assert drops(res, "uncertified") > 0


# ---------------------------------------------------------------- WARNs in others' names
@pytest.mark.parametrize("insider", [1, 3, 5])
def test_per_robot_warnings_in_other_names_count_for_nothing(paper: Paper, insider: int) -> None:
    plan, params = paper
    res = run(plan, params, "per-robot", f"forge:{insider}@3:warn")
    assert res.violations == [] and takeovers(res) == []
    assert named(res, "vote") == []  # not one forged witness counted
    assert drops(res, "auth") > 0


def test_shared_warnings_in_other_names_reach_the_quorum(paper: Paper) -> None:
    """Documented: with the swarm key, invented witnesses reach the quorum; what stops
    the takeover is the standby's own ears (rule 4), the suspect heard alive."""
    plan, params = paper
    res = run(plan, params, "shared", "forge:1@3:warn")
    assert max(e["count"] for e in named(res, "vote")) >= params.quorum
    assert takeovers(res) == [] and res.violations == []


# ---------------------------------------------------------------- replays across a restart
def _signed(identity: Identity, plan: SwarmPlan, sender: int, seq: int,
            msg: wire.Message) -> bytes:
    return wire.encode(wire.Frame(plan.swarm_id, sender, seq, msg), None, identity.signer)


def cert(plan: SwarmPlan, seq: int, slot: int, raw: bytes) -> bytes:
    """A CERT frame from robot 6 relaying `raw` (only its bytes go on the wire)."""
    blank = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
    return wire.encode(wire.Frame(plan.swarm_id, 6, seq, wire.Cert(slot, blank, raw)))


def test_a_restarted_standby_drops_replayed_heartbeats_of_a_dead_robot(paper: Paper) -> None:
    plan, params = paper
    ids = fake_identities(plan.robots)
    standby = Node(6, plan, params, 0.0, identity=ids[6])
    standby.tick(0.0)
    # What robot 2's radio sent for a second: anchors and links of its chain.
    two = Node(2, plan, params, 0.0, identity=ids[2], seq_start=100)
    captured = [a.frame for i in range(10) for a in two.tick(0.1 * i)
                if isinstance(a, Broadcast)]
    for i, data in enumerate(captured):
        standby.receive(data, 0.1 * i)
    snap = standby.snapshot()
    assert snap.peer_seq[2] == two.snapshot().seq and 2 in snap.heard
    # Robot 2 dies; the standby restarts with what it persisted.
    again = Node(6, plan, params, 5.0, identity=ids[6],
                 restored=Restored(known=dict(snap.known), peer_seq=dict(snap.peer_seq)))
    again.tick(5.0)
    for i, data in enumerate(captured):
        again.receive(data, 5.0 + 0.01 * i)
    # The anchors are replays; the links lead nowhere it knows (no chain yet).
    assert again.drops["replay"] + again.drops["unanchored"] == len(captured)
    assert again.drops["replay"] >= 3
    assert 2 not in again.snapshot().heard  # the dead robot does not look alive
    # Without the persisted seqs, a replayed anchor would be taken (the hole closed).
    naive = Node(6, plan, params, 5.0, identity=ids[6])
    naive.tick(5.0)
    naive.receive(captured[0], 5.0)
    assert naive.drops["replay"] == 0 and 2 in naive.snapshot().heard


REPLAY = ("crash:6@1.5", "crash:2@2.5", "restart:6@3")
"""Standby 6 is down when robot 2 (f2) dies and comes back after it."""


@pytest.mark.parametrize("auth", ["shared", "per-robot"])
def test_replayed_frames_delay_a_takeover_by_one_t_max_at_most(paper: Paper, auth: str) -> None:
    """`forge:1@3:replay`: robot 1's radio recorded the channel for 3 s (robot 2's
    heartbeats among it) and plays it all back every warn interval to the restarted
    standby and everyone else."""
    plan, params = paper
    (normal,) = [e["t"] for e in named(run(plan, params, auth, *REPLAY), "takeover")]
    res = run(plan, params, auth, *REPLAY, "forge:1@3:replay")
    assert res.violations == []
    got = [(e["robot"], e["function"], e["t"]) for e in named(res, "takeover")]
    assert [(r, f) for r, f, _ in got] == [(6, "f2")]
    assert got[0][2] <= normal + params.t_max
    # Every robot that heard the playback dropped it, the restarted standby included.
    assert {r for r, d in res.drops.items() if d.get("replay", 0) > 0} == {1, 3, 4, 5, 6}


def test_a_robots_drops_are_summed_over_its_restarts(paper: Paper) -> None:
    plan, params = paper
    # One burst at 1 s, heard by robot 6 only before its crash at 2 s.
    res = run(plan, params, "per-robot", "forge:3@1:seq", "crash:6@2", "restart:6@3",
              duration=5.0)
    alive = run(plan, params, "per-robot", "forge:3@1:seq", duration=5.0)
    assert res.drops[6]["seq_jump"] == alive.drops[6]["seq_jump"] > 0


def test_an_old_own_frame_replayed_after_a_restart_is_no_duplicate_robot(paper: Paper) -> None:
    plan, params = paper
    node = Node(1, plan, params, 0.0, seq_start=2_000_000)
    old = wire.encode(wire.Frame(plan.swarm_id, 1, 1_500_000, wire.Heartbeat(1, 0, 1, 0)))
    node.receive(old, 0.1)
    assert node.drops["replay"] == 1 and node.drops["own"] == 0


def test_per_robot_a_takeover_needs_a_certificate_of_signed_witnesses(paper: Paper) -> None:
    """Robot 6 (standby of f2) hears a CLAIM and the new holder's heartbeat: it moves
    f2's epoch only once a quorum of witnesses' own signed warnings backs the claim."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    seq = iter(range(10_000, 20_000))
    observer = Node(1, plan, params, 0.0, identity=ids[1])
    observer.tick(0.0)
    slot = plan.slot("f2")

    def claim_and_beat(t: float) -> None:
        """Robot 6's signed CLAIM of f2 at epoch 1, then its heartbeat as the holder."""
        observer.receive(_signed(ids[6], plan, 6, next(seq), wire.Claim(2, slot, 1)), t)
        observer.receive(signed_beat(ids[6], plan.swarm_id, 6, next(seq), slot, 1), t + 0.01)

    claim_and_beat(1.0)
    assert observer.snapshot().known["f2"] == (2, 0)
    assert observer.drops["uncertified"] == 2
    # One witness (robot 3, holder of f3, watches f2) is not a quorum ...
    w3 = _signed(ids[3], plan, 3, next(seq), wire.Warn(2, slot, 0))
    observer.receive(cert(plan, next(seq), slot, w3), 1.1)
    claim_and_beat(1.11)
    assert observer.snapshot().known["f2"] == (2, 0)
    # ... and a "warning" signed by robot 6 in robot 4's name is no witness at all.
    fake = _signed(ids[6], plan, 4, next(seq), wire.Warn(2, slot, 0))
    assert not FakeVerifier({}).verify(4, fake[:-SIGNATURE_LEN], fake[-SIGNATURE_LEN:])
    before = observer.drops["auth"]
    observer.receive(cert(plan, next(seq), slot, fake), 1.2)
    assert observer.drops["auth"] == before + 1
    # The claimant's own signed warning is rule 9's second witness: now certified.
    w6 = _signed(ids[6], plan, 6, next(seq), wire.Warn(2, slot, 0))
    observer.receive(cert(plan, next(seq), slot, w6), 1.3)
    claim_and_beat(1.31)
    assert observer.snapshot().known["f2"] == (6, 1)


def test_per_robot_a_leave_signed_by_the_holder_is_its_own_certificate(paper: Paper) -> None:
    plan, params = paper
    ids = fake_identities(plan.robots)
    observer = Node(1, plan, params, 0.0, identity=ids[1])
    observer.tick(0.0)
    slot = plan.slot("f2")
    # 2's anchor first: a LEAVE of a robot not heard yet is not judged within the
    # receiver's start-up grace (DESIGN, "Every proof is bound to its run").
    observer.receive(signed_beat(ids[2], plan.swarm_id, 2, 400, slot, 0), 0.9)
    observer.receive(_signed(ids[2], plan, 2, 500, wire.Leave(slot, 0, 0)), 1.0)
    observer.receive(_signed(ids[6], plan, 6, 900, wire.Claim(2, slot, 1)), 1.01)
    observer.receive(signed_beat(ids[6], plan.swarm_id, 6, 901, slot, 1), 1.2)
    assert observer.snapshot().known["f2"] == (6, 1)
    assert observer.drops.get("uncertified", 0) == 0


# ---------------------------------------------------------------- the wire, per-robot
def test_per_robot_frame_sizes_and_verification(paper: Paper) -> None:
    plan, _ = paper
    ids = fake_identities(plan.robots)
    verifier = ids[1].verifier
    key = bytes(32)

    def enc(sender: int, msg: wire.Message, signer_of: int | None = None) -> bytes:
        signer = ids[signer_of or sender].signer
        return wire.encode(wire.Frame(plan.swarm_id, sender, 7, msg), key, signer)

    beat = enc(2, wire.Heartbeat(2, 0, 1, 0, 1, bytes(8)))
    anchor = enc(2, wire.Heartbeat(2, 0, 1, 0, 1, bytes(8), anchor=True))
    warn = enc(3, wire.Warn(2, 2, 0))
    claim = enc(6, wire.Claim(2, 2, 1))
    leave = enc(2, wire.Leave(2, 0, 0))
    relay = enc(6, wire.Cert(2, wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0)), warn))
    sizes = [len(x) for x in (beat, anchor, warn, claim, leave, relay)]
    assert sizes == [32, 88, 81, 80, 79, 93]  # a WARN carries its belief (DESIGN "Detection")
    bare = wire.encode(wire.Frame(plan.swarm_id, 2, 7, wire.Heartbeat(2, 0, 1, 0, 1, bytes(8))),
                       None, ids[2].signer)
    assert len(bare) == 24  # per robot without a swarm key: the link alone
    got_beat = wire.decode(anchor, (key,), verifier).msg
    assert isinstance(got_beat, wire.Heartbeat) and got_beat.anchor
    got_beat = wire.decode(beat, (key,), verifier).msg
    assert isinstance(got_beat, wire.Heartbeat) and not got_beat.anchor
    # An anchor in robot 2's name signed with robot 6's key is refused.
    with pytest.raises(wire.CodecError) as exc:
        wire.decode(enc(2, wire.Heartbeat(2, 0, 1, 0, 1, bytes(8), anchor=True), 6),
                    (key,), verifier)
    assert exc.value.reason == "auth"
    got = wire.decode(relay, (key,), verifier)
    assert isinstance(got.msg, wire.Cert) and got.msg.inner.sender == 3
    # A relayed CLAIM (a takeover shown whole to a robot with an older view) verifies
    # with its claimant's key; a relayed heartbeat is no evidence of anything.
    blank = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
    got = wire.decode(enc(3, wire.Cert(2, blank, claim)), (key,), verifier)
    assert isinstance(got.msg, wire.Cert) and got.msg.inner.msg == wire.Claim(2, 2, 1)
    with pytest.raises(wire.CodecError) as exc:
        wire.decode(enc(3, wire.Cert(2, blank, anchor)), (key,), verifier)
    assert exc.value.reason == "malformed"
    assert wire.decode(warn, (key,), verifier).raw == warn
    # A WARN in robot 3's name signed with robot 6's key, bare or relayed: refused.
    forged = enc(3, wire.Warn(2, 2, 0), signer_of=6)
    for data in (forged, enc(6, wire.Cert(2, wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0)),
                                         forged))):
        with pytest.raises(wire.CodecError) as exc:
            wire.decode(data, (key,), verifier)
        assert exc.value.reason == "auth"
    # The swarm key alone does not vouch for a WARN in per-robot mode.
    hmac_only = wire.encode(wire.Frame(plan.swarm_id, 3, 8, wire.Warn(2, 2, 0)), key)
    with pytest.raises(wire.CodecError):
        wire.decode(hmac_only, (key,), verifier)
    # A certificate means nothing to a robot without robot keys.
    with pytest.raises(wire.CodecError):
        wire.decode(relay, (key,))


# ---------------------------------------------------------------- chaos, per-robot
def test_per_robot_random_chaos_breaks_no_invariant() -> None:
    """A sample of bench/bench_chaos.py's random swarms and schedules, per-robot mode."""
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "bench" / "bench_chaos.py"
    spec = importlib.util.spec_from_file_location("bench_chaos", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules["bench_chaos"] = bench
    spec.loader.exec_module(bench)
    from swarmd.core.params import udp
    # Seeds 0-99 run per robot in tests/test_chaos.py; here 25 (a standby's own refuted
    # claim relayed back in a reassertion's proof) and a sample beyond them.
    for seed in (25, *range(100, 300, 10)):
        case = bench.draw_case(seed, max_robots=12)
        res = run_virtual(case.plan, udp(), duration=case.duration, faults=case.faults,
                          loss=case.loss, seed=case.seed, auth="per-robot")
        assert res.violations == [], (seed, [v.as_dict() for v in res.violations])


# ---------------------------------------------------------------- seqs bounded by the clock
# (DESIGN section 2, "Sequence numbers"): a receiver bounds every sender's seq by its own
# clock, from the first frame heard and after a restore.
NOW_SEQ = wire.seq_seed(1_750_000_000.0)
"""Where a daemon's counter starts: its wall clock in 10 us units."""
MODES = ["none", "shared", "per-robot"]


def _mode_node(plan: SwarmPlan, params: Params, mode: str, rid: int, now: float, *,
               seq_start: int = NOW_SEQ, restored: Restored | None = None) -> Node:
    key = (bytes(32),) if mode != "none" else ()
    ident = fake_identities(plan.robots)[rid] if mode == "per-robot" else None
    node = Node(rid, plan, params, now, keys=key, identity=ident, seq_start=seq_start,
                restored=restored)
    node.tick(now)
    return node


def _beat(plan: SwarmPlan, mode: str, sender: int, seq: int) -> bytes:
    """A heartbeat of `sender` (holder of its home slot at epoch 0): what the robot sends,
    or what an insider with the swarm key (anyone, unsigned) forges in its name; per
    robot, an anchor signed with the sender's own key (only it can make one)."""
    key = bytes(32) if mode != "none" else None
    if mode == "per-robot":
        return signed_beat(fake_identities(plan.robots)[sender], plan.swarm_id, sender, seq,
                           sender, 0, key=key)
    return wire.encode(wire.Frame(plan.swarm_id, sender, seq,
                                  wire.Heartbeat(sender, 0, 1, 0)), key)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("restart", [False, True])
def test_a_max_seq_heard_first_mutes_nobody(paper: Paper, mode: str, restart: bool) -> None:
    """One heartbeat in robot 2's name at 2^48-1 is the first frame robot 1 hears of it,
    at its start or after a restart (the restored seq was no bound either): robot 2's
    own heartbeats are still heard, not dropped as replays for good."""
    plan, params = paper
    restored = Restored(peer_seq={2: NOW_SEQ + 50}) if restart else None
    node = _mode_node(plan, params, mode, 1, 10.0, restored=restored)
    node.receive(_beat(plan, mode, 2, wire.SEQ_MAX - 1), 10.0)
    assert node.drops["seq_jump"] == 1
    for i in range(20):
        node.receive(_beat(plan, mode, 2, NOW_SEQ + 100 + i), 10.1 + 0.1 * i)
    assert node.drops["replay"] == 0
    assert node.snapshot().heard[2] == pytest.approx(12.0)


def _claim_of(plan: SwarmPlan, mode: str, claimant: int, seq: int, c: wire.Claim) -> bytes:
    """`claimant`'s CLAIM `c` as the swarm's mode makes it: per robot signed with the
    claimant's own key (an insider's own claim), with a shared key tagged, unsigned bare."""
    key = bytes(32) if mode != "none" else None
    signer = fake_identities(plan.robots)[claimant].signer if mode == "per-robot" else None
    return wire.encode(wire.Frame(plan.swarm_id, claimant, seq, c), key, signer)


@pytest.mark.parametrize("mode", MODES)
def test_a_claim_replacing_a_live_hold_is_refuted_once_certified_here_or_not(
        paper: Paper, mode: str) -> None:
    """Robot 2 holds f2 at epoch 0, alive; 6 (which covers f2) claims f2 at epoch 1 with
    no certificate that verifies at 2 (rule 4: the robots that hold one judge 2's REFUTE
    with it, `Proofs._refute_claim`). 2 refutes it once, however often it comes; a claim
    in the name of robot 4, which does not cover f2, gets no answer, so a stream of them
    costs nothing."""
    plan, params = paper
    key = (bytes(32),) if mode != "none" else ()
    verifier = fake_identities(plan.robots)[1].verifier if mode == "per-robot" else None
    node = _mode_node(plan, params, mode, 2, 1.0)
    slot = plan.slot("f2")

    def refutes(data: bytes, now: float) -> list[wire.Refute]:
        out = [wire.decode(a.frame, key, verifier).msg for a in node.receive(data, now)
               if isinstance(a, Broadcast)]
        return [m for m in out if isinstance(m, wire.Refute)]

    claim = _claim_of(plan, mode, 6, NOW_SEQ + 10, wire.Claim(2, slot, 1))
    first = refutes(claim, 1.1)
    assert [(r.witness, r.epoch, r.seq) for r in first] == [(6, 1, NOW_SEQ + 10)]
    again = _claim_of(plan, mode, 6, NOW_SEQ + 11, wire.Claim(2, slot, 1))
    assert refutes(again, 1.2) == []
    for i in range(5):
        forged = _claim_of(plan, mode, 4, NOW_SEQ + 20 + i, wire.Claim(2, slot, 1))
        assert refutes(forged, 1.3 + 0.01 * i) == []
    assert (node.snapshot().function, node.snapshot().epoch) == ("f2", 0)


@pytest.mark.parametrize("mode", MODES)
def test_a_walk_at_any_rate_stops_at_the_receivers_clock(paper: Paper, mode: str) -> None:
    """Walking robot 2's seq up in big steps, 4,000 frames a second: the walk stops at
    the receiver's own clock plus the stated allowance, so the 48-bit space cannot be
    used up faster than real time; robot 2's own counter does not move on it (`own`),
    and the receiver still hears robot 2's own next frames below the walk."""
    from swarmd.core.replay import AHEAD, JUMP, RATE

    plan, params = paper
    node = _mode_node(plan, params, mode, 1, 0.0)
    node.receive(_beat(plan, mode, 2, NOW_SEQ), 0.0)  # robot 1 has heard robot 2
    step = JUMP // 2
    for i in range(2000):
        node.receive(_beat(plan, mode, 2, NOW_SEQ + step * (i + 1)), i / 4000)
    top = max(s for s in node._replay.state[2].main.seqs)
    assert top <= NOW_SEQ + int(RATE * 0.5) + AHEAD
    assert node.drops["seq_jump"] >= 2000 - (AHEAD + RATE) // step - 1
    two = _mode_node(plan, params, mode, 2, 0.0)
    for i in range(2000):
        two.receive(_beat(plan, mode, 2, NOW_SEQ + step * (i + 1)), i / 4000)
    assert two.snapshot().seq < NOW_SEQ + step and two.drops["own"] > 0
    for i in range(20):
        node.receive(_beat(plan, mode, 2, NOW_SEQ + 1 + i), 0.6 + 0.1 * i)
    assert node.drops["replay"] == 0 and node.snapshot().heard[2] == pytest.approx(2.5)


@pytest.mark.parametrize("mode", MODES)
def test_an_absurd_restored_peer_seq_is_refused(paper: Paper, mode: str) -> None:
    """A persisted seq of robot 2 far beyond any clock (written after a forged frame
    was taken, or a corrupted file): refused at the restore, so it mutes nobody across
    restarts; a plausible one still keeps old frames old."""
    plan, params = paper
    node = _mode_node(plan, params, mode, 1, 5.0,
                      restored=Restored(peer_seq={2: wire.SEQ_MAX - 1, 4: NOW_SEQ - 10}))
    assert 2 not in node.snapshot().peer_seq and node.drops["seq_jump"] == 1
    node.receive(_beat(plan, mode, 2, NOW_SEQ + 5), 5.1)
    node.receive(_beat(plan, mode, 4, NOW_SEQ - 20), 5.1)  # older than what was kept
    assert node.drops["replay"] == 1 and 2 in node.snapshot().heard


def test_a_sender_restarted_after_a_long_run_is_heard(paper: Paper) -> None:
    """A sender's counter lags its clock by its uptime (one step a frame, 10^5 a
    second): restarted after ten minutes it reseeds from its clock, 6*10^7 above its
    last frame. That is no jump to drop: it is within the receiver's clock."""
    plan, params = paper
    node = _mode_node(plan, params, "none", 1, 0.0)
    for i in range(6000):  # ten minutes of heartbeats at 10 Hz
        node.receive(_beat(plan, "none", 2, NOW_SEQ + i), 0.1 * i)
    restarted = wire.seq_seed(1_750_000_000.0 + 602.0)
    node.receive(_beat(plan, "none", 2, restarted), 602.0)
    assert node.drops["seq_jump"] == 0 and node.snapshot().heard[2] == 602.0
    # What a restart of robot 1 would persist follows robot 2's new run once it has
    # sent more than what robot 1 still remembers of the old one.
    for i in range(1, 40):
        node.receive(_beat(plan, "none", 2, restarted + i), 602.0 + 0.1 * i)
    assert node.snapshot().peer_seq[2] == restarted + 39


def test_replay_filter_clock_and_limits() -> None:
    from swarmd.core.replay import AHEAD, RATE, ReplayFilter

    f = ReplayFilter(1000, 2.0)
    assert f.clock(2.0) == 1000 and f.clock(12.0) == 1000 + 10 * RATE
    assert f.clock(1.0) == 1000  # never before the start
    assert f.limit(2.0) == 1000 + AHEAD
    assert f.check(2, 1000 + AHEAD + 1, 2.0) == "seq_jump" and f.top(2) is None
    assert f.check(2, 1000 + AHEAD, 2.0) is None
    assert not f.restore(3, 1000 + AHEAD + 1) and f.restore(3, 1000 + AHEAD)
    assert ReplayFilter().check(2, wire.SEQ_MAX, 5.0) is None  # no origin, no bound


def _six_takes_f2_on_robot_2s_leave(paper: Paper) -> tuple[dict[int, Identity], Node,
                                                             bytes, bytes]:
    """Per robot, standby 6 takes f2 over on robot 2's signed LEAVE: the robots'
    identities, 6's node holding f2 at epoch 1, the LEAVE and the CLAIM 6 signed."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    node = Node(6, plan, params, 0.0, identity=ids[6])
    node.tick(0.0)
    slot = plan.slot("f2")
    leave = _signed(ids[2], plan, 2, 700, wire.Leave(slot, 0, 0))
    node.receive(signed_beat(ids[2], plan.swarm_id, 2, 600, slot, 0), 0.1)
    sent = [a.frame for a in node.receive(leave, 1.0) if isinstance(a, Broadcast)]
    claim = next(raw for raw in sent
                 if isinstance(wire.decode(raw, (), ids[1].verifier).msg, wire.Claim))
    node.tick(1.0 + params.claim_hold + 0.01)
    assert (node.snapshot().function, node.snapshot().epoch) == ("f2", 1)
    return ids, node, leave, claim


def test_per_robot_certificate_survives_a_restart(paper: Paper) -> None:
    """The new holder persists its certificate; after a restart it can still prove its
    hold to the old holder back from a partition."""
    plan, params = paper
    res_ids, node, leave, claim = _six_takes_f2_on_robot_2s_leave(paper)
    slot = plan.slot("f2")
    snap = node.snapshot()
    assert (snap.function, snap.epoch) == ("f2", 1) and snap.certificate == (leave,)
    # Its seq a clock that a restart does not set back (DESIGN, "Sequence numbers").
    again = Node(6, plan, params, 5.0, identity=res_ids[6], seq_start=snap.seq + 100,
                 restored=Restored(
        known=dict(snap.known), held=("f2", 1), peer_seq=dict(snap.peer_seq),
        certificate=snap.certificate))
    again.tick(5.0)
    again.tick(5.0 + params.rejoin_hold)
    assert again.snapshot().function == "f2"
    assert again.snapshot().certificate == (leave,)
    # Its claim from before the restart, relayed back by a robot that kept it: older
    # than the standby heartbeats of the rejoin, so outdated wherever they were heard.
    blank = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
    again.receive(wire.encode(wire.Frame(plan.swarm_id, 1, 50, wire.Cert(slot, blank, claim))),
                  5.9)
    # The old holder's stale heartbeat gets the whole proof back, in CERTs: the
    # certificate and the claim it backs, which the restart lost and the resumed hold
    # signed again (the latest, not the one relayed back).
    stale = signed_beat(res_ids[2], plan.swarm_id, 2, 800, slot, 0)
    out = [wire.decode(a.frame, (), res_ids[1].verifier).msg
           for a in again.receive(stale, 6.0) if isinstance(a, Broadcast)]
    inner = [m.inner for m in out if isinstance(m, wire.Cert)]
    assert [f.msg for f in inner if f.sender == 2] == [wire.Leave(slot, 0, 0)]
    assert [(f.sender, f.msg) for f in inner if isinstance(f.msg, wire.Claim)] == [
        (6, wire.Claim(2, slot, 1))]
    old_seq = wire.decode(claim, (), res_ids[1].verifier).seq
    assert all(f.seq > old_seq for f in inner if isinstance(f.msg, wire.Claim))


def test_per_robot_a_heartbeat_that_proves_nothing_gets_the_refutes_that_void_it(
        paper: Paper) -> None:
    """Watcher 1 holds robot 2's signed REFUTE of a warning about it (f2 at epoch 0). A
    heartbeat in 6's name holding f2 at epoch 1, on a link of no chain 1 follows
    (`unanchored`: a forger, or a robot whose chain 1 lost), proves nothing; 1 answers it
    as it answers an uncertified one (`Hearing._unproven_beat`, DESIGN "How entries
    spread"): with the REFUTE, which voids any claim against 2's entry, inside a CERT,
    at most once per T_max; its view stays 2's."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    one = Node(1, plan, params, 0.0, identity=ids[1])
    one.tick(0.0)
    slot = plan.slot("f2")
    refute = _signed(ids[2], plan, 2, 40, wire.Refute(3, slot, 0, 9))
    one.receive(refute, 0.5)
    unanchored = signed_beat(None, plan.swarm_id, 6, 10**6, slot, 1, link=b"\x07" * 8, n=1)
    shown = []
    for t in (1.0, 1.0 + params.t_max / 2, 1.0 + params.t_max + 0.01):
        out = [wire.decode(a.frame, (), ids[1].verifier).msg
               for a in one.receive(unanchored, t) if isinstance(a, Broadcast)]
        shown.append([m.inner.raw for m in out if isinstance(m, wire.Cert)])
    assert shown == [[refute], [], [refute]]
    assert one.drops["unanchored"] == 3
    assert one.snapshot().known["f2"] == (2, 0)


def test_per_robot_a_proof_is_shown_once_per_t_max_whoever_asks(paper: Paper) -> None:
    """A holder shows the proof of its entry one way (`Proofs._show`): to the old
    holder's stale heartbeat, its certificate and its own signed CLAIM, inside CERTs; a
    watcher's warning about the old holder within T_max gets nothing more (one gate a
    slot, whoever asked), and after T_max the whole proof again."""
    plan, params = paper
    ids, node, _, _ = _six_takes_f2_on_robot_2s_leave(paper)
    slot = plan.slot("f2")

    def shown(frame: bytes, now: float) -> list[tuple[int, wire.Message]]:
        return [(c.inner.sender, c.inner.msg) for a in node.receive(frame, now)
                if isinstance(a, Broadcast)
                and isinstance(c := wire.decode(a.frame, (), ids[1].verifier).msg, wire.Cert)]

    t = 2.0
    stale = signed_beat(ids[2], plan.swarm_id, 2, 800, slot, 0)
    assert shown(stale, t) == [(2, wire.Leave(slot, 0, 0)), (6, wire.Claim(2, slot, 1))]
    warn = _signed(ids[1], plan, 1, 900, wire.Warn(2, slot, 0))
    assert shown(warn, t + params.t_max / 2) == []
    again = _signed(ids[1], plan, 1, 901, wire.Warn(2, slot, 0))
    assert (6, wire.Claim(2, slot, 1)) in shown(again, t + params.t_max + 0.01)

# ---------------------------------------------------------------- fragments
# (DESIGN section 2, "Fragments"): a forger spoils at most the messages it has seen.
class _Air:
    """What a serial radio puts on the air: the transport's writes, as datagrams."""

    def __init__(self) -> None:
        from swarmd.transport import framing

        self.decoder = framing.FrameDecoder()
        self.datagrams: list[bytes] = []

    def get_write_buffer_size(self) -> int:
        return 0

    def write(self, data: bytes) -> None:
        self.datagrams += self.decoder.feed(data)


def _warns(n: int) -> list[bytes]:
    """Robot 3's per-robot signed WARNs: 80 B, two fragments each on a 64 B serial radio."""
    ids = fake_identities([3])
    return [wire.encode(wire.Frame(0x607, 3, 1000 + i, wire.Warn(1, 1, 0)), None, ids[3].signer)
            for i in range(n)]


def test_fragment_ids_cannot_be_predicted_from_a_heard_one() -> None:
    """A listener heard one fragmented message of robot 3 (its id), then forges one
    fragment in robot 3's name for each of the next eight ids a counter would give:
    robot 3's next messages still reassemble whole (a random id is hit by a guess once
    in 65,536; one hit is allowed, so the test cannot flake)."""
    from typing import cast

    from swarmd.transport import fragment
    from swarmd.transport.serial import SerialTransport

    tx = SerialTransport(port="/dev/null")  # never opened: the air is `_Air`
    air = _Air()
    cast(Any, tx)._transport = air
    first, *later = _warns(9)
    tx.send(first)
    heard = fragment.HEADER.unpack_from(air.datagrams[0])[2]
    rx = fragment.Reassembler()
    for guess in range(heard + 1, heard + 9):
        forged = fragment.HEADER.pack(fragment.MARKER, 3, guess & 0xFFFF, 1 << 4 | 2)
        assert rx.feed(forged + bytes(40), 0.0) is None
    air.datagrams.clear()
    for f in later:
        tx.send(f)
    got = [out for d in air.datagrams if (out := rx.feed(d, 0.1)) is not None]
    assert len(air.datagrams) == 2 * len(later)
    assert len(set(got) & set(later)) >= len(later) - 1


def test_a_fragment_flood_in_one_name_spoils_no_other_robots_message() -> None:
    """One robot's name on a flood of first fragments of made-up messages: the other
    robots' messages in flight are not evicted (a per-sender reassembly budget)."""
    from swarmd.transport import fragment

    warn = _warns(1)[0]
    pieces = fragment.split(warn, 64, 0x5A5A)
    rx = fragment.Reassembler()
    assert rx.feed(pieces[0], 0.0) is None
    for i in range(200):  # made-up messages of robot 9
        forged = fragment.HEADER.pack(fragment.MARKER, 9, i, 1 << 4 | 2)
        rx.feed(forged + bytes(40), 0.001)
    assert rx.feed(pieces[1], 0.002) == warn
    assert rx.drops["evicted_sender"] >= 190 and len(rx) <= fragment.MAX_PER_SENDER


# ---------------------------------------------------------------- the robot link
async def test_a_robot_link_flood_never_starves_the_loop(tmp_path: Any,
                                                         caplog: pytest.LogCaptureFixture) -> None:
    """120 kB of short bad lines on the socket robot link: the loop gets a turn every
    `LINES_PER_TURN` lines (its timers, the protocol's heartbeats, run between), the log
    gets one line for the lot, not one a line, and the health line after them counts."""
    import asyncio
    import logging

    from swarmd.core.roles import Health
    from swarmd.link.socket import SocketLink

    healths: list[Health] = []
    link = SocketLink(tmp_path / "robot.sock", health_timeout=30.0)
    await link.start(healths.append)
    per_turn: list[int] = []
    last = 0

    def turn() -> None:  # one call per turn of the loop
        nonlocal last
        per_turn.append(link.counters["bad_lines"] - last)
        last = link.counters["bad_lines"]
        if not healths:
            ticker[0] = asyncio.get_running_loop().call_soon(turn)

    ticker = [asyncio.get_running_loop().call_soon(turn)]
    try:
        with caplog.at_level(logging.WARNING, logger="swarmd.link.socket"):
            _, writer = await asyncio.open_unix_connection(str(tmp_path / "robot.sock"))
            writer.write(b"x\n" * 60_000 + b'{"health": "ok"}\n')
            await writer.drain()
            await asyncio.wait_for(_until(lambda: bool(healths)), 30.0)
            writer.close()
    finally:
        ticker[0].cancel()
        await link.close()
    assert healths == [Health.OK] and link.counters["bad_lines"] == 60_000
    assert max(per_turn) <= 2 * 64  # two of the link's turns at most between two of ours
    logged = [r for r in caplog.records if "bad line" in r.getMessage()]
    assert 1 <= len(logged) <= 2 and "60000" not in logged[0].getMessage()


async def _until(cond: Any) -> None:
    import asyncio

    while not cond():
        await asyncio.sleep(0.01)


class _Burst:
    """An autopilot connection that delivers `n` heartbeats at once, their status
    flapping between CRITICAL and ACTIVE, then nothing."""

    def __init__(self, n: int) -> None:
        import io

        from pymavlink.dialects.v20 import common as mavlink2
        from test_mavlink_link import Autopilot

        ap = Autopilot("px4")
        self.msgs = [ap.heartbeat(status=5 if i % 2 else 4) for i in range(n)]
        self.mav = mavlink2.MAVLink(io.BytesIO(), srcSystem=1, srcComponent=191)

    def recv_match(self, blocking: bool, timeout: float) -> Any:
        import time

        if self.msgs:
            return self.msgs.pop()
        time.sleep(min(timeout, 0.01))
        return None

    def close(self) -> None:
        pass


async def test_a_mavlink_burst_is_handed_over_and_logged_in_bounded_pieces(
        caplog: pytest.LogCaptureFixture) -> None:
    """4,000 heartbeats at once whose health flaps: the loop is handed the latest health
    a few times, not 4,000 callbacks, and the log counts the changes in one line."""
    import asyncio
    import logging

    from swarmd.core.roles import Health
    from swarmd.link.mavlink import MavlinkLink

    burst = _Burst(4000)
    got: list[Health] = []
    link = MavlinkLink("/dev/ttyFAKE", opener=lambda: burst)
    with caplog.at_level(logging.INFO, logger="swarmd.link.mavlink"):
        await link.start(got.append)
        try:
            await asyncio.wait_for(_until(lambda: not burst.msgs), 30.0)
            await asyncio.sleep(0.1)  # the hand-overs still queued, if any
        finally:
            await link.close()
    assert got and set(got) <= {Health.OK, Health.DEGRADED}
    assert len(got) <= 400
    logged = [r for r in caplog.records if "robot health" in r.getMessage()]
    assert 1 <= len(logged) <= 2


# ---------------------------------------------------------------- the monitor
class _Channel:
    """A transport for `swarmd monitor` (`listen`): at its start, a forged heartbeat far
    ahead in the name of every robot; `later` s after, each robot's own heartbeat."""

    max_payload = 255

    def __init__(self, plan: SwarmPlan, key: bytes | None, later: float) -> None:
        self.plan, self.key, self.later = plan, key, later
        self.heard_at: float | None = None

    def _beats(self, seq: int) -> list[bytes]:
        return [wire.encode(wire.Frame(self.plan.swarm_id, r, seq + r, wire.Heartbeat(
            r if r <= 4 else 0, 0, 1 if r <= 4 else 2, 0)), self.key) for r in range(1, 7)]

    async def start(self, on_frame: Any, on_event: Any) -> None:
        import asyncio
        import time

        loop = asyncio.get_running_loop()
        for f in self._beats(wire.SEQ_MAX - 10):
            on_frame(f)

        def genuine() -> None:
            self.heard_at = loop.time()
            for f in self._beats(wire.seq_seed(time.time())):
                on_frame(f)

        loop.call_later(self.later, genuine)

    def send(self, frame: bytes) -> None:
        raise AssertionError("a monitor never sends")

    async def close(self) -> None:
        pass


@pytest.mark.parametrize("mode", ["none", "shared"])
async def test_the_monitor_bounds_seqs_as_the_daemons_do(paper: Paper, mode: str) -> None:
    """Forged (or bit-flipped) frames far ahead, one per robot, then the robots' own
    heartbeats: every robot is live at the monitor, none silent, no false alert."""
    from swarmd.daemon.monitor import MonitorState, listen

    plan, params = paper
    key = bytes(32) if mode == "shared" else None
    state = MonitorState(plan, params, (key,) if key else ())
    channel = _Channel(plan, key, later=params.t_max + 0.1)
    await listen(state, channel, duration=params.t_max + 0.3)
    assert channel.heard_at is not None
    now = channel.heard_at
    assert {r["robot"]: r["status"] for r in state.rows(now)} == dict.fromkeys(range(1, 7),
                                                                                "live")
    assert state.alerts(now) == [] and state.drops == {"seq_jump": 6}


def test_the_monitor_shows_an_insiders_heartbeat_as_unverified(paper: Paper) -> None:
    """Per-robot mode: one heartbeat with the swarm key in robot 1's name holding f2 at
    epoch 1 supersedes nobody (robot 1 is shown `unverified`, no split brain). Row 2:
    standby 6's own signed CLAIM for f2 with no certificate, and its anchor at epoch 1,
    supersede nobody either (the daemons are unmoved by them: so is the monitor); with
    the warnings of a quorum of f2's watchers (its certificate) they do."""
    from swarmd.daemon.monitor import MonitorState

    plan, params = paper
    ids = fake_identities(plan.robots)
    key = bytes(32)
    state = MonitorState(plan, params, (key,), verifier=ids[1].verifier)
    seq = iter(range(1000, 2000))

    def beat(r: int, slot: int, epoch: int) -> bytes:
        return signed_beat(ids[r], plan.swarm_id, r, next(seq), slot, epoch, key=key)

    for r in range(1, 5):
        state.feed(beat(r, r, 0), 0.0)
    state.feed(beat(1, 2, 1), 0.1)  # the insider's one frame
    rows = {r["robot"]: r for r in state.rows(0.2)}
    assert rows[2]["status"] == "live" and rows[1]["status"] == "unverified"
    assert state.alerts(0.2) == []
    claim = _signed(ids[6], plan, 6, next(seq), wire.Claim(2, 2, 1))
    state.feed(claim, 0.3)  # no certificate
    state.feed(beat(6, 2, 1), 0.3)
    for r in range(1, 5):
        state.feed(beat(r, r, 0), 0.35)
    rows = {r["robot"]: r for r in state.rows(0.4)}
    assert rows[2]["status"] == "live" and rows[6]["status"] == "unverified"
    assert state.alerts(0.4) == []
    for witness in (1, 3):  # f2's watchers warn about robot 2: the certificate
        state.feed(_signed(ids[witness], plan, witness, next(seq), wire.Warn(2, 2, 0)), 0.5)
    state.feed(_signed(ids[6], plan, 6, next(seq), wire.Claim(2, 2, 1)), 0.5)
    state.feed(beat(6, 2, 1), 0.5)
    rows = {r["robot"]: r for r in state.rows(0.55)}
    assert rows[2]["status"] == "superseded" and rows[6]["status"] == "live"


async def test_lines_waiting_for_their_turn_survive_the_robot_closing(tmp_path: Any) -> None:
    """A robot writes 500 lines and closes at once: the lines still waiting for their
    turn when the connection ends are handled one by one, the last health line too."""
    import asyncio

    from swarmd.core.roles import Health
    from swarmd.link.socket import SocketLink

    healths: list[Health] = []
    link = SocketLink(tmp_path / "robot.sock", health_timeout=30.0)
    await link.start(healths.append)
    try:
        _, writer = await asyncio.open_unix_connection(str(tmp_path / "robot.sock"))
        writer.write(b'{"health": "degraded"}\n' * 499 + b'{"health": "ok"}')
        await writer.drain()
        writer.write_eof()
        await asyncio.wait_for(_until(lambda: len(healths) == 500), 30.0)
    finally:
        await link.close()
    assert healths[-1] == Health.OK and link.counters["bad_lines"] == 0
