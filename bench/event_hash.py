"""One hash per auth mode of every event of a fixed set of virtual runs: the proof that a
change meant to move code, or to make it faster, changes nothing a robot does.

    python bench/event_hash.py              # 6 seeds a mode, about 15 s
    python bench/event_hash.py --seeds 2    # quicker
    python bench/event_hash.py --chaos 30   # also 30 wide chaos seeds a mode (12 robots)

Run it on the tree before and after the change: the lines must be identical. The fixed
set is the paper swarm (configs/paper.yaml) for 30 s, robot 2 crashing at 5 s and robot 3
paused from 12 s for 3 s, on a channel losing 10 % of frames in bursts of 4, one run per
seed; `--chaos N` adds wide seeds 30000.. of `bench_chaos.py` (compound link faults,
bursty loss up to 40 %), whose hash covers events, violations, drops and frames sent.
The events are the JSON lines the event log would hold, so a hash that moves means some
robot did something else, or at another time.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import bench_chaos  # noqa: E402

from sim.shared.faults import parse_fault  # noqa: E402
from sim.virtual.simulator import run_virtual  # noqa: E402
from swarmd.config import load_swarm  # noqa: E402

MODES = ("per-robot", "shared", "none")


def paper_hash(auth: str, seeds: int) -> str:
    cfg = load_swarm(ROOT / "configs" / "paper.yaml")
    h = hashlib.blake2b(digest_size=8)
    for seed in range(seeds):
        events: list[dict[str, Any]] = []
        run_virtual(cfg.to_plan(), cfg.params(), duration=30,
                    faults=[parse_fault("crash:2@5"), parse_fault("pause:3@12+3")],
                    loss=0.1, seed=seed, auth=auth, on_event=events.append,
                    loss_model="burst", burst_len=4)
        h.update(json.dumps(events, sort_keys=True, default=str).encode())
    return h.hexdigest()


def chaos_hash(auth: str, seeds: int) -> str:
    h = hashlib.blake2b(digest_size=8)
    for seed in range(30000, 30000 + seeds):
        case = bench_chaos.draw_case(seed, 12, wide=True)
        result = bench_chaos.run_case(case, auth=auth)
        seen = [result.events, [str(v) for v in result.violations], result.drops,
                result.final, result.frames_sent, result.deliveries]
        h.update(json.dumps(seen, sort_keys=True, default=str).encode())
    return h.hexdigest()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=6, help="paper-swarm runs a mode (default 6)")
    ap.add_argument("--chaos", type=int, default=0, help="wide chaos seeds a mode (default 0)")
    a = ap.parse_args()
    t0 = time.process_time()
    for auth in MODES:
        line = f"{auth:9} paper {paper_hash(auth, a.seeds)}"
        if a.chaos:
            line += f"  chaos {chaos_hash(auth, a.chaos)}"
        print(line, flush=True)
    print(f"cpu {time.process_time() - t0:.1f} s")


if __name__ == "__main__":
    main()
