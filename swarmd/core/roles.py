"""Roles and their transitions, as data (paper Fig. 5 with the wait state; h11's
`_state.py` is the model).

Theory of operation
-------------------
A robot is ACTIVE (executes one function slot, heartbeats, watches the slots its slot
watches) or STANDBY (the paper's *inactive*: heartbeats slowly, counts warnings about
the slots it may substitute). When a standby counts `quorum` distinct witnesses within
the vote window (Fig. 9), or the holder itself announced LEAVE, it goes CLAIMING (the
paper's *wait*): it broadcasts CLAIM with the next epoch and holds `claim_hold`. A lower
id claiming the same slot, or the suspect heard alive, sends it back to STANDBY; else it
becomes ACTIVE and tells the robot to execute the slot. An ACTIVE robot that hears its
slot held at a higher epoch (or at the same epoch by a lower id) is FENCED: it stops
the function at once, and after one heartbeat period rejoins as STANDBY (DESIGN rule 2).
A robot that reports itself faulty sends LEAVE and drops to STANDBY (rule 7). A holder
that restarts is REJOINING: it listens for `rejoin_hold`, then resumes its slot (ACTIVE)
or, having heard it held by another robot or at a newer epoch, becomes a STANDBY.

Every transition the node makes goes through `transition()`, so this table is the whole
state machine; `docs/roles.md` is generated from it by `python -m swarmd.core.roles`.
"""

from __future__ import annotations

from enum import Enum, IntEnum

from swarmd.core.errors import TransitionError as TransitionError


class Role(IntEnum):
    ACTIVE = 1
    STANDBY = 2
    CLAIMING = 3
    FENCED = 4
    REJOINING = 5
    """A restarted holder listening for `rejoin_hold` before it resumes (rule 2 across
    a reboot). On the wire it heartbeats as a STANDBY."""


class Health(IntEnum):
    OK = 0
    DEGRADED = 1  # still heartbeats and works; shown to watchers and the monitor
    FAULTY = 2  # stops heartbeating and leaves (DESIGN rule 7)


class Trigger(Enum):
    QUORUM = "quorum of distinct warnings within the window (Fig. 9)"
    LEAVE_HEARD = "the holder announced LEAVE"
    CLAIM_HELD = "claim hold ran out with no lower claimant"
    BACKOFF = "a lower id claims the same slot (paper: lowest id wins)"
    REFUTED = "the suspect was heard alive at its epoch (rule 4)"
    SUPERSEDED = "the slot was heard at the claimed epoch or higher"
    FENCE = "own slot heard at a higher epoch, or same epoch from a lower id (rule 2)"
    FENCE_DONE = "fenced robot rejoins as standby"
    FAULT = "the robot reported itself faulty (rule 7)"
    REJOIN = "restarted holder heard no newer holder during rejoin_hold"
    OUTDATED = "restarted holder heard its slot held by another robot or at a newer epoch"



TRANSITIONS: dict[Role, dict[Trigger, Role]] = {
    Role.STANDBY: {
        Trigger.QUORUM: Role.CLAIMING,
        Trigger.LEAVE_HEARD: Role.CLAIMING,
        Trigger.FAULT: Role.STANDBY,
    },
    Role.REJOINING: {
        Trigger.REJOIN: Role.ACTIVE,
        Trigger.OUTDATED: Role.STANDBY,
        Trigger.FAULT: Role.STANDBY,
    },
    Role.CLAIMING: {
        Trigger.CLAIM_HELD: Role.ACTIVE,
        Trigger.BACKOFF: Role.STANDBY,
        Trigger.REFUTED: Role.STANDBY,
        Trigger.SUPERSEDED: Role.STANDBY,
        Trigger.FAULT: Role.STANDBY,
    },
    Role.ACTIVE: {
        Trigger.FENCE: Role.FENCED,
        Trigger.FAULT: Role.STANDBY,
    },
    Role.FENCED: {
        Trigger.FENCE_DONE: Role.STANDBY,
        Trigger.FAULT: Role.FENCED,
    },
}


def transition(role: Role, trigger: Trigger) -> Role:
    try:
        return TRANSITIONS[role][trigger]
    except KeyError:
        raise TransitionError(f"no transition from {role.name} on {trigger.name}") from None


def mermaid() -> str:
    """The state diagram drawn from the table (Mermaid syntax)."""
    lines = ["stateDiagram-v2", "    [*] --> ACTIVE: configured with a function",
             "    [*] --> STANDBY: configured as substitute",
             "    [*] --> REJOINING: restarted holding a function"]
    for src, edges in TRANSITIONS.items():
        for trig, dst in edges.items():
            lines.append(f"    {src.name} --> {dst.name}: {trig.name.lower()}")
    return "\n".join(lines)


REGENERATE = "python -m swarmd.core.roles > docs/roles.md"
"""The command that writes `docs/roles.md` (tests/test_roles.py checks it is current)."""


def markdown() -> str:
    """The whole `docs/roles.md` page: the table of transitions and the diagram."""
    lines = [
        "# Roles and transitions",
        "",
        f"<!-- Generated from swarmd/core/roles.py by `{REGENERATE}`; do not edit. -->",
        "",
        "A robot's role (paper Fig. 5, with the wait state as `CLAIMING`) changes only "
        "through this table: the node (`swarmd/core/node.py`) raises `TransitionError` on "
        "any other change. A robot starts `ACTIVE` when the swarm file gives it a "
        "function, `STANDBY` otherwise; a restarted holder starts `REJOINING` and "
        "listens for `rejoin_hold` first (DESIGN rule 2).",
        "",
        "| from | trigger | to | when |",
        "|---|---|---|---|",
    ]
    for src, edges in TRANSITIONS.items():
        for trig, dst in edges.items():
            lines.append(f"| {src.name} | `{trig.name.lower()}` | {dst.name} | {trig.value} |")
    lines += ["", "```mermaid", mermaid(), "```", ""]
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    print(markdown(), end="")
