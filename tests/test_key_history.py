"""Key changes never rewrite history (DESIGN section 2, "Who may say what"): a
certificate accepted before a rotation or a revocation keeps its effect; the keys in
force decide only what comes next.

The paper's swarm: robot 2 dies, standby 6 takes f2 over on the signed warnings of its
watchers 1 and 3. Then robot 1's key changes — revoked (docs/operations.md, "Revoking a
robot") or rotated by the guide's four steps — and 6 restarts. Before, 6 checked its saved
certificate with the keys of the day, found robot 1's warning no longer verified, forgot
its hold and its view and ignored the warnings about itself: f2 was executed by nobody
while 6 lived. A robot that missed the takeover (2, back after the key change) could not
verify it either. Now the keys no longer in force still verify what they signed as a
certificate's backers (`wire.BACKERS`, `Verifier.verify(history=True)`), and only that.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from harness import Net
from swarms import paper_text, signed_paper

from sim.shared.fakeid import fake_identities
from swarmd.base.identity import (
    Ed25519Signer,
    Keyring,
    public_key_path,
    read_public_keys,
    write_identity,
)
from swarmd.config import load_robot, load_swarm
from swarmd.core import wire
from swarmd.core.auth import Identity
from swarmd.core.node import Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.proofs import RELAY_EVERY
from swarmd.core.records import Snapshot
from swarmd.daemon.daemon import Daemon, run_daemon
from swarmd.link.none import NoneLink
from swarmd.services.revocation import EXIT_REVOKED

Paper = tuple[SwarmPlan, Params]
KEY = b"k" * 32


def restored(snap: Snapshot) -> Restored:
    """What the daemon's state file hands back after a restart (services/state.py)."""
    held = (snap.function, snap.epoch) if snap.function is not None else None
    return Restored(known=dict(snap.known), held=held, peer_seq=dict(snap.peer_seq),
                    certificate=snap.certificate if held else ())


def backers(snap: Snapshot) -> set[int]:
    """Who signed the frames of a holder's certificate."""
    return {int.from_bytes(raw[3:5], "big") for raw in snap.certificate}


def took_f2_over(n: Net) -> None:
    """Robot 2 dies at 3 s; 6 takes f2 over on the warnings of 1 and 3."""
    n.run_until(3.0)
    n.crash(2)
    n.run_until(5.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    assert backers(n.nodes[6].snapshot()) == {1, 3}


def holding(n: Net) -> dict[int, str]:
    """Live robot -> the function it executes (a restarted node's own word: the harness
    keeps a crashed node's last assignment, which its daemon would have released)."""
    out: dict[int, str] = {}
    for r in sorted(n.alive):
        f = n.nodes[r].snapshot().function
        if f is not None:
            out[r] = f
    return out


def views_of_f2(n: Net) -> set[tuple[int, int]]:
    """The views of f2 of every live robot that hears it."""
    hears = [r for r in n.alive if n.plan.slot("f2") in n.plan.relevant(r).slots]
    return {(holder, epoch) for holder, epoch in
            (n.nodes[r].snapshot().known["f2"] for r in hears)}


# ------------------------------------------------------------ rotation, virtual time
def _keyrings(keys_dir: Path, swarm: Path, robots: list[int]) -> dict[int, Keyring]:
    """Each robot's keyring as its daemon reads it from the keys dir (one per robot:
    each reloads on its own SIGHUP)."""
    cfg = load_swarm(swarm)
    from swarmd.config.auth import public_keys, retired_keys

    return {r: Keyring(public_keys(cfg), cfg.revoked, retired=retired_keys(cfg))
            for r in robots}


def _reload(rings: dict[int, Keyring], swarm: Path) -> None:
    from swarmd.config.auth import public_keys, retired_keys

    cfg = load_swarm(swarm)
    for ring in rings.values():  # `systemctl reload swarmd` on every robot
        ring.replace(public_keys(cfg), cfg.revoked, retired=retired_keys(cfg))


def test_a_rotated_witness_key_keeps_the_takeover_it_witnessed(paper: Paper,
                                                               tmp_path: Path) -> None:
    """Robot 1's key rotated by docs/operations.md's four steps, the old one retired in
    robot-1.pub; then holder 6 restarts, robot 2 comes back on its old state file, and
    robot 3 restarts with no state file at all. 6 resumes f2 at epoch 1 and every robot
    that hears f2 holds (6, 1); a frame signed with the retired key now counts for
    nothing (the keys in force decide what comes next)."""
    plan, params = paper
    swarm, keys = signed_paper(tmp_path)
    robots = sorted(plan.robots)
    rings = _keyrings(keys, swarm, robots)
    first_key = _private(keys, 1)
    signers = {r: Ed25519Signer(r, _private(keys, r)) for r in robots}
    ids = {r: Identity(signers[r], rings[r]) for r in robots}
    n = Net(plan, params, identities=ids)
    took_f2_over(n)
    snap2 = n.nodes[2].snapshot()
    old = read_public_keys(public_key_path(keys, 1))[0]
    # 1. the new pair; 2. both keys accepted everywhere; 3. robot 1 signs with the new
    # one; 4. the old one retired everywhere.
    _, new_pub = write_identity(tmp_path / "new", 1)
    pub = public_key_path(keys, 1)
    pub.write_text(pub.read_text() + new_pub.read_text())
    _reload(rings, swarm)
    signers[1].replace(_private(tmp_path / "new", 1))
    pub.write_text(new_pub.read_text() + f"retired {old.hex()}\n")
    _reload(rings, swarm)
    n.run_until(6.0)
    snap6 = n.nodes[6].snapshot()
    n.crash(6)
    n.crash(3)
    n.run_until(6.5)
    n.boot(6, restored=restored(snap6), seq_start=snap6.seq + 1000)
    n.boot(2, restored=restored(snap2), seq_start=snap2.seq + 10**6)
    n.boot(3, seq_start=10**7)  # no state file: it learns f2's holder from the swarm
    n.run_until(6.5 + 2 * params.rejoin_hold + 8 * params.t_max)
    assert holding(n) == {1: "f1", 3: "f3", 4: "f4", 6: "f2"}
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]
    assert views_of_f2(n) == {(6, 1)}
    assert n.named("alert") == []
    # What comes next: a warning signed with the retired key, heard first-hand, counts
    # for nothing (only a certificate's backers are history).
    seq = n.nodes[1].snapshot().seq + 1000
    warn = wire.Frame(plan.swarm_id, 1, seq, wire.Warn(4, plan.slot("f4"), 0))
    raw = wire.encode(warn, None, Ed25519Signer(1, first_key))
    before = n.nodes[5].drops["auth"]
    n.inject(5, n.nodes[5].receive(raw, n.now))
    assert n.nodes[5].drops["auth"] == before + 1


