"""Every small schedule of tests/test_schedules.py, in one mode, with figures.

The suite runs them signed per robot (and a sample unsigned and with a shared key);
this runs the whole set in the mode asked and prints how many ran, how many broke an
invariant (each with its schedule) and the time they took:

    python bench/bench_schedules.py                    # per-robot, as shipped
    python bench/bench_schedules.py --auth none        # also: shared
    python bench/bench_schedules.py --link             # the link-fault schedules only
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from test_schedules import LINK, every_schedule, swarm  # noqa: E402

from sim.virtual.simulator import run_virtual  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--auth", choices=("per-robot", "shared", "none"), default="per-robot")
    ap.add_argument("--link", action="store_true", help="only the link-fault schedules")
    a = ap.parse_args()
    todo = [s for s in every_schedule() if not a.link or s.kind in LINK]
    kinds = collections.Counter(s.kind for s in todo)
    t0 = time.perf_counter()
    bad = 0
    for s in todo:
        plan, params = swarm(s.swarm)
        res = run_virtual(plan, params, duration=s.duration(), faults=s.faults(), auth=a.auth)
        if res.violations:
            bad += 1
            print(f"  {s.id()}: {res.violations[0].kind}: {res.violations[0].detail}")
    print(f"{len(todo)} schedules ({', '.join(f'{k} {n}' for k, n in sorted(kinds.items()))}),"
          f" auth {a.auth}: {bad} with a violation, {time.perf_counter() - t0:.1f} s")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
