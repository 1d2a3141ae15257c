"""The invariants a virtual run judges from its nodes at the end (`sim.shared.invariants`
7 and 8): what no event log shows, since a muted robot and a disagreeing view log
nothing. `VirtualSwarm.run` calls them after the checker has read the log."""

from __future__ import annotations

from typing import TYPE_CHECKING

from sim.shared.invariants import Violation
from swarmd.core.roles import Health, Role

if TYPE_CHECKING:
    from sim.virtual.simulator import VirtualSwarm


def muted(swarm: VirtualSwarm) -> list[Violation]:
    """Invariant 7 (`sim.shared.invariants`): a live, healthy, heartbeating robot
    whose current heartbeats some robot that should hear them (same partition side,
    the frame relevant to it) has not accepted for ten heartbeat periods, although
    it did accept that robot's frames before: its frames are dropped (a forged
    sequence number, say)."""
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
            if last is not None and swarm.duration - last > window \
                    and swarm.duration - swarm.checker_last_change(x) > window:
                out.append(Violation(swarm.duration, "muted", x,
                                     f"robot {r} has accepted no frame of live robot {x} "
                                     f"since {last:.2f} s"))
                break
    return out


def views(swarm: VirtualSwarm) -> list[Violation]:
    """Invariant 8 (`sim.shared.invariants`): at the end of a run that has been quiet
    for `Bounds.settle`, every live robot that hears a slot holds one view of it
    (`views_disagree`), and a live, healthy holder they all name executes it
    (`orphaned`)."""
    last = max((f.end if f.end is not None else f.at for f in swarm.faults), default=0.0)
    if swarm.duration - last < swarm.checker.bounds.settle:
        return []
    snaps = {rid: r.node.snapshot() for rid, r in swarm.robots.items()
             if r.alive and not r.paused and r.node is not None}
    # A robot that reported itself faulty has left the protocol (rule 7): it hears
    # and heartbeats nothing that matters, so its view is nobody's business.
    snaps = {rid: sx for rid, sx in snaps.items() if sx.health != Health.FAULTY}
    out: list[Violation] = []
    for f in swarm.plan.functions:
        slot = swarm.plan.slot(f)
        seen = {rid: sx.known[f] for rid, sx in snaps.items()
                if slot in swarm.plan.relevant(rid).slots or sx.function == f}
        named = {h[0] for h in seen.values()}
        executing = {rid for rid, sx in snaps.items()
                     if sx.role == Role.ACTIVE and sx.function == f}
        if len(set(seen.values())) > 1 and (named & set(snaps) or executing):
            # (Views that all name dead robots are an unheld slot: invariant 1 and
            # rule 8's alert judge it.)
            shown = ", ".join(f"{r}: {h[0]}@{h[1]}" for r, h in sorted(seen.items()))
            out.append(Violation(swarm.duration, "views_disagree", None,
                                 f"{f} is held by different robots in different views "
                                 f"({shown})"))
            continue
        if not seen:
            continue
        holder = next(iter(seen.values()))[0]
        sh = snaps.get(holder)
        if sh is not None and sh.health == Health.OK and not (
                sh.role == Role.ACTIVE and sh.function == f):
            out.append(Violation(swarm.duration, "orphaned", holder,
                                 f"every view names robot {holder} the holder of {f}, "
                                 f"which it does not execute"))
    return out


__all__ = ["muted", "views"]