def _private(keys: Path, robot: int) -> bytes:
    from swarmd.base.identity import private_key_path, read_private_key

    return read_private_key(private_key_path(keys, robot))


# ------------------------------------------------------------ no proof left at all
class _Forgotten:
    """A keyring that lost robot 1's key altogether (its .pub deleted from the keys dir,
    as the guide once allowed for a revoked robot): nothing it signed verifies."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        return robot != 1 and bool(self.inner.verify(robot, data, signature,
                                                      history=history))


def test_a_hold_that_cannot_be_proven_any_more_is_taken_over_again(paper: Paper) -> None:
    """Per robot, 6's saved certificate no longer verifies at all (robot 1's key is
    gone). It cannot resume what it cannot prove, but the watchers warn about it, the
    holder they see, and as f2's standby it takes f2 over again at the next epoch:
    f2 is never left to nobody while a robot that covers it lives."""
    plan, params = paper
    ids = fake_identities(plan.robots)
    n = Net(plan, params, keys=(KEY,), identities=ids)
    took_f2_over(n)
    snap6 = n.nodes[6].snapshot()
    n.crash(6)
    n.run_until(6.0)
    n.identities[6] = Identity(ids[6].signer, _Forgotten(ids[6].verifier))
    n.boot(6, restored=restored(snap6), seq_start=snap6.seq + 1000)
    n.run_until(6.0 + params.rejoin_hold + params.takeover_bound(lossy=False) + 1.0)
    assert [(e["robot"], e["epoch"], e["replaced"]) for e in n.named("takeover")] == [
        (6, 1, 2), (6, 2, 6)]
    assert holding(n)[6] == "f2" and views_of_f2(n) == {(6, 2)}


def test_shared_key_a_restarted_holder_resumes_across_a_key_rotation(paper: Paper) -> None:
    """Shared key: nothing is verified on restore (a state file is the robot's own
    memory; there are no certificates), so a rotation of the swarm key
    (docs/operations.md, "Rotating the swarm key") changes nothing of what 6 held."""
    plan, params = paper
    n = Net(plan, params, keys=(KEY,))
    took_f2_over_shared(n)
    new = b"n" * 32
    for r in n.alive:
        n.nodes[r].set_keys((KEY, new))
    for r in n.alive:
        n.nodes[r].set_keys((new, KEY))
    for r in n.alive:
        n.nodes[r].set_keys((new,))
    n.keys = (new,)
    snap6 = n.nodes[6].snapshot()
    n.crash(6)
    n.run_until(6.0)
    n.boot(6, restored=restored(snap6), seq_start=snap6.seq + 1000)
    n.run_until(6.0 + params.rejoin_hold + 1.0)
    assert holding(n)[6] == "f2" and views_of_f2(n) == {(6, 1)}


def took_f2_over_shared(n: Net) -> None:
    n.run_until(3.0)
    n.crash(2)
    n.run_until(5.0)
    assert [(e["robot"], e["epoch"]) for e in n.named("takeover")] == [(6, 1)]


# ------------------------------------------------------------ revocation, real daemons
async def _until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        await asyncio.sleep(0.02)


@pytest.mark.slow
async def test_revoking_a_witness_keeps_the_takeover_it_witnessed_on_real_daemons(
        tmp_path: Path, udp_port: int) -> None:
    """Six `run_daemon` tasks over UDP on loopback, signed per robot, state files on
    disk. Robot 2 dies (its task is cancelled: no LEAVE), 6 takes f2 over on the
    warnings of 1 and 3; robot 1 is revoked by the guide's steps (every robot reloads;
    1 exits 3 and 5 takes f1 over). Then 6 restarts on its state file: it resumes f2 at
    epoch 1. Then robot 2 comes back on its own state file (it held f2 at epoch 0): it
    verifies 6's takeover with the keys of the time and stays a standby. Every daemon
    that hears f2 holds (6, 1); nobody alerts after 6 is back."""
    swarm, _keys = signed_paper(tmp_path)
    events: list[dict[str, Any]] = []
    daemons: dict[int, Daemon] = {}
    links = {r: NoneLink() for r in range(1, 7)}
    tasks: dict[int, asyncio.Task[int]] = {}
    stop = asyncio.Event()
    params = load_swarm(swarm).params()

    def start(r: int) -> None:
        path = tmp_path / f"robot{r}.yaml"
        path.write_text(f"robot: {r}\nswarm: {swarm}\nstate_dir: {tmp_path / 'state'}\n"
                        f"identity_file: keys/robot-{r}.key\n"
                        f"transport: {{kind: udp, port: {udp_port}}}\n")
        daemons.pop(r, None)
        tasks[r] = asyncio.create_task(run_daemon(
            load_robot(path), link=links[r], event_sink=events.append, stop_event=stop,
            config_path=path, on_ready=lambda d: daemons.__setitem__(r, d)))

    async def crash(r: int) -> None:
        tasks[r].cancel()
        with pytest.raises(asyncio.CancelledError):
            await tasks[r]

    def took(robot: int, f: str) -> bool:
        return any(e["event"] == "takeover" and (e["robot"], e["function"]) == (robot, f)
                   for e in events)

    try:
        for r in range(1, 7):
            start(r)
        await _until(lambda: len(daemons) == 6, 20.0, "six daemons ready")
        await asyncio.sleep(3 * params.startup_grace / 2)
        await crash(2)
        await _until(lambda: took(6, "f2"), 20.0, "6 takes f2 over")
        assert backers(daemons[6].runtime.snapshot()) == {1, 3}  # type: ignore[union-attr]
        swarm.write_text(paper_text("{mode: per-robot, keys_dir: keys, revoked: [1]}",
                                    swarm))
        for r in (1, 3, 4, 5, 6):
            daemons[r].reload()
        assert await asyncio.wait_for(tasks[1], 10.0) == EXIT_REVOKED
        await _until(lambda: took(5, "f1"), 20.0, "5 takes f1 over")
        await crash(6)
        assert links[6].function is None  # a crash as the daemon sees it: released
        start(6)
        await _until(lambda: links[6].function == "f2", 20.0, "6 resumes f2")
        assert links[6].epoch == 1
        # Alerts while 6 was down (and rejoining) are right: f2 had nobody then.
        await asyncio.sleep(params.t_max)
        back = len(events)
        start(2)
        await _until(lambda: 2 in daemons, 20.0, "2 ready again")

        def views() -> dict[int, tuple[int, int]]:
            return {r: tuple(daemons[r].runtime.snapshot().known["f2"])  # type: ignore
                    for r in (2, 3, 5, 6)}

        # Within the convergence bound (DESIGN, "Convergence": the holder relays its
        # certificate unasked every RELAY_EVERY T_max), plus the machine's slack.
        bound = (RELAY_EVERY + 1) * params.t_max + 2 * params.heartbeat_interval
        try:
            await _until(lambda: set(views().values()) == {(6, 1)}, bound + 5.0,
                         "every view of f2 at (6, 1)")
            assert daemons[2].runtime.snapshot().function is None  # type: ignore
            assert links[2].function is None and links[6].function == "f2"
            later = [(e["robot"], e["event"], e.get("function")) for e in events[back:]]
            assert not [e for e in later if e[1] in ("alert", "takeover", "fenced")], later
        except AssertionError:
            print([(e["robot"], e["event"], e.get("function"), e.get("epoch"),
                    e.get("reason")) for e in events])
            raise
    finally:
        stop.set()
        await asyncio.wait_for(asyncio.gather(*tasks.values(), return_exceptions=True), 30.0)
