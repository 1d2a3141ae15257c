"""The base station file `swarmd monitor --config` reads (docs/monitor.md): a robot file
without `robot:` (it is no robot) and without link, state or metrics (it executes nothing
and sends nothing). Here, in the config layer, because only this package imports pydantic
(DESIGN section 2)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from swarmd.config import ConfigError, SwarmConfig, load_robot
from swarmd.config.errors import Problem
from swarmd.config.robot import TransportConfig, UdpTransportConfig, load_referenced_swarm
from swarmd.config.source import read_source, validate


class _BaseStationFile(BaseModel):
    """A base station file: a robot file without `robot:` (it is no robot) and without
    link, state or metrics (it executes nothing and sends nothing)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    swarm: str
    transport: TransportConfig = Field(default_factory=UdpTransportConfig)
    key_files: list[str] = Field(default_factory=list)


@dataclass(frozen=True)
class BaseStation:
    """What `swarmd monitor --config` listens with: the swarm, a transport section (any
    kind: UDP, an XBee coordinator, a serial radio) and the keys frames are checked with."""

    swarm: SwarmConfig
    transport: Any
    keys: tuple[bytes, ...]


def load_base_station(path: str | Path) -> BaseStation:
    """A base station file, or a robot file (its swarm, transport and keys are used).
    Raises ConfigUnreadable or ConfigError, like `load_robot`."""
    from swarmd.base.keys import KeyFileError, load_key

    src = read_source(path)
    if isinstance(src.data, dict) and "robot" in src.data:
        robot = load_robot(path)
        return BaseStation(robot.swarm, robot.transport, robot.keys())
    f: _BaseStationFile = validate(_BaseStationFile, src)
    problems: list[Problem] = []
    swarm = load_referenced_swarm(src, f.swarm, problems)
    keys: list[bytes] = []
    if swarm is not None and (swarm_key := swarm.key()) is not None:
        keys.append(swarm_key)
    for i, name in enumerate(f.key_files):
        try:
            key = load_key(src.resolve(name))
        except KeyFileError as exc:
            problems.append(src.problem(("key_files", i), str(exc)))
            continue
        if key not in keys:
            keys.append(key)
    if swarm is None or any(p.severity == "error" for p in problems):
        raise ConfigError(problems)
    return BaseStation(swarm, f.transport, tuple(keys))


__all__ = ["BaseStation", "load_base_station"]
