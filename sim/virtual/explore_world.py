"""One state of the explorer (`sim.virtual.explore`): real protocol nodes on a step clock.

A `World` is the swarm at one step: the live `Node`s (the same objects the daemon
drives, reached only through their public entry points), the frames in flight to each
receiver, the scripted faults and the checker that reads the event log. Time is
discrete: step k is `k * dt`; in a step the frames due are delivered (each one, at a
choice point, may instead be dropped, duplicated or held back a step, which reorders
it after the next step's frames), then every node whose deadline is due ticks, robots
in id order. What a node broadcasts reaches every other robot the next step, unless a
one-way cut (`sim.shared.channel.LinkCut`) in force drops it. So a run is a pure
function of the script and the choices made, and a `World` can be copied
(`World.freeze`, `World.thaw`: a pickle that shares the keys, Ed25519 ones
included) to try each choice from one state.
"""

from __future__ import annotations

import hashlib
import io
import pickle
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from sim.shared.channel import LinkCut
from sim.shared.faults import Fault, FaultKind, fault_record
from sim.shared.invariants import Bounds, Checker, Violation
from swarmd.core import wire
from swarmd.core.actions import Action, Broadcast
from swarmd.core.auth import Identity
from swarmd.core.events import Event
from swarmd.core.node import Node, Restored
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Role

NodeFactory = Callable[..., Node]
"""Builds a node with `Node`'s signature: `Node` itself, or a test's wrapped node."""
PERTURB = ("drop", "dup", "delay")
"""What a choice point may do to one delivery instead of delivering it."""


@dataclass(frozen=True, slots=True)
class Choice:
    """One perturbed delivery: at step `step`, the `index`-th frame due is `what`."""

    step: int
    index: int
    what: str
    t: float = 0.0
    sender: int = 0
    receiver: int = 0
    frame: str = ""

    def describe(self) -> str:
        return f"t={self.t:.2f} {self.what} {self.frame} {self.sender}->{self.receiver}"


@dataclass(frozen=True, slots=True)
class Script:
    """A configuration: the swarm, its mode, the scripted faults and the search bounds."""

    name: str
    plan: SwarmPlan
    params: Params
    faults: tuple[Fault, ...]
    horizon: float
    windows: tuple[tuple[float, float], ...]
    """Choice points only at steps in one of these [start, end] (seconds)."""
    dt: float = 0.1


@dataclass(frozen=True, slots=True)
class _Flight:
    due: int
    sender: int
    receiver: int
    data: bytes


