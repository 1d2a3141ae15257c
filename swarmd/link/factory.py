"""Build the robot link the robot file asks for (`link: {kind: none | socket | exec | mavlink |
ros2}`).

The simulator injects its own link (the MuJoCo quadrotor) into `run_daemon` instead of
calling this.
"""

from __future__ import annotations

from typing import Any

from swarmd.link.base import RobotLink
from swarmd.link.exec import ExecLink
from swarmd.link.none import NoneLink
from swarmd.link.socket import SocketLink


class LinkConfigError(ValueError):
    """The link section names a kind this build does not know."""


def make_link(cfg: Any) -> RobotLink:
    """`cfg` is the robot file's `link` model (or None for the `none` link)."""
    kind = getattr(cfg, "kind", "none") if cfg is not None else "none"
    if kind == "none":
        return NoneLink()
    if kind == "socket":
        return SocketLink(cfg.path, health_timeout=cfg.health_timeout)
    if kind == "exec":
        extra: dict[str, Any] = {}
        interval = getattr(cfg, "health_interval", None)
        if interval is not None:
            extra["health_interval"] = interval
        for name in ("timeout", "health_timeout"):
            value = getattr(cfg, name, None)
            if value is not None:
                extra[name] = value
        return ExecLink(on_assign=cfg.on_assign, on_release=cfg.on_release,
                        health_command=getattr(cfg, "health_command", None), **extra)
    if kind == "mavlink":
        from swarmd.link.mavlink import MavlinkLink, pilot_config

        return MavlinkLink(cfg.url, baud=cfg.baud, source_system=cfg.source_system,
                           source_component=cfg.source_component, pilot=pilot_config(cfg))
    if kind == "ros2":
        from swarmd.link.ros2_node import Ros2Unavailable, require_rclpy

        try:
            require_rclpy("link kind ros2")
        except Ros2Unavailable as exc:
            raise LinkConfigError(str(exc)) from None
        from swarmd.link.ros2 import Ros2Link

        return Ros2Link(cfg)
    raise LinkConfigError(f"unknown robot link kind {kind!r} (none, socket, exec, mavlink, "
                          "ros2)")
