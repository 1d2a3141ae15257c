"""Whom the `liar:R@T` fault accuses: one definition for both simulators.

A liar forges WARN frames (paper section III-B) about the holders of the slots its own
slot watches, or, when it holds no slot, about the holder of every slot it knows. It
never accuses itself, and never a vacant slot: holder 0 in `Snapshot.known` means "no
robot holds it" (robot ids start at 1), so a WARN naming robot 0 would accuse nobody.
The point of the fault is that one witness, however loud, never makes a quorum of
*distinct* witnesses (DESIGN rule 3); the invariant checker then expects no takeover of
a healthy robot.
"""

from __future__ import annotations

from swarmd.core import wire
from swarmd.core.node import Snapshot
from swarmd.core.plan import SwarmPlan


def liar_warnings(plan: SwarmPlan, snap: Snapshot) -> list[wire.Warn]:
    """The WARN frames a liar whose node is in state `snap` sends in one warn interval,
    in plan order."""
    functions = (plan.watched(snap.function) if snap.function is not None
                 else plan.functions)
    out = []
    for f in functions:
        holder, epoch = snap.known.get(f, (0, 0))
        if holder and holder != snap.robot_id:
            out.append(wire.Warn(suspect=holder, function=plan.slot(f), epoch=epoch))
    return out
