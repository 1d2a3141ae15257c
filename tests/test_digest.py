"""A standby's heartbeat shows its view of the slots it covers (DESIGN section 2,
"Convergence", "How entries spread"; `swarmd/core/digest.py`), on virtual time.

Standbys 5 and 6 both cover f2 of the paper's ring. Robot 2 crashes and 6 takes f2
over while 5 hears nothing (deaf to everyone, it still transmits): 5's view of f2 stays
(2, 0). Once it hears again, its next standby heartbeat shows f2 at epoch 0 mod 4, and
6 (holding f2 at epoch 1) answers it at once: 5 holds (6, 1) within a standby period
and the answer, not the unasked relay's RELAY_EVERY T_max. The same for 5 restarted
from a state file older than the takeover.
"""

from __future__ import annotations

from collections.abc import Sequence

import pytest
from harness import Net
from swarms import two_standbys

from sim.shared.fakeid import fake_identities
from swarmd.core import digest, wire
from swarmd.core.actions import Action, Broadcast
from swarmd.core.node import Node, Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.records import Holder

KEY = b"d" * 32
MODES = ("per-robot", "shared", "none")
HEAL = 6.0


def net(plan: SwarmPlan, params: Params, auth: str) -> Net:
    ids = fake_identities(plan.robots) if auth == "per-robot" else {}
    keys = (KEY,) if auth in ("shared", "per-robot") else ()
    # 5 deaf to everyone from 2.9 s to the heal: it misses robot 2's crash and 6's
    # takeover, and hears 6 heartbeat f2 at epoch 1 only afterwards.
    return Net(plan, params, keys=keys, identities=ids, cuts=[(None, 5, 2.9, HEAL)])


def merged_after_heal(params: Params, auth: str, restart: bool = False) -> float:
    """Seconds from the heal until standby 5 holds 6's takeover of f2: 5 deaf until
    the heal, or (`restart`) down from before robot 2's crash and restarted at the heal
    from a state file that predates the takeover."""
    n = net(two_standbys(), params, auth)
    n.run_until(3.0)
    n.crash(2)
    if restart:
        n.crash(5)
    n.run_until(HEAL)
    if restart:
        n.boot(5, Restored(known={"f2": (2, 0)}), seq_start=10**7)
    assert n.nodes[6].snapshot().function == "f2", "6 took f2 over"
    assert n.nodes[5].snapshot().known["f2"] == (2, 0), "5 missed it"
    t = HEAL
    while n.nodes[5].snapshot().known["f2"] != (6, 1):
        t += 0.01
        assert t < HEAL + 10.0, "5 never learnt the takeover"
        n.run_until(t)
    return t - HEAL


@pytest.mark.parametrize("auth", MODES)
@pytest.mark.parametrize("restart", [False, True])
def test_a_standby_that_missed_a_takeover_learns_it_within_a_standby_period(
        udp_params: Params, auth: str, restart: bool) -> None:
    """The bound for a standby (DESIGN "Why it converges"): its next heartbeat after
    the heal, plus the holder's answer; at most one more standby period if the holder
    answered another digest within its gate just before the heal, and per robot one
    heartbeat period for the holder's next anchor. Restarted, with a shared key or
    unsigned, 5 has heard nothing of 6 but heartbeats that raise f2's entry: it holds
    them until its start-up grace ends (DESIGN, "Every proof is bound to its run")."""
    p = udp_params
    took = merged_after_heal(p, auth, restart)
    bound = 2 * p.standby_heartbeat_interval + p.heartbeat_interval
    if restart and auth != "per-robot":
        bound = max(bound, p.startup_grace)
    assert took <= bound + 0.01, took


def test_the_digest_shows_the_first_eight_covered_slots_two_bits_each() -> None:
    covered = tuple(f"f{i}" for i in range(10))
    known = {f: Holder(1, 4 * i + i % 4) for i, f in enumerate(covered)}
    d = digest.make(covered, known)
    assert 0 <= d <= 0xFFFF
    assert [digest.shown(d, covered, f) for f in covered] == [0, 1, 2, 3, 0, 1, 2, 3,
                                                              None, None]
    assert not digest.differs(d, covered, "f1", 5) and digest.differs(d, covered, "f1", 4)
    assert not digest.differs(d, covered, "f9", 0)  # not shown: nothing to answer
    assert digest.make((), known) == 0


