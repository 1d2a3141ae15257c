"""Swarm and robot config files (pydantic; DESIGN.md section 3).

    cfg = load_swarm("configs/paper.yaml")      # SwarmConfig; cfg.warnings
    plan, params = cfg.to_plan(), cfg.params()  # what swarmd.core.Node takes
    robot = load_robot("configs/robot-example.yaml")   # RobotConfig, robot.swarm loaded

Errors raise `ConfigError`, whose `.problems` each name the file, the field and what
is wrong. Only this package imports pydantic (DESIGN section 2).
"""

from swarmd.config.errors import ConfigError, ConfigUnreadable, Problem, format_loc
from swarmd.config.robot import (
    ExecLinkConfig,
    MetricsConfig,
    NoneLinkConfig,
    RobotConfig,
    SerialTransportConfig,
    SocketLinkConfig,
    UdpTransportConfig,
    XBeeTransportConfig,
    load_robot,
    parse_robot,
)
from swarmd.config.swarm import (
    Coverage,
    PatrolFunction,
    RobotEntry,
    SlotFunction,
    SwarmConfig,
    Timing,
)
from swarmd.config.swarm_rules import inspect_swarm, load_swarm, parse_swarm

__all__ = [
    "ConfigError",
    "ConfigUnreadable",
    "Coverage",
    "ExecLinkConfig",
    "MetricsConfig",
    "NoneLinkConfig",
    "PatrolFunction",
    "Problem",
    "RobotConfig",
    "RobotEntry",
    "SerialTransportConfig",
    "SlotFunction",
    "SocketLinkConfig",
    "SwarmConfig",
    "Timing",
    "UdpTransportConfig",
    "XBeeTransportConfig",
    "format_loc",
    "inspect_swarm",
    "load_robot",
    "load_swarm",
    "parse_robot",
    "parse_swarm",
]
