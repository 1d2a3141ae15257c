"""swarmd.core.limits: the range check a node applies to restored state at construction."""

from __future__ import annotations

import pytest

from swarmd.core.limits import EPOCH_MAX, ROBOT_MAX, check_restored, restored_problems
from swarmd.core.node import NodeError, Restored
from swarmd.core.wire import SEQ_MAX


def test_in_range_restored_state_passes() -> None:
    # holder 0: nobody; f9: a function a later swarm file dropped (the node ignores it)
    known = {"f1": (1, 0), "f2": (ROBOT_MAX, EPOCH_MAX), "f3": (0, 3), "f9": (2, 4)}
    assert restored_problems(known, ("f2", EPOCH_MAX), SEQ_MAX) == []
    check_restored(Restored(known, ("f2", EPOCH_MAX)), SEQ_MAX)  # no raise
    check_restored(None, 0)


@pytest.mark.parametrize(("known", "held", "seq", "message"), [
    ({}, ("f2", 70000), 0, "held epoch 70000 is not in 0..65535"),
    ({"f2": (2, 70000)}, None, 0, "known['f2'] epoch 70000 is not in 0..65535"),
    ({"f2": (2, -1)}, None, 0, "epoch -1"),
    ({"f2": (2, True)}, None, 0, "epoch True"),
    ({"f2": (70000, 1)}, None, 0, "holder 70000 is not in 0..65535"),
    ({"f2": (2, 1, 3)}, None, 0, "is not (holder, epoch)"),
    ({}, ("f2",), 0, "is not (function, epoch)"),
    ({}, None, SEQ_MAX + 1, "is not in 0..281474976710655 (48 bits)"),
    ({}, None, -5, "sequence number -5"),
])
def test_out_of_range_restored_state_raises_node_error(
        known: dict[str, tuple[int, int]], held: tuple[str, int] | None, seq: int,
        message: str) -> None:
    assert any(message in p for p in restored_problems(known, held, seq))
    with pytest.raises(NodeError, match="restored state out of range") as info:
        check_restored(Restored(known, held), seq)
    assert message in str(info.value)


def test_every_problem_is_named_once() -> None:
    problems = restored_problems({"f1": (1 << 17, 70000)}, ("f2", 1 << 20), 1 << 60)
    assert len(problems) == 4