@pytest.mark.parametrize("auth", MODES)
def test_a_standby_heartbeats_its_digest_and_an_old_format_zero_is_harmless(
        udp_params: Params, auth: str) -> None:
    """A standby's heartbeat carries its digest (no byte added); any 16-bit digest,
    0 from a robot of the older format included, makes the holder answer at most
    once per its gate, and moves nobody's entry."""
    plan = two_standbys()
    n = net(plan, udp_params, auth)
    n.run_until(3.0)
    n.crash(2)
    n.run_until(HEAL + 1.0)
    keys = (KEY,) if auth != "none" else ()
    verifier = n.identities[6][1] if auth == "per-robot" else None
    beats = [wire.decode(f, keys, verifier).msg for _, r, f in n.frames if r == 5]
    ours = [m for m in beats if isinstance(m, wire.Heartbeat)]
    assert ours and ours[-1].function == 0 and ours[-1].epoch == 1  # f2 at epoch 1
    holder: Node = n.nodes[6]
    before = holder.snapshot().known
    last = max(t for t, r, _ in n.frames if r == 6)
    mid, seq = last + udp_params.heartbeat_interval / 2, n.nodes[5].snapshot().seq
    out: list[Action] = []
    for i, d in enumerate(range(0, 0x10000, 0x0FFF)):  # per robot 5's own anchors
        out += holder.receive(beat_of(n, auth, 5, d, seq + 1 + i), mid + i * 0.001)
    assert holder.snapshot().known == before
    got = answers(n, auth, out, holder=6)
    assert [(m.function, m.epoch) for m in got] == [(2, 1)]  # one, within the gate
    assert len(out) <= 4, out  # and per robot its certificate: 2 warnings, the claim


def beat_of(n: Net, auth: str, sender: int, shown: int, seq: int) -> bytes:
    """A heartbeat without a slot from `sender` showing digest `shown` (per robot an
    anchor of its own key, so it needs no chain)."""
    keys = (KEY,) if auth != "none" else ()
    signer = n.identities[sender][0] if auth == "per-robot" else None
    hb = wire.Heartbeat(0, shown, 2, 0, 1, bytes(8), anchor=True) if signer \
        else wire.Heartbeat(0, shown, 2, 0)
    return wire.encode(wire.Frame(n.plan.swarm_id, sender, seq, hb),
                       keys[0] if keys else None, signer)


def answers(n: Net, auth: str, actions: Sequence[Action], holder: int = 2,
            ) -> list[wire.Heartbeat]:
    """The heartbeats among a holder's actions."""
    keys = (KEY,) if auth != "none" else ()
    verifier = n.identities[holder][1] if auth == "per-robot" else None
    msgs = [wire.decode(a.frame, keys, verifier).msg for a in actions
            if isinstance(a, Broadcast)]
    return [m for m in msgs if isinstance(m, wire.Heartbeat)]


@pytest.mark.parametrize("auth", MODES)
def test_a_holder_answers_a_digest_that_shows_its_slot_otherwise_at_once(
        udp_params: Params, auth: str) -> None:
    """Holder 2 (f2 at epoch 0) hears standby 5 show f2 at epoch 1 mod 4, between two
    of its scheduled heartbeats: it heartbeats its entry at once (per robot an anchor,
    which a standby that lost its chain accepts), and not again within its gate; a
    digest that agrees gets no answer."""
    n = net(two_standbys(), udp_params, auth)
    n.run_until(3.0)
    last = max(t for t, r, _ in n.frames if r == 2)
    holder = n.nodes[2]
    mid = last + udp_params.heartbeat_interval / 2
    seq = {r: n.nodes[r].snapshot().seq for r in (5, 6)}
    assert answers(n, auth, holder.receive(beat_of(n, auth, 5, 0, seq[5] + 1), mid)) == []
    got = answers(n, auth, holder.receive(beat_of(n, auth, 5, 1, seq[5] + 2), mid + 0.001))
    assert [(m.function, m.epoch) for m in got] == [(2, 0)]
    assert got[0].anchor == (auth == "per-robot")
    again = holder.receive(beat_of(n, auth, 6, 3, seq[6] + 1), mid + 0.002)
    assert answers(n, auth, again) == []  # within the gate, whoever shows it
