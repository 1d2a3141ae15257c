"""`forge` faults in the real-time swarm: real daemons on loopback, an insider with robot
1's key sends a forged max-epoch HEARTBEAT for every slot it does not hold, raw on the
transport (sim/realtime/robot_proc.py `Forger`). Signed per robot, no live holder is
fenced; unsigned (`auth: none`), the checker reports the fenced holder and the run fails."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from swarms import PAPER, ROOT, unsigned_paper

pytestmark = pytest.mark.slow


def _sim(swarm: Path, *faults: str) -> tuple[int, dict[str, Any]]:
    args = [sys.executable, "-m", "swarmd.cli", "sim", str(swarm), "--no-physics", "--json",
            "--duration", "7"]
    for f in faults:
        args += ["--fault", f]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(args, capture_output=True, text=True, timeout=120, env=env,
                          cwd=ROOT, check=False)
    assert done.stdout.strip(), done.stderr
    return done.returncode, json.loads(done.stdout)


def test_forged_epoch_does_not_fence_the_holder_when_signed_per_robot() -> None:
    # configs/paper.yaml is signed per robot; `swarmd sim` makes throwaway keys.
    code, out = _sim(PAPER, "forge:1@3:epoch")
    assert out["violations"] == []
    assert out["holders"]["f2"] == [2]
    assert out["takeovers"] == 0
    assert code == 0 and out["ok"] is True
    # Robot 1's own daemon heard frames with its id it did not send: the insider is seen.
    assert any("sending as robot 1" in w for w in out["warnings"])


def test_forged_epoch_fences_the_holder_of_an_unsigned_swarm(tmp_path: Path) -> None:
    code, out = _sim(unsigned_paper(tmp_path), "forge:1@3:epoch")
    kinds = {(v["kind"], v["robot"]) for v in out["violations"]}
    assert ("fenced_without_takeover", 2) in kinds
    assert "f2" not in out["holders"]
    assert code == 1 and out["ok"] is False
