"""The explorer (sim/virtual/explore.py) over its configurations, with figures.

For each small swarm (three, four, five robots), each scripted fault set (crash, leave,
restart, crash then restart, a fade, a one-way cut, a deaf standby while the holder
crashes, two overlapping one-way cuts) and each auth mode, it walks every interleaving
with at most `--budget` dropped, duplicated or reordered frames in the windows around
the faults, and prints the interleavings tried, the states stepped through, the runs
walked to the end, the violating ones and the wall time; then, per violation kind, the
shortest interleaving that shows it, as a readable schedule:

    python bench/bench_explore.py                         # four robots, every mode
    python bench/bench_explore.py --swarm five --budget 2 --auth none
    python bench/bench_explore.py --only fade --auth per-robot
    python bench/bench_explore.py --mutant last-heard     # must report violations

`--mutant last-heard` runs a deliberately broken node (`LastHeardNode`, below: after
each heartbeat it overwrites its view of the slot with the heartbeat's sender and
epoch, keeping the last entry heard instead of the greatest): the explorer must catch
it (tests/test_explore.py). The mutant lives here and in the tests, never in swarmd/.
`--ed25519` signs per robot with real Ed25519 keys instead of the simulators' stand-in.
It exits 1 when any violation was found.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from sim.virtual.explore import AUTH_MODES, SWARMS, Result, explore, scripts  # noqa: E402
from sim.virtual.explore_world import NodeFactory  # noqa: E402
from swarmd.core import wire  # noqa: E402
from swarmd.core.actions import Action  # noqa: E402
from swarmd.core.node import Node  # noqa: E402
from swarmd.core.records import Holder  # noqa: E402


class LastHeardNode(Node):
    """A test-only mutant: the view of a slot is the last heartbeat heard for it, not
    the greatest (epoch, then lower id). It reaches into the node's private slot table
    on purpose; it exists to show that the explorer catches a broken merge."""

    def receive(self, data: bytes, now: float) -> list[Action]:
        actions = super().receive(data, now)
        try:
            frame = wire.decode(data, self.keys, self._verifier)
        except wire.CodecError:
            return actions
        msg = frame.msg
        if isinstance(msg, wire.Heartbeat) and msg.function and frame.sender != self.robot_id:
            f = self.plan.function_at(msg.function)
            if f is not None:
                _overwrite(self._known, f, Holder(frame.sender, msg.epoch))
        return actions


def _overwrite(known: Any, f: str, entry: Holder) -> None:
    """Set a view behind the merge: the slot table's private entries (swarmd.core.slots,
    which offers no way to lower one), or a plain dict of views."""
    entries = getattr(known, "_entries", known)
    entries[f] = entry


MUTANTS: dict[str, NodeFactory] = {"last-heard": LastHeardNode}


def ed25519_identities(robots: Any) -> dict[int, Any]:
    from swarmd.base.identity import throwaway_identities

    return throwaway_identities(robots)


def run(swarm: str, auths: tuple[str, ...], budget: int, only: str,
        factory: NodeFactory, ed25519: bool = False) -> list[Result]:
    results = []
    for auth in auths:
        for script in scripts(swarm):
            if only and only not in script.name:
                continue
            ids = ed25519_identities(script.plan.robots) if ed25519 and auth == "per-robot" \
                else None
            res = explore(script, auth=auth, budget=budget, factory=factory, identities=ids)
            print(res.summary(), flush=True)
            results.append(res)
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--swarm", choices=SWARMS, default="four", help="default four")
    ap.add_argument("--auth", choices=AUTH_MODES, default=None, help="default: every mode")
    ap.add_argument("--budget", type=int, default=1,
                    help="perturbed deliveries a run at most (default 1)")
    ap.add_argument("--only", default="", help="only the fault sets whose name has this")
    ap.add_argument("--mutant", choices=sorted(MUTANTS), default=None,
                    help="run a deliberately broken node instead of swarmd's")
    ap.add_argument("--ed25519", action="store_true",
                    help="per-robot mode with real Ed25519 keys (slower)")
    a = ap.parse_args()
    if a.budget < 0:
        ap.error("--budget must be 0 or more")
    auths = (a.auth,) if a.auth else AUTH_MODES
    factory = MUTANTS[a.mutant] if a.mutant else Node
    t0 = time.perf_counter()
    results = run(a.swarm, auths, a.budget, a.only, factory, a.ed25519)
    bad = [r for r in results if r.found]
    print(f"{len(results)} configurations, {sum(r.branches for r in results)} interleavings, "
          f"{sum(r.states for r in results)} states, {len(bad)} with a violation, "
          f"{time.perf_counter() - t0:.1f} s")
    for r in bad:
        for kind in sorted(r.found):
            print(r.schedule(kind))
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
