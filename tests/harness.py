"""A small in-memory network of core nodes on virtual time (h11's ConnectionPair, for N).

For node-level tests that need a few robots talking but not the full simulator
(`sim.virtual.simulator`): every broadcast goes through `Net.deliver` to all other live nodes
after `delay`, dropped with probability `loss` by a seeded `random.Random`, so a test
is a pure function of its seed (no sleeps, virtual time only).
"""

from __future__ import annotations

import heapq
import itertools
import random
import socket
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from sim.shared.fakeid import fake_identities
from swarmd.core import wire
from swarmd.core.actions import Action, Assign, Broadcast, Release
from swarmd.core.auth import Identity
from swarmd.core.events import Event
from swarmd.core.node import Node, Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan


@dataclass(slots=True)
class Net:
    """N nodes on one virtual clock. Drive it with `run_until(t)`."""

    plan: SwarmPlan
    params: Params
    ids: Sequence[int] = ()
    loss: float = 0.0
    seed: int = 0
    delay: float = 0.001
    keys: Sequence[bytes] = ()
    identities: dict[int, Identity] = field(default_factory=dict)
    """Per-robot mode: each robot's identity (`sim.shared.fakeid.fake_identities`)."""
    cuts: list[tuple[int | None, int | None, float, float]] = field(default_factory=list)
    """Link faults: (sender, receiver, from, until): frames from `sender` (None: any) to
    `receiver` (None: any) sent in [from, until) are lost. A fade of R is (R, None, ..),
    R deaf to S is (S, R, ..): one way only."""
    now: float = 0.0
    nodes: dict[int, Node] = field(default_factory=dict)
    alive: set[int] = field(default_factory=set)
    events: list[dict[str, Any]] = field(default_factory=list)
    outputs: dict[int, list[Assign | Release]] = field(default_factory=dict)
    frames: list[tuple[float, int, bytes]] = field(default_factory=list)
    """Every broadcast: (time, sender, frame bytes)."""
    _rng: random.Random = field(init=False)
    _queue: list[tuple[float, int, int, bytes]] = field(default_factory=list)
    _order: itertools.count[int] = field(default_factory=itertools.count)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)
        for rid in self.ids or sorted(self.plan.robots):
            self.boot(rid)

    # -- topology ----------------------------------------------------------------------
    def boot(self, rid: int, restored: Restored | None = None, seq_start: int = 0) -> Node:
        """Start (or restart) robot `rid` now and run its start-up tick."""
        node = Node(rid, self.plan, self.params, self.now, keys=self.keys,
                    identity=self.identities.get(rid), seq_start=seq_start,
                    restored=restored)
        self.nodes[rid] = node
        self.alive.add(rid)
        self.outputs.setdefault(rid, [])
        self._execute(rid, node.tick(self.now))
        return node

    def crash(self, rid: int) -> None:
        """The robot vanishes: no more ticks, frames to it are lost."""
        self.alive.discard(rid)

    def inject(self, rid: int, actions: Iterable[Action]) -> None:
        """Execute actions a test obtained by calling a node directly."""
        self._execute(rid, list(actions))

    # -- clock -------------------------------------------------------------------------
    def run_until(self, t: float) -> None:
        """Advance virtual time to `t`, firing deliveries and deadlines in order."""
        while True:
            nxt, rid = self._next_timer()
            q = self._queue[0][0] if self._queue else None
            if q is not None and q <= t and (nxt is None or q <= nxt):
                at, _, dst, data = heapq.heappop(self._queue)
                self.now = at
                if dst in self.alive:
                    self._execute(dst, self.nodes[dst].receive(data, at))
            elif nxt is not None and nxt <= t:
                assert rid is not None
                self.now = max(self.now, nxt)
                self._execute(rid, self.nodes[rid].tick(self.now))
            else:
                break
        self.now = max(self.now, t)

    def _next_timer(self) -> tuple[float | None, int | None]:
        best: tuple[float | None, int | None] = (None, None)
        for rid in sorted(self.alive):
            d = self.nodes[rid].next_deadline()
            if d is not None and (best[0] is None or d < best[0]):
                best = (d, rid)
        return best

    # -- actions -----------------------------------------------------------------------
    def _execute(self, rid: int, actions: list[Action]) -> None:
        for a in actions:
            match a:
                case Broadcast(frame):
                    self.frames.append((self.now, rid, frame))
                    for dst in sorted(self.alive):
                        if dst == rid or (self.loss and self._rng.random() < self.loss) \
                                or self._cut(rid, dst):
                            continue
                        heapq.heappush(self._queue,
                                       (self.now + self.delay, next(self._order), dst, frame))
                case Event() as ev:
                    self.events.append(ev.record(self.now, rid))
                case Assign() | Release():
                    self.outputs[rid].append(a)

    def _cut(self, src: int, dst: int) -> bool:
        return any((s is None or s == src) and (d is None or d == dst) and a <= self.now < b
                   for s, d, a, b in self.cuts)

    # -- queries -----------------------------------------------------------------------
    def executing(self) -> dict[int, str]:
        """Robot -> the function it executes now (its last Assign not yet Released), of
        the live robots."""
        out: dict[int, str] = {}
        for rid in sorted(self.alive):
            last = self.outputs[rid][-1] if self.outputs[rid] else None
            if isinstance(last, Assign):
                out[rid] = last.function
        return out

    def named(self, name: str, robot: int | None = None) -> list[dict[str, Any]]:
        """Events called `name` (of one robot, if given), in order."""
        return [e for e in self.events
                if e["event"] == name and (robot is None or e["robot"] == robot)]


