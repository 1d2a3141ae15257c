"""The explorer (sim/virtual/explore.py): every interleaving of a small swarm's frames
near its faults, on the real protocol core, in each auth mode; and it catches a
deliberately broken merge (bench/bench_explore.py's `LastHeardNode`)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from sim.virtual.explore import AUTH_MODES, explore, scripts
from sim.virtual.explore_world import Choice, Script, World
from swarmd.base.identity import throwaway_identities
from swarmd.core.node import Node

ROOT = Path(__file__).resolve().parent.parent


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_explore",
                                                  ROOT / "bench" / "bench_explore.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_explore"] = mod
    spec.loader.exec_module(mod)
    return mod


def _script(name: str) -> Script:
    return next(s for s in scripts("four") if s.name == f"four/{name}")


@pytest.mark.parametrize("auth", AUTH_MODES)
def test_every_loss_dup_and_reorder_around_a_crash_is_taken_over(auth: str) -> None:
    """Robot 1 crashes; every interleaving with one frame dropped, doubled or held back
    in the second after it: f1 is taken over within the bound, one view everywhere."""
    res = explore(_script("crash"), auth=auth, budget=1)
    assert res.branches > 100  # the window holds that many deliveries to perturb
    assert res.runs >= 1 and res.states > 100
    assert res.found == {}, {k: res.schedule(k) for k in res.found}


def test_a_perturbed_leave_takes_other_paths() -> None:
    """A lost LEAVE is a different history (a timeout instead of a handover): the
    explorer walks such runs to the end instead of merging them into the plain one."""
    res = explore(_script("leave"), auth="none", budget=1)
    assert res.runs > 1
    assert res.found == {}, {k: res.schedule(k) for k in res.found}


@pytest.mark.parametrize("auth", ["none", "shared"])
def test_a_merge_that_keeps_the_last_entry_heard_is_caught(auth: str) -> None:
    """Robot 1 is cut off while 4 takes f1 over; when the cut heals, 1's stale heartbeat
    (epoch 0) reaches the others. swarmd keeps the greater view (4@1) and 1 fences
    itself; the mutant takes the last heartbeat heard and goes back to 1@0."""
    script = _script("cut-off")
    good = explore(script, auth=auth, budget=0)
    assert good.found == {}, {k: good.schedule(k) for k in good.found}
    bad = explore(script, auth=auth, budget=0, factory=_bench().LastHeardNode)
    assert {"view_regressed", "views_disagree"} <= set(bad.found)
    shown = bad.schedule("view_regressed")
    assert "partition:1|2,3,4@3+2.2" in shown and "went back from 4@1 to 1@0" in shown


def test_a_state_copies_with_ed25519_keys_and_replays_the_same() -> None:
    """Per robot with real Ed25519 keys (which do not pickle: they are shared, not
    copied): a thawed copy steps exactly as the original does."""
    script = _script("crash")
    world = World.start(script, keys=(bytes(range(32)),),
                        identities=throwaway_identities(script.plan.robots), factory=Node)
    for _ in range(12):
        world.advance()
    copy = world.thaw(world.freeze())
    assert copy.key() == world.key()
    choice = Choice(copy.step, 0, "drop")
    copy.advance(choice)
    world.advance(Choice(world.step, 0, "drop"))
    for _ in range(10):
        copy.advance()
        world.advance()
    assert copy.key() == world.key() and copy.events == world.events
    assert [c.describe() for c in copy.choices] == [c.describe() for c in world.choices]
    assert "drop HEARTBEAT" in copy.choices[0].describe()


def test_bad_input_is_refused_clearly() -> None:
    with pytest.raises(ValueError, match="auth must be one of"):
        explore(_script("crash"), auth="rsa")