@dataclass(slots=True)
class World:
    script: Script
    keys: tuple[bytes, ...]
    identities: dict[int, Identity]
    factory: NodeFactory
    step: int = 0
    nodes: dict[int, Node] = field(default_factory=dict)
    persisted: dict[int, tuple[Restored, int]] = field(default_factory=dict)
    flights: list[_Flight] = field(default_factory=list)
    cuts: list[LinkCut] = field(default_factory=list)
    checker: Checker | None = None
    history: list[str] = field(default_factory=list)
    """The events logged so far, without their times (part of the state's identity)."""
    events: list[dict[str, Any]] = field(default_factory=list)
    choices: list[Choice] = field(default_factory=list)
    regressions: list[Violation] = field(default_factory=list)
    _views: dict[tuple[int, str], tuple[int, int]] = field(default_factory=dict)

    @classmethod
    def start(cls, script: Script, *, keys: Sequence[bytes] = (),
              identities: dict[int, Identity] | None = None,
              factory: NodeFactory = Node) -> World:
        w = cls(script, tuple(keys), dict(identities or {}), factory)
        w.checker = Checker(script.plan, script.params)
        for rid in sorted(script.plan.robots):
            w.nodes[rid] = w._node(rid, 0.0, None, 0)
        return w

    def _node(self, rid: int, now: float, restored: Restored | None, seq: int) -> Node:
        return self.factory(rid, self.script.plan, self.script.params, now, keys=self.keys,
                            identity=self.identities.get(rid), seq_start=seq,
                            restored=restored)

    # ------------------------------------------------------------------ reading
    @property
    def now(self) -> float:
        return round(self.step * self.script.dt, 6)

    @property
    def last_step(self) -> int:
        return round(self.script.horizon / self.script.dt)

    def due(self) -> list[_Flight]:
        """The frames to deliver this step, in the order they are delivered."""
        return [f for f in self.flights if f.due == self.step]

    def choosable(self) -> bool:
        return any(lo <= self.now <= hi for lo, hi in self.script.windows)

    def key(self) -> str:
        """What identifies this state for de-duplication: every node's snapshot (without
        its counters and frame times) and next deadline, the frames in flight and the
        event history. Hidden node state (a watchdog's phase, a chain's position) is
        not in it, so two states may share a key and differ there: the search is
        bounded, not complete (docs/testing.md, "The explorer")."""
        h = hashlib.blake2b(digest_size=16)
        for rid, node in sorted(self.nodes.items()):
            s = node.snapshot()
            h.update(repr((rid, s.role, s.function, s.epoch, s.health, sorted(s.known.items()),
                           sorted(s.suspects.items()), sorted(s.votes.items()),
                           node.next_deadline())).encode())
        for fl in self.flights:
            h.update(repr((fl.due - self.step, fl.sender, fl.receiver)).encode() + fl.data)
        h.update("|".join(self.history).encode())
        return h.hexdigest()

    def executors(self) -> dict[str, list[int]]:
        out: dict[str, list[int]] = {}
        for rid, node in sorted(self.nodes.items()):
            s = node.snapshot()
            if s.role == Role.ACTIVE and s.function is not None:
                out.setdefault(s.function, []).append(rid)
        return out

    def _shared(self) -> list[object]:
        """What no step changes (the script, plan, params, keys and identities): shared
        between a state and its copies, never copied (Ed25519 keys do not pickle)."""
        out: list[object] = [self.script, self.script.plan, self.script.params,
                             self.factory, self.keys, self.identities]
        for ident in self.identities.values():
            out += [ident, ident.signer, ident.verifier]
        return out

    def freeze(self) -> bytes:
        """This state as bytes, to try several choices from (`thaw`): a pickle with the
        shared objects left out, about twice as fast as `copy.deepcopy`."""
        buf = io.BytesIO()
        _Pickler(buf, self._shared()).dump(self)
        return buf.getvalue()

    def thaw(self, blob: bytes) -> World:
        """A copy of the state `freeze` gave, sharing this one's unchanging objects."""
        world = _Unpickler(io.BytesIO(blob), self._shared()).load()
        assert isinstance(world, World)
        return world

    # ------------------------------------------------------------------ one step
    def advance(self, choice: Choice | None = None) -> None:
        """One step: faults due, then deliveries (one perturbed by `choice`), then ticks."""
        now = self.now
        self._faults(now)
        due = self.due()
        self.flights = [f for f in self.flights if f.due != self.step]
        for i, fl in enumerate(due):
            what = choice.what if choice is not None and choice.index == i else "deliver"
            if what != "deliver":
                self._perturbed(choice, fl, now)  # type: ignore[arg-type]
            if what == "delay":
                self.flights.append(_Flight(self.step + 1, fl.sender, fl.receiver, fl.data))
            if what in ("deliver", "dup"):
                self._deliver(fl, now)
            if what == "dup":
                self._deliver(fl, now)
        for rid in sorted(self.nodes):
            node = self.nodes.get(rid)
            deadline = node.next_deadline() if node is not None else None
            if node is not None and deadline is not None and deadline <= now:
                self._run(rid, node.tick(now))
                self._watch_views(rid, node, now)
        self.step += 1

    def _perturbed(self, choice: Choice, fl: _Flight, now: float) -> None:
        if not self.choices:  # the channel lost, doubled or reordered a frame: judged
            assert self.checker is not None  # as a lossy run from here (invariant 2)
            self.checker.loss = 0.01
            self.checker.bounds = Bounds.of(self.script.params, 0.01)
        self.choices.append(Choice(self.step, choice.index, choice.what, now, fl.sender,
                                   fl.receiver, _describe(fl.data, self.keys, self.script)))

    def _deliver(self, fl: _Flight, now: float) -> None:
        node = self.nodes.get(fl.receiver)
        if node is None or any(c.cuts(fl.sender, fl.receiver, now) for c in self.cuts):
            return
        self._run(fl.receiver, node.receive(fl.data, now))
        self._watch_views(fl.receiver, node, now)

    def _run(self, rid: int, actions: list[Action]) -> None:
        assert self.checker is not None
        for action in actions:
            if isinstance(action, Broadcast):
                for other in self._audience(rid, action.frame):
                    self.flights.append(_Flight(self.step + 1, rid, other, action.frame))
            elif isinstance(action, Event):
                rec = action.record(self.now, rid)
                self.events.append(rec)
                self.history.append(f"{rid}:{rec['event']}:{rec.get('function')}")
                self.checker.event(rec)

    def _audience(self, sender: int, data: bytes) -> list[int]:
        """Who a broadcast matters to, by the plan (`SwarmPlan.relevant`, the sets a node
        drops irrelevant frames by, as `sim.virtual.simulator` delivers with `interest`):
        a frame anyone else would drop unread is no choice worth trying."""
        plan = self.script.plan
        head = wire.peek(data)
        others = [r for r in sorted(plan.robots) if r != sender]
        if head is None:
            return others
        if head.slot == 0 and head.mtype == wire.MsgType.HEARTBEAT:
            return [r for r in others if sender in plan.relevant(r).standbys]
        return [r for r in others if head.slot in plan.relevant(r).slots or head.robot == r]

    def _watch_views(self, rid: int, node: Node, now: float) -> None:
        """A robot's view of a slot only moves forward: to a higher epoch, or at one
        epoch to the lower robot id (DESIGN rule 2's tie-break). Judged after every
        frame and tick, a step back is recorded (`view_regressed`), once a robot and
        slot."""
        for f, (holder, epoch) in node.snapshot().known.items():
            before = self._views.get((rid, f))
            self._views[(rid, f)] = (holder, epoch)
            if before is not None and _rank(holder, epoch) < _rank(*before) and not any(
                    v.robot == rid and f in v.detail for v in self.regressions):
                self.regressions.append(Violation(
                    now, "view_regressed", rid,
                    f"robot {rid}'s view of {f} went back from {before[0]}@{before[1]} "
                    f"to {holder}@{epoch}"))

    # ------------------------------------------------------------------ faults
    def _faults(self, now: float) -> None:
        assert self.checker is not None
        # A fault on several robots is one fault a robot at the same instant.
        for fault in (part for f in self.script.faults for part in f.split()):
            for phase, at in (("begin", fault.at), ("end", fault.end)):
                if at is not None and round(at / self.script.dt) == self.step:
                    if phase == "begin":
                        rec = fault_record(fault, now)
                        self.events.append(rec)
                        self.checker.event(rec)
                    self.checker.fault(now, fault, phase)
                    self._apply(fault, phase, now)

    def _apply(self, fault: Fault, phase: str, now: float) -> None:
        for cut in _cuts_of(fault):
            if phase == "begin":
                self.cuts.append(cut)
            elif cut in self.cuts:
                self.cuts.remove(cut)
        if fault.kind not in (FaultKind.PARTITION, FaultKind.FADE, FaultKind.DEAF):
            self._robot_fault(fault, now)

    def _robot_fault(self, fault: Fault, now: float) -> None:
        rid = fault.robot
        node = self.nodes.get(rid)
        if fault.kind in (FaultKind.CRASH, FaultKind.COLLIDE, FaultKind.RESTART) \
                and node is not None:
            self._persist(rid, node, left=False)
            del self.nodes[rid]
        elif fault.kind is FaultKind.LEAVE and node is not None:
            self._run(rid, node.stop(now, handover=True))
            self._persist(rid, node, left=True)
            del self.nodes[rid]
        if fault.kind is FaultKind.RESTART:
            restored, seq = self.persisted.get(rid, (Restored(), 0))
            # Above what it sent before, as the daemon's state file keeps it (the
            # replay window of DESIGN section 2, "Sequence numbers"); wiped, as at a
            # first start, its seq from the wall clock is above it all the same.
            self.nodes[rid] = self._node(rid, now, None if fault.wiped else restored,
                                         seq + 1_000_000)
            for key in [k for k in self._views if k[0] == rid]:
                del self._views[key]  # a new node: its file's views are judged on restore

    def _persist(self, rid: int, node: Node, *, left: bool) -> None:
        """What the robot's state file holds when it stops (as `sim.virtual.simulator`)."""
        s = node.snapshot()
        held = (s.function, s.epoch) if s.function and not left and s.role == Role.ACTIVE \
            else None
        self.persisted[rid] = (Restored(known=dict(s.known), held=held,
                                        peer_seq=dict(s.peer_seq),
                                        certificate=s.certificate if held else ()), s.seq)

    # ------------------------------------------------------------------ the end
    def finish(self) -> list[Violation]:
        """Every violation of the run that ends here (call at `last_step`)."""
        from sim.virtual.judge import view_violations

        assert self.checker is not None
        out = self.checker.finish(self.events, self.now) + self.regressions
        snaps = {rid: n.snapshot() for rid, n in self.nodes.items()}
        last = max((f.end if f.end is not None else f.at) for f in self.script.faults)
        if self.now - last >= self.checker.bounds.settle:
            out += view_violations(self.script.plan, snaps, self.now)
        return out


