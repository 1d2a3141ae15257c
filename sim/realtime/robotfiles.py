"""The robot files of a real-time run: each simulated robot runs from a file that is
literally what `swarmd start --config` takes, on a UDP port leased for the run (so runs
and tests never hear each other: sim/realtime/ports.py) or an emulated radio.

Signed by default: every run signs with throwaway keys made for it (`sign_for_run`), so
a swarm file's real keys are never needed, nor touched, to simulate it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from swarmd.transport.addresses import DEFAULT_INTERFACE, DEFAULT_TTL

if TYPE_CHECKING:
    from sim.xbee_emu.medium import Medium


def start_medium(robots: int, run_dir: Path, seed: int, transport: str) -> Medium:
    """`--transport xbee|serial`: every robot gets an emulated radio on a pty, all on one
    simulated 802.15.4 medium (xbee: API mode 1 through digi-xbee; serial: the same
    radios in transparent mode, AP=0, under the serial transport)."""
    from sim.xbee_emu.medium import Medium

    return Medium(robots, protocol="802.15.4", directory=run_dir / "radios", seed=seed,
                  transparent=transport == "serial").start()


def emulated_radio(transport: str, medium: Medium | None, radio: int) -> dict[str, Any] | None:
    """The `transport` section of a robot file whose robot speaks through radio number
    `radio` of an emulated `medium` (sim.xbee_emu; None: UDP multicast, no section)."""
    if medium is None:
        return None
    port = medium.path(radio)
    if transport == "serial":
        # The emulated medium is 802.15.4: its 100 B packets carry 93 B of framed
        # swarmd frame, so even a per-robot CERT (92 B) goes whole; the 64 B default
        # of a serial radio would send signed frames in fragments (transport/fragment).
        return {"kind": "serial", "port": port, "max_payload": 93}
    role = "coordinator" if radio == 1 else "router"
    return {"kind": "xbee", "port": port, "protocol": "802.15.4", "api_mode": 1,
            "role": role}


def robot_ids(swarm_path: Path) -> tuple[int, ...]:
    """Robot ids of a swarm file, validated by the config layer."""
    from swarmd.config import load_swarm

    cfg = load_swarm(swarm_path)
    return tuple(sorted(int(r.id) for r in cfg.robots))


def state_dir(run_dir: Path, robot: int) -> Path:
    """Where robot `robot` of a run keeps its state file (`restart:R@T:wiped` empties
    it)."""
    return run_dir / "state" / str(robot)


def write_robot_file(
    run_dir: Path, swarm_path: Path, robot: int, *, group: str, port: int,
    interface: str = DEFAULT_INTERFACE, transport: dict[str, Any] | None = None,
    identity_file: Path | None = None, link: dict[str, Any] | None = None,
) -> Path:
    """The robot file of one simulated robot: literally what `swarmd start` would take.
    `transport` replaces the default UDP multicast section (emulated radios), `link` the
    `none` link (`--link ros2`)."""
    doc = {
        "robot": robot,
        "swarm": str(swarm_path.resolve()),
        "transport": transport or {"kind": "udp", "group": group, "port": port,
                                   "interface": interface, "ttl": DEFAULT_TTL,
                                   "loopback": True},
        "link": link or {"kind": "none"},
        "event_log": None,
        "state_dir": str(state_dir(run_dir, robot)),
        "handover_on_stop": True,
    }
    if identity_file is not None:
        doc["identity_file"] = str(identity_file)
    path = run_dir / "robots" / f"robot{robot}.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def sign_for_run(run_dir: Path, swarm_path: Path) -> tuple[Path, dict[int, Path]]:
    """The swarm file the run's robots use and each robot's private key file.

    A swarm that says `auth: none` runs unsigned, as written. Any other gets keys made
    for this run under `run_dir/keys` and a copy of the swarm file naming them: per-robot
    Ed25519 keys (the default, also for a swarm that says nothing about signing), or a
    throwaway swarm key for `auth: {mode: shared}`. Revocations are dropped: every
    simulated robot must be able to start."""
    from swarmd.base.identity import private_key_path, write_identity
    from swarmd.base.keys import generate_key
    from swarmd.config import load_swarm
    from swarmd.config.source import read_source

    cfg = load_swarm(swarm_path)
    if cfg.auth_mode == "none" and cfg.auth_explicit:
        return swarm_path, {}
    data = read_source(swarm_path).data
    assert isinstance(data, dict)  # load_swarm validated it
    doc = {k: v for k, v in data.items() if k != "key_file"}
    keys_dir = run_dir / "keys"
    keys_dir.mkdir(parents=True, exist_ok=True)
    identity_files: dict[int, Path] = {}
    if cfg.auth_mode == "shared":
        key = keys_dir / "swarm.key"
        generate_key(key, force=True)
        doc["auth"] = {"mode": "shared", "key_file": str(key)}
    else:
        for r in cfg.robot_ids():
            write_identity(keys_dir, r, force=True)
            identity_files[r] = private_key_path(keys_dir, r)
        doc["auth"] = {"mode": "per-robot", "keys_dir": str(keys_dir)}
        if cfg.key_path is not None:  # per-robot plus a swarm key
            key = keys_dir / "swarm.key"
            generate_key(key, force=True)
            doc["auth"]["key_file"] = str(key)
    out = run_dir / "swarm.yaml"
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out, identity_files
