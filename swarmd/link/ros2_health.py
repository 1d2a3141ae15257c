"""The ros2 link's health input as pure data (docs/ros2.md, "In the field"): whose
statuses count, and what the daemon may conclude before it ever heard its robot.

Health belongs to its robot: a status counts only when its publisher is a node of the
robot's own namespace (`/swarmd/<swarm>/robot<id>` by default) or the one node the robot
file names (`health_node`), never because its `hardware_id` says so: any node in the
domain can write any hardware_id. Statuses are kept per (publisher, name), so two
publishers of one status never overwrite each other; the worst fresh one decides.

Start-up (DESIGN rule 7 applies to a robot that was heard): a stack not heard yet is not
a faulty robot, it may still be booting, and DDS discovery alone took seconds on a
loaded machine. So the daemon never reports faulty before the robot's first status; it
says what it waits for, and it raises an alert, keeping its function, when no health
publisher of the robot was found `startup_timeout` after the start, or when one was
found and sent nothing within `health_timeout` of its discovery.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.link.ros2_status import ERROR, OK, STALE, WARN

NEVER_HEARD = "holder never heard"
"""The alert's first words, on /diagnostics and in the log (docs/ros2.md)."""


def node_fqn(namespace: str, name: str) -> str:
    """A node's fully qualified name, /ns/name (the root namespace is `/`)."""
    return f"{namespace.rstrip('/')}/{name}"


class HealthFold:
    """The worst level among the robot's statuses heard within `timeout`, kept per
    (publisher, status name). The executor thread owns it."""

    def __init__(self, names: tuple[str, ...], hardware_id: str, timeout: float,
                 prefix: str = "swarmd/") -> None:
        self.names = frozenset(names)
        self.hardware_id = hardware_id
        self.timeout = timeout
        self.prefix = prefix
        self.latest: dict[tuple[str, str], tuple[int, float]] = {}

    def mine(self, name: str, hardware_id: str) -> bool:
        if name.startswith(self.prefix):
            return False  # a daemon's view of the swarm, not a robot's health
        return name in self.names if self.names else hardware_id == self.hardware_id

    def hear(self, publisher: str, name: str, hardware_id: str, level: int,
             now: float) -> bool:
        if not self.mine(name, hardware_id):
            return False
        self.latest[(publisher, name)] = (level, now)
        return True

    def level(self, now: float) -> int:
        fresh = [lv for lv, at in self.latest.values() if now - at <= self.timeout]
        return max(fresh) if fresh else STALE


class Publishers:
    """Which nodes may speak for the robot: those of `namespace` (every node when it is
    the root namespace, as an explicit `namespace: ""` asks) or exactly `health_node`;
    never the daemon's own node (`own`)."""

    def __init__(self, namespace: str, health_node: str | None, own: str) -> None:
        self.namespace = "/" + namespace.strip("/") if namespace.strip("/") else "/"
        self.health_node = health_node
        self.own = own

    def accepts(self, fqn: str) -> bool:
        if fqn == self.own:
            return False
        if self.health_node is not None:
            return fqn == self.health_node
        if self.namespace == "/":
            return True
        return fqn.rsplit("/", 1)[0] == self.namespace

    def describe(self) -> str:
        """Whose health counts, for messages."""
        if self.health_node is not None:
            return f"node {self.health_node}"
        if self.namespace == "/":
            return "any node"
        return f"a node in {self.namespace}"


@dataclass(frozen=True, slots=True)
class StackState:
    """What the link concludes now. `health`: the level to report to the daemon (None:
    nothing yet, never a fault); `level`/`message`: the robot's own function as
    /diagnostics shows it (None: the holder's ordinary status); `alert`: True once a
    start-up bound passed."""

    health: int | None
    level: int | None
    message: str
    alert: bool = False


class StackWatch:
    """The start-up timeline of one robot stack on the link's monotonic clock (pure;
    tests drive it on virtual time)."""

    def __init__(self, fold: HealthFold, publishers: Publishers, *, started_at: float,
                 startup_timeout: float, topic: str = "/diagnostics") -> None:
        self.fold = fold
        self.publishers = publishers
        self.started_at = started_at
        self.startup_timeout = startup_timeout
        self.topic = topic
        self.found_at: float | None = None
        self.found_node = ""

    def found(self, fqn: str, now: float) -> bool:
        """A matching publisher of the health topic was discovered; True the first time."""
        if self.found_at is not None:
            return False
        self.found_at, self.found_node = now, fqn
        return True

    def waiting_for(self) -> str:
        return (f"robot health: a DiagnosticStatus from {self.publishers.describe()} on "
                f"{self.topic} (hardware_id {self.fold.hardware_id})" if not self.fold.names
                else f"robot health: statuses {sorted(self.fold.names)} from "
                f"{self.publishers.describe()} on {self.topic}")

    def state(self, now: float) -> StackState:
        if self.fold.latest:
            level = self.fold.level(now)
            if level == OK:
                return StackState(level, None, "")
            if level == STALE:
                return StackState(level, STALE, f"robot health not heard for "
                                                f"{self.fold.timeout:g} s")
            return StackState(level, level if level == WARN else ERROR, "robot health "
                              + ("degraded" if level == WARN else "faulty"))
        if self.found_at is None:
            if now - self.started_at <= self.startup_timeout:
                return StackState(None, WARN, f"waiting for {self.waiting_for()}")
            return StackState(None, ERROR, f"{NEVER_HEARD}: no health publisher "
                              f"({self.publishers.describe()}) after "
                              f"{self.startup_timeout:g} s", alert=True)
        if now - self.found_at <= self.fold.timeout:
            return StackState(None, WARN, f"waiting for the first status of "
                                          f"{self.found_node}")
        return StackState(None, ERROR, f"{NEVER_HEARD}: {self.found_node} publishes on "
                          f"{self.topic} but sent no status of this robot within "
                          f"{self.fold.timeout:g} s", alert=True)
