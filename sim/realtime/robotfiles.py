"""The robot files of a real-time run: each simulated robot runs from a file that is
literally what `swarmd start --config` takes, on a UDP port picked for the run (so runs
and tests never hear each other) or an emulated radio."""

from __future__ import annotations

import socket
from pathlib import Path
from typing import Any

import yaml

from swarmd.transport.addresses import DEFAULT_INTERFACE, DEFAULT_TTL


def free_udp_port() -> int:
    """A UDP port nothing on 127.0.0.1 uses now: each run gets its own channel."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def robot_ids(swarm_path: Path) -> tuple[int, ...]:
    """Robot ids of a swarm file, validated by the config layer."""
    from swarmd.config import load_swarm

    cfg = load_swarm(swarm_path)
    return tuple(sorted(int(r.id) for r in cfg.robots))


def write_robot_file(
    run_dir: Path, swarm_path: Path, robot: int, *, group: str, port: int,
    interface: str = DEFAULT_INTERFACE, transport: dict[str, Any] | None = None,
) -> Path:
    """The robot file of one simulated robot: literally what `swarmd start` would take.
    `transport` replaces the default UDP multicast section (emulated radios)."""
    doc = {
        "robot": robot,
        "swarm": str(swarm_path.resolve()),
        "transport": transport or {"kind": "udp", "group": group, "port": port,
                                   "interface": interface, "ttl": DEFAULT_TTL,
                                   "loopback": True},
        "link": {"kind": "none"},
        "event_log": None,
        "state_dir": str(run_dir / "state" / str(robot)),
        "handover_on_stop": True,
    }
    path = run_dir / "robots" / f"robot{robot}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
