"""sim.shared.liar: whom the `liar` fault accuses, the one rule both simulators follow."""

from __future__ import annotations

import dataclasses

from sim.shared.liar import liar_warnings
from swarmd.core import wire
from swarmd.core.node import Node, Snapshot
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan


def _snap(plan: SwarmPlan, params: Params, robot: int,
          known: dict[str, tuple[int, int]]) -> Snapshot:
    return dataclasses.replace(Node(robot, plan, params, 0.0).snapshot(), known=known)


def test_a_holder_accuses_the_holders_of_the_slots_it_watches(
        paper: tuple[SwarmPlan, Params]) -> None:
    plan, params = paper
    # Robot 1 holds f1, which watches f2 and f4 (the paper's ring).
    snap = _snap(plan, params, 1, {"f1": (1, 1), "f2": (2, 3), "f3": (3, 1), "f4": (4, 2)})
    assert liar_warnings(plan, snap) == [
        wire.Warn(suspect=2, function=2, epoch=3), wire.Warn(suspect=4, function=4, epoch=2)]


def test_a_standby_accuses_every_holder_but_never_a_vacant_slot_or_itself(
        paper: tuple[SwarmPlan, Params]) -> None:
    plan, params = paper
    # Robot 5 is a standby; f2 is vacant (holder 0: nobody to accuse); f4 is held by 5.
    snap = _snap(plan, params, 5, {"f1": (1, 1), "f2": (0, 4), "f3": (3, 1), "f4": (5, 2)})
    assert liar_warnings(plan, snap) == [
        wire.Warn(suspect=1, function=1, epoch=1), wire.Warn(suspect=3, function=3, epoch=1)]
