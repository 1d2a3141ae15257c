"""A robot that learns its own key is revoked stops acting (docs/operations.md,
"Revoking a robot"; DESIGN section 2, "Who may say what").

Revocation makes the swarm deaf to a robot: nobody accepts its signatures and every
daemon that reloaded forgets its heartbeat chain, so its slot is taken over as a silent
robot's. A robot that is told (its own daemon reloads the swarm file that names it in
`auth.revoked`) must not keep executing what it held beside the new holder: it releases
its function through its robot link (the link holds or lands, as configured), says so in
one log line and its event log (`leave`, reason `revoked`), and exits with
`EXIT_REVOKED`, which the systemd unit does not restart (`RestartPreventExitStatus`).
A revoked robot's daemon that starts exits with the same status before it sends
anything.
"""

from __future__ import annotations

from collections.abc import Iterable

from swarmd.config import ConfigError, ConfigUnreadable, Problem, load_swarm

EXIT_REVOKED = 3
"""This robot's key is revoked in the swarm file: it released its function and stopped.
Restarting will not help (deploy/swarmd.service: `RestartPreventExitStatus=3`); bring it
back with a new key pair (docs/operations.md)."""


def revoked_in(swarm_file: str, robot: int) -> bool:
    """Does `swarm_file` (per-robot mode) list `robot` in `auth.revoked`? False for a
    file that cannot be read or used: that is a config error, not a revocation."""
    try:
        swarm = load_swarm(swarm_file)
    except (ConfigError, ConfigUnreadable, OSError):
        return False
    return swarm.auth_mode == "per-robot" and robot in swarm.revoked


def revoked_problem(problems: Iterable[Problem]) -> Problem | None:
    """The problem of a robot file that refuses to load because its robot is revoked
    (`swarmd.config.robot`'s deploy check, field `robot`), if it is among `problems`."""
    for p in problems:
        if p.field == "robot" and p.severity == "error" and " is revoked in swarm file " \
                in p.message:
            return p
    return None
