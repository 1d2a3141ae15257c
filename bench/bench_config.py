"""Config loading speed: a swarm of 255 actives and 1,000 / 5,000 standbys.

Prints, per size: the time to read, validate and cross-check the swarm file
(`load_swarm` + `coverage`, in process: wall and CPU seconds) and `swarmd check` as a
user runs it (a new Python process, imports and the rendered report included: wall and
CPU seconds; CPU time is what a shared, loaded machine does not inflate). Goal: the
5,255-robot swarm checked in under 2 s. The loader must be linear in the swarm's size.

    python bench/bench_config.py
    python bench/bench_config.py --standbys 1000 5000 20000
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd.config import load_swarm  # noqa: E402


def write_swarm(path: Path, actives: int, standbys: int) -> Path:
    """Actives in a ring (two watchers each), each standby covering four slots."""
    lines = ["swarm: {id: 7}", "functions:"]
    lines += [f"  f{i}: {{kind: slot, position: [{i}.0, 0.0, 1.0]}}"
              for i in range(1, actives + 1)]
    lines.append("robots:")
    for i in range(1, actives + 1):
        left, right = (i - 2) % actives + 1, i % actives + 1
        lines.append(f"  - {{id: {i}, state: active, neighbors: [{left}, {right}]}}")
    for j in range(standbys):
        subs = ", ".join(f"f{(j + k) % actives + 1}" for k in range(4))
        lines.append(f"  - {{id: {actives + 1 + j}, state: standby, subs: [{subs}]}}")
    path.write_text("\n".join(lines) + "\n")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--actives", type=int, default=255)
    ap.add_argument("--standbys", type=int, nargs="+", default=[1000, 5000])
    args = ap.parse_args()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    print(f"{'robots':>7} {'file kB':>8} {'load s':>7} {'load cpu':>9} {'check s':>8} "
          f"{'check cpu':>10}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.standbys:
            path = write_swarm(Path(tmp) / f"swarm{n}.yaml", args.actives, n)
            t0, c0 = time.perf_counter(), time.process_time()
            cfg = load_swarm(path)
            cfg.coverage()
            load_s, load_cpu = time.perf_counter() - t0, time.process_time() - c0
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "swarmd.cli", "check", str(path)],
                                  capture_output=True, text=True, env=env, timeout=600)
            check_s = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            check_cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            ok = "ok" if proc.returncode == 0 else f"rc {proc.returncode}"
            print(f"{args.actives + n:>7} {path.stat().st_size / 1024:>8.0f} {load_s:>7.2f} "
                  f"{load_cpu:>9.2f} {check_s:>8.2f} {check_cpu:>10.2f}  {ok}")


if __name__ == "__main__":
    main()