class _Pickler(pickle.Pickler):
    def __init__(self, buf: io.BytesIO, shared: list[object]) -> None:
        super().__init__(buf, protocol=pickle.HIGHEST_PROTOCOL)
        self._ids = {id(x): i for i, x in enumerate(shared)}

    def persistent_id(self, obj: object) -> int | None:
        return self._ids.get(id(obj))


class _Unpickler(pickle.Unpickler):
    def __init__(self, buf: io.BytesIO, shared: list[object]) -> None:
        super().__init__(buf)
        self._shared = shared

    def persistent_load(self, pid: Any) -> object:
        return self._shared[pid]


def _rank(holder: int, epoch: int) -> tuple[int, int, int]:
    """The order of views: epoch first, then any holder above nobody (robot 0), then
    the lower id (DESIGN rule 2)."""
    return (epoch, 1 if holder else 0, -holder)


def _cuts_of(fault: Fault) -> list[LinkCut]:
    """A link fault as one-way cuts: a two-way partition is one cut each way between
    every two of its groups, so partitions and cuts may overlap freely."""
    end = fault.end or fault.at
    one = fault.cut()
    if one is not None:
        return [LinkCut(fault.at, end, *one)]
    if fault.kind is not FaultKind.PARTITION:
        return []
    return [LinkCut(fault.at, end, frozenset(a), frozenset(b))
            for a in fault.groups for b in fault.groups if a != b]


def _describe(data: bytes, keys: tuple[bytes, ...], script: Script) -> str:
    """A frame, readably: its type and fields (`HEARTBEAT(f1, epoch 0)`)."""
    peek = wire.peek(data)
    if peek is None:
        return "garbage"
    name = script.plan.function_at(peek.slot) if peek.slot else None
    return f"{wire.MsgType(peek.mtype).name}({name or 'standby'} from {peek.sender})"


__all__ = ["PERTURB", "Choice", "NodeFactory", "Script", "World"]
