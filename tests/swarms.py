"""Swarm files and plans for tests: the paper's swarm (configs/paper.yaml) with the auth a
test wants, and small plans built in code. The committed file is signed per robot with
keys nobody committed, so a test that runs daemons from it says `auth: none` (signing is
not what it tests) or makes keys."""

from __future__ import annotations

import re
from pathlib import Path

from swarmd.base.identity import private_key_path, write_identity
from swarmd.core.plan import RobotPlan, SwarmPlan

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
_AUTH = re.compile(r"(?m)^auth:.*$")


def paper_text(auth: str = "none", source: Path = PAPER) -> str:
    """configs/paper.yaml with its `auth:` line replaced by `auth: <auth>` (or by
    `auth` itself when it is a whole line such as `key_file: swarm.key`)."""
    line = auth if ":" in auth.split("{")[0] else f"auth: {auth}"
    text, n = _AUTH.subn(line, source.read_text(), count=1)
    assert n == 1, f"{source} has no auth line"
    return text


def unsigned_paper(directory: Path, name: str = "paper.yaml") -> Path:
    """The paper's swarm saying `auth: none`, written to directory/name."""
    path = directory / name
    path.write_text(paper_text("none"))
    return path


def signed_paper(directory: Path, name: str = "paper.yaml") -> tuple[Path, Path]:
    """The paper's swarm signed per robot with keys made in directory/keys: (swarm
    file, keys dir). Robot N's private key is `identity_file(keys, N)`."""
    keys = directory / "keys"
    for robot in range(1, 7):
        write_identity(keys, robot)
    path = directory / name
    path.write_text(paper_text("{mode: per-robot, keys_dir: keys}"))
    return path, keys


def identity_file(keys: Path, robot: int) -> Path:
    return private_key_path(keys, robot)


def ring_text(name: str = "ring") -> str:
    """The smallest swarm with the paper's rules at work: three actives in a ring (each
    slot watched by the other two, a quorum), one standby for all three; unsigned."""
    return f"""\
swarm: {{id: 77, name: {name}}}
timing: {{preset: udp}}
auth: none
functions:
  f1: {{kind: slot, position: [2.0, 0.0, 1.5]}}
  f2: {{kind: slot, position: [0.0, 2.0, 1.5]}}
  f3: {{kind: slot, position: [-2.0, 0.0, 1.5]}}
robots:
  - {{id: 1, state: active, function: f1, neighbors: [2, 3]}}
  - {{id: 2, state: active, function: f2, neighbors: [1, 3]}}
  - {{id: 3, state: active, function: f3, neighbors: [1, 2]}}
  - {{id: 4, state: standby, subs: [1, 2, 3]}}
"""


def two_standbys() -> SwarmPlan:
    """The paper's ring of four, with standbys 5 and 6 both covering f2 (rule 6)."""
    fs = ("f1", "f2", "f3", "f4")
    robots = {i + 1: RobotPlan(i + 1, f) for i, f in enumerate(fs)}
    robots[5], robots[6] = RobotPlan(5, None, ("f2",)), RobotPlan(6, None, ("f2",))
    return SwarmPlan(1544, fs, robots, {f: (fs[i - 1], fs[(i + 1) % 4])
                                        for i, f in enumerate(fs)})