def signed_beat(identity: Identity | None, swarm_id: int, sender: int, seq: int,
                slot: int, epoch: int, role: int = 1, *, key: bytes | None = None,
                link: bytes = bytes(8), n: int = 0) -> bytes:
    """A heartbeat of `sender` as its own radio sends it in per-robot mode: an anchor
    (signed with `identity`, the sender's own) carrying `link` as its chain position.
    With `identity` None, the frame a forger without the sender's key can make: the
    same link, unsigned (swarm key tag if `key`)."""
    hb = wire.Heartbeat(slot, epoch, role, 0, n, link, anchor=identity is not None)
    signer = identity.signer if identity is not None else _NoSigner(sender)
    return wire.encode(wire.Frame(swarm_id, sender, seq, hb), key, signer)


class _NoSigner:
    """Makes `wire.encode` lay a heartbeat out as per-robot mode does; never signs."""

    def __init__(self, robot: int) -> None:
        self.robot = robot

    def sign(self, data: bytes) -> bytes:
        raise AssertionError("an unsigned per-robot heartbeat is never signed")


MODE_KEY = bytes(32)
"""The swarm key of `Radio`'s frames with a shared key, and alongside a signature per robot."""


class Radio:
    """Frames of a swarm's robots as each auth mode sends them (with a key: `MODE_KEY`;
    per robot: fake identities), and nodes that hear them."""

    def __init__(self, plan: SwarmPlan, params: Params, mode: str) -> None:
        self.plan, self.params, self.mode = plan, params, mode
        self.keys = (MODE_KEY,) if mode != "none" else ()
        self.ids = fake_identities(plan.robots) if mode == "per-robot" else {}
        self.seq = 1000

    def node(self, rid: int) -> Node:
        node = Node(rid, self.plan, self.params, 0.0, keys=self.keys,
                    identity=self.ids.get(rid))
        node.tick(0.0)
        return node

    def _next(self) -> int:
        self.seq += 1
        return self.seq

    def beat(self, sender: int, f: str) -> bytes:
        """`sender`'s heartbeat as holder of f at epoch 0 (per robot: an anchor)."""
        slot, key = self.plan.slot(f), MODE_KEY if self.keys else None
        if self.mode == "per-robot":
            return signed_beat(self.ids[sender], self.plan.swarm_id, sender, self._next(),
                               slot, 0, key=key)
        return wire.encode(wire.Frame(self.plan.swarm_id, sender, self._next(),
                                      wire.Heartbeat(slot, 0, 1, 0)), key)

    def warn(self, sender: int, suspect: int, f: str, belief: int) -> bytes:
        msg = wire.Warn(suspect, self.plan.slot(f), 0, belief)
        signer = self.ids[sender].signer if self.mode == "per-robot" else None
        return wire.encode(wire.Frame(self.plan.swarm_id, sender, self._next(), msg),
                           MODE_KEY if self.keys else None, signer)


def send_to_group(group: str, port: int, frame: bytes) -> None:
    """`frame` to the multicast group from a socket of its own, on loopback with TTL 1:
    another daemon on this host (a neighbour, or one started with our robot id)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        s.sendto(frame, (group, port))
