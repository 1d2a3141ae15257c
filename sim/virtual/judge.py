"""The invariants a virtual run judges from its nodes at the end (`sim.shared.invariants`
7 and 8): what no event log shows, since a muted robot and a disagreeing view log
nothing. `VirtualSwarm.run` calls them after the checker has read the log.

The judge reads a finished run through `FinishedRun`, the part of the simulator's state
it needs: the simulator imports the judge, never the other way round."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol

from sim.shared.channel import LinkCut
from sim.shared.faults import Fault
from sim.shared.invariants import Checker, Violation
from swarmd.core.node import Node
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.records import Snapshot
from swarmd.core.roles import Health, Role


class RobotAtEnd(Protocol):
    """One robot of the run: its node, unless it is down (crashed or paused)."""

    @property
    def node(self) -> Node | None: ...
    @property
    def alive(self) -> bool: ...
    @property
    def paused(self) -> bool: ...


class ChannelOfRun(Protocol):
    """The run's medium, as far as the loss it made excuses silence."""

    @property
    def loss(self) -> float: ...
    @property
    def loss_model(self) -> str: ...
    @property
    def burst_len(self) -> float: ...


class FinishedRun(Protocol):
    """What the judge reads of a virtual run at its end (`VirtualSwarm` is one)."""

    @property
    def plan(self) -> SwarmPlan: ...
    @property
    def params(self) -> Params: ...
    @property
    def duration(self) -> float: ...
    @property
    def faults(self) -> Sequence[Fault]: ...
    @property
    def channel(self) -> ChannelOfRun: ...
    @property
    def robots(self) -> Mapping[int, RobotAtEnd]: ...
    @property
    def partition(self) -> Mapping[int, int] | None: ...
    @property
    def cuts_seen(self) -> Sequence[LinkCut]: ...
    @property
    def checker(self) -> Checker: ...

    def audience(self, sender: int, slot: int) -> tuple[int, ...]: ...

    def last_arrival(self, sender: int, receiver: int) -> float | None: ...

    def checker_last_change(self, rid: int) -> float: ...


def muted(swarm: FinishedRun) -> list[Violation]:
    """Invariant 7 (`sim.shared.invariants`): a live, healthy, heartbeating robot
    whose current heartbeats some robot that should hear them (same partition side,
    the frame relevant to it) has not accepted for ten heartbeat periods, although
    it did accept that robot's frames before: its frames are dropped (a forged
    sequence number, say). Not when none of them reached it since: the channel lost
    them all (at 29 % loss ten in a row happen once in half a million windows)."""
    out: list[Violation] = []
    snaps = {rid: r.node.snapshot() for rid, r in swarm.robots.items()
             if r.alive and not r.paused and r.node is not None}
    part = swarm.partition
    for x, sx in snaps.items():
        if sx.health != Health.OK:
            continue
        active = sx.role == Role.ACTIVE and sx.function is not None
        period = swarm.params.heartbeat_interval if active else \
            swarm.params.standby_heartbeat_interval
        # A bursty channel loses whole runs of frames (mean `burst_len`): silence of
        # a few bursts is the channel, not a muted robot.
        bursty = swarm.channel.loss_model == "burst" and swarm.channel.loss > 0
        window = max(10.0, 16 * swarm.channel.burst_len if bursty else 0.0) * period
        slot = swarm.plan.slot(sx.function) if active and sx.function is not None else 0
        audience = swarm.audience(x, slot)
        for r in audience:
            sr = snaps.get(r)
            if sr is None or r == x or (part is not None and part.get(r, 0) != part.get(x, 0)):
                continue
            if any(c.cuts(x, r, c.start) and c.end > swarm.duration - window
                   for c in swarm.cuts_seen):
                continue  # cut off from x lately: not muted, unheard
            last = sr.heard.get(x)
            arrived = swarm.last_arrival(x, r)
            if last is not None and arrived is not None and arrived <= last:
                continue  # nothing of x reached r since: the channel's loss, no drop
            if last is not None and swarm.duration - last > window \
                    and swarm.duration - swarm.checker_last_change(x) > window:
                out.append(Violation(swarm.duration, "muted", x,
                                     f"robot {r} has accepted no frame of live robot {x} "
                                     f"since {last:.2f} s"))
                break
    return out


def views(swarm: FinishedRun) -> list[Violation]:
    """Invariant 8 (`sim.shared.invariants`): at the end of a run that has been quiet
    for `Bounds.settle`, every live robot that hears a slot holds one view of it
    (`views_disagree`), and a live, healthy holder they all name executes it
    (`orphaned`)."""
    last = max((f.end if f.end is not None else f.at for f in swarm.faults), default=0.0)
    if swarm.duration - last < swarm.checker.bounds.settle:
        return []
    snaps = {rid: r.node.snapshot() for rid, r in swarm.robots.items()
             if r.alive and not r.paused and r.node is not None}
    return view_violations(swarm.plan, snaps, swarm.duration)


def view_violations(plan: SwarmPlan, snaps: Mapping[int, Snapshot],
                    t: float) -> list[Violation]:
    """Invariant 8 on the snapshots of the live robots at a quiet moment `t` (also what
    the explorer, `sim.virtual.explore`, judges its final states by): one view of each
    slot among the robots that hear it, and the live, healthy holder it names executes
    it."""
    # A robot that reported itself faulty has left the protocol (rule 7): it hears
    # and heartbeats nothing that matters, so its view is nobody's business.
    snaps = {rid: sx for rid, sx in snaps.items() if sx.health != Health.FAULTY}
    out: list[Violation] = []
    for f in plan.functions:
        slot = plan.slot(f)
        seen = {rid: sx.known[f] for rid, sx in snaps.items()
                if slot in plan.relevant(rid).slots or sx.function == f}
        named = {h[0] for h in seen.values()}
        executing = {rid for rid, sx in snaps.items()
                     if sx.role == Role.ACTIVE and sx.function == f}
        if len(set(seen.values())) > 1 and (named & set(snaps) or executing):
            # (Views that all name dead robots are an unheld slot: invariant 1 and
            # rule 8's alert judge it.)
            shown = ", ".join(f"{r}: {h[0]}@{h[1]}" for r, h in sorted(seen.items()))
            out.append(Violation(t, "views_disagree", None,
                                 f"{f} is held by different robots in different views "
                                 f"({shown})"))
            continue
        if not seen:
            continue
        holder = next(iter(seen.values()))[0]
        sh = snaps.get(holder)
        if sh is not None and sh.health == Health.OK and not (
                sh.role == Role.ACTIVE and sh.function == f):
            out.append(Violation(t, "orphaned", holder,
                                 f"every view names robot {holder} the holder of {f}, "
                                 f"which it does not execute"))
    return out


__all__ = ["FinishedRun", "muted", "view_violations", "views"]
