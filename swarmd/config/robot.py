"""The robot file: which robot this daemon is, its swarm, channel and robot link.

    robot: 2
    swarm: paper.yaml                 # relative to this file
    transport: {kind: udp}            # udp | serial | xbee
    link: {kind: none}                # none | socket | exec | mavlink | ros2
    event_log: null
    state_dir: /var/lib/swarmd
    handover_on_stop: true
    metrics: null                     # {host: 127.0.0.1, port: 9477}
    key_files: []
    identity_file: keys/robot-2.key   # this robot's private key (per-robot auth)

Every relative path in a config file is relative to that file, so a robot directory
can be copied as a whole. See docs/config.md.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, StrictInt, field_validator

from swarmd.base.identity import IdentityFileError, public_key_of, read_private_key
from swarmd.base.keys import KeyFileError, load_key
from swarmd.config.auth import auth_issues, public_keys, retired_keys
from swarmd.config.errors import ConfigError, ConfigUnreadable, Problem, format_loc
from swarmd.config.source import Source, parse_source, read_source, validate
from swarmd.config.swarm import RobotEntry, SwarmConfig
from swarmd.config.swarm_rules import load_swarm
from swarmd.transport.addresses import interface_address, multicast_group
from swarmd.transport.fragment import MIN_LIMIT
from swarmd.transport.media import SERIAL_MAX_PAYLOAD


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _int_or_hex(value: Any) -> Any:
    # XBee manuals and XCTU write PAN ids and channels in hex ("0x607", "0C").
    if isinstance(value, str):
        text = value.strip().lower()
        try:
            return int(text, 16) if text.startswith("0x") else int(text, 0)
        except ValueError:
            raise ValueError(f"not a number: {value!r} (write 1543 or \"0x607\")") from None
    return value


HexInt = Annotated[int, BeforeValidator(_int_or_hex)]


class UdpTransportConfig(_Model):
    """UDP multicast. Defaults stay on loopback with TTL 1 (DESIGN.md section 4)."""

    kind: Literal["udp"] = "udp"
    group: str = "239.255.77.7"
    port: int = Field(default=47007, ge=1, le=65535)
    interface: str = "127.0.0.1"
    """IPv4 address of the interface multicast is sent from (IP_MULTICAST_IF)."""
    ttl: int = Field(default=1, ge=0, le=255)
    loopback: bool = True
    """IP_MULTICAST_LOOP: needed when several robots run on one machine (sim)."""

    # The transport's own checks (swarmd/transport/addresses.py): a file that validates
    # never fails later in UdpTransport's constructor.
    @field_validator("group")
    @classmethod
    def _multicast(cls, value: str) -> str:
        return multicast_group(value)

    @field_validator("interface")
    @classmethod
    def _ipv4(cls, value: str) -> str:
        return interface_address(value)


class SerialTransportConfig(_Model):
    """Transparent serial radio (XBee in AP=0, SiK telemetry radios)."""

    kind: Literal["serial"]
    port: str
    baud: int = Field(default=57600, gt=0)
    max_payload: int = Field(default=SERIAL_MAX_PAYLOAD, ge=MIN_LIMIT, le=1024)
    """Largest datagram, bytes: the radio's RF packet less the 7 B of framing, so a
    datagram never spans two packets (docs/radios.md). The default fits every XBee; a
    larger frame (a per-robot signed one: up to 92 B) goes out in fragments
    (transport/fragment.py), at least 24 B each."""


class XBeeTransportConfig(_Model):
    """XBee in API mode through digi-xbee (docs/radios.md)."""

    kind: Literal["xbee"]
    port: str
    baud: int = Field(default=9600, gt=0)
    protocol: Literal["zigbee", "802.15.4", "digimesh"] = "802.15.4"
    api_mode: Literal[1, 2] = 1
    pan_id: HexInt | None = Field(default=None, ge=0, le=0xFFFF)
    """None leaves the radio's own PAN id."""
    channel: HexInt | None = Field(default=None, ge=0, le=0xFF)
    role: Literal["coordinator", "router"] = "router"
    max_in_flight: int = Field(default=8, ge=1)


TransportConfig = Annotated[
    UdpTransportConfig | SerialTransportConfig | XBeeTransportConfig,
    Field(discriminator="kind"),
]

Command = str | list[str]


class NoneLinkConfig(_Model):
    """No robot: always healthy (tests, bench)."""

    kind: Literal["none"] = "none"


class SocketLinkConfig(_Model):
    """The robot connects to a Unix socket and speaks JSON Lines."""

    kind: Literal["socket"]
    path: str
    health_timeout: float = Field(default=2.0, gt=0, description="s")


class ExecLinkConfig(_Model):
    """Run commands on assign / release; optionally poll a health command."""

    kind: Literal["exec"]
    on_assign: Command
    on_release: Command | None = None
    health_command: Command | None = None
    health_timeout: float = Field(default=5.0, gt=0, description="s")
    """A health command still running after this is killed: the robot is faulty."""


HealthName = Literal["ok", "degraded", "faulty"]


class MavlinkHealthConfig(_Model):
    """Thresholds of the MAVLink health table (docs/mavlink.md)."""

    heartbeat_timeout: float = Field(default=3.0, gt=0, description="s")
    battery_degraded: float = Field(default=30.0, ge=0, le=100, description="%")
    battery_faulty: float = Field(default=15.0, ge=0, le=100, description="%")
    estimator_degraded: float = Field(default=0.5, gt=0)
    estimator_faulty: float = Field(default=0.8, gt=0)
    critical: HealthName = "degraded"
    not_ready: HealthName = "degraded"
    failsafe_mode: HealthName = "faulty"
    command_refused: HealthName = "faulty"
    refused_hold: float = Field(default=30.0, ge=0, description="s")
    sensors: dict[Literal["gyro", "accel", "mag", "gps", "motors"], HealthName] = Field(
        default_factory=dict)
    """Overrides of the per-sensor health (gyro, accel, motors faulty; mag, gps degraded)."""


class MavlinkLinkConfig(_Model):
    """A PX4 or ArduPilot flight controller over MAVLink (docs/mavlink.md)."""

    kind: Literal["mavlink"]
    url: str = Field(min_length=1)
    """pymavlink form: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a serial device."""
    baud: int = Field(default=57600, gt=0)
    source_system: int = Field(default=1, ge=1, le=255)
    source_component: int = Field(default=191, ge=1, le=255)
    target_system: int | None = Field(default=None, ge=1, le=255)
    target_component: int = Field(default=1, ge=0, le=255)
    autopilot: Literal["auto", "px4", "ardupilot"] = "auto"
    takeoff_altitude: float = Field(default=2.0, gt=0, description="m")
    setpoint_rate: float = Field(default=10.0, ge=5, le=50, description="Hz")
    release: Literal["hold", "land", "rtl"] = "rtl"
    command_timeout: float = Field(default=1.0, gt=0, description="s")
    command_retries: int = Field(default=3, ge=0, le=20)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Swarm-frame position (x east, y north, z up) of the autopilot's local origin."""
    geo_origin: tuple[float, float, float] | None = None
    """(latitude, longitude, altitude) of the swarm frame's 0; replaces `origin`."""
    health: MavlinkHealthConfig = Field(default_factory=MavlinkHealthConfig)


class Ros2LinkConfig(_Model):
    """The robot is a ROS 2 stack (docs/ros2.md): health from its DiagnosticStatus entries
    on /diagnostics, the function out as topics, the swarm's view on /diagnostics."""

    kind: Literal["ros2"]
    node_name: str | None = Field(default=None, min_length=1)
    """The daemon's ROS 2 node; None: swarmd_robot<id>."""
    namespace: str | None = None
    """The daemon's node namespace, where its relative topics live and where the robot's
    stack runs; None: /swarmd/<swarm name>/robot<id>, so the robots of two swarms in one
    domain never share a topic or a health (docs/ros2.md, "In the field")."""
    health_node: str | None = Field(default=None, min_length=2, pattern=r"^/")
    """The fully qualified node (/ns/name) whose statuses are this robot's health; None:
    any node in `namespace`."""
    startup_timeout: float = Field(default=30.0, gt=0, description="s")
    """No health publisher of this robot found this long after the start: an alert (the
    function is kept; the daemon goes on waiting). Never a hand-over: a stack that is
    still booting is not a faulty robot."""
    domain_id: int | None = Field(default=None, ge=0, le=232)
    """None: $ROS_DOMAIN_ID (else 0), as any ROS 2 node."""
    localhost_only: bool = True
    """Discovery on this machine only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) unless
    $ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise: the robot's stack runs beside the
    daemon (DESIGN section 4: nothing leaves loopback unless asked)."""
    health_names: list[str] = Field(default_factory=list)
    """The DiagnosticStatus names that are this robot's health; empty: every status with
    `hardware_id`."""
    hardware_id: str | None = None
    """None: robot<id>."""
    health_timeout: float = Field(default=2.0, gt=0, description="s")
    """No status of this robot for this long, once its publisher was found: faulty
    (STALE)."""
    goal_topic: str = Field(default="swarmd/goal_pose", min_length=1)
    function_topic: str = Field(default="swarmd/function", min_length=1)
    release_topic: str = Field(default="swarmd/release", min_length=1)
    assignment_topic: str = Field(default="swarmd/assignment", min_length=1)
    """The whole assignment in one latched message, with seq, boot and lease."""
    frame_id: str = "map"
    release: Literal["hold", "land"] = "hold"
    republish_interval: float = Field(default=1.0, gt=0, description="s")
    status_interval: float = Field(default=1.0, gt=0, le=1.0, description="s")
    """The swarm's statuses on /diagnostics at least this often (and at every change)."""


LinkConfig = Annotated[
    NoneLinkConfig | SocketLinkConfig | ExecLinkConfig | MavlinkLinkConfig | Ros2LinkConfig,
    Field(discriminator="kind"),
]


class MetricsConfig(_Model):
    host: str = "127.0.0.1"
    port: int = Field(default=9477, ge=1, le=65535)
    allow_remote: bool = False
    """A metrics endpoint off loopback must be asked for explicitly (DESIGN section 4)."""


class RobotFile(_Model):
    """The robot file's schema, as written."""

    robot: StrictInt = Field(ge=1, le=0xFFFF)  # `robot: true` is not robot 1
    swarm: str
    transport: TransportConfig = Field(default_factory=UdpTransportConfig)
    link: LinkConfig = Field(default_factory=NoneLinkConfig)
    event_log: str | None = None
    state_dir: str = "/var/lib/swarmd"
    handover_on_stop: bool = True
    metrics: MetricsConfig | None = None
    key_files: list[str] = Field(default_factory=list)
    identity_file: str | None = None


@dataclass(frozen=True)
class IdentityMaterial:
    """Per-robot auth as read from the files: what `swarmd.base.identity` builds the
    node's `Identity` from (the daemon keeps signer and keyring to reload on SIGHUP)."""

    private_key: bytes
    public_keys: dict[int, tuple[bytes, ...]]
    revoked: frozenset[int]
    retired: dict[int, tuple[bytes, ...]] = field(default_factory=dict)
    """Keys that verify history only: retired by a rotation, or a revoked robot's
    (`swarmd.config.auth.retired_keys`)."""


@dataclass(frozen=True)
class RobotConfig:
    """A validated robot file with its swarm loaded and every path resolved."""

    robot: int
    swarm: SwarmConfig
    swarm_path: Path
    transport: UdpTransportConfig | SerialTransportConfig | XBeeTransportConfig
    link: NoneLinkConfig | SocketLinkConfig | ExecLinkConfig | MavlinkLinkConfig | Ros2LinkConfig
    event_log: Path | None
    state_dir: Path
    handover_on_stop: bool
    metrics: MetricsConfig | None
    key_files: tuple[Path, ...]
    source: str
    warnings: tuple[Problem, ...] = ()
    identity_file: Path | None = None
    """This robot's private key (per-robot auth), resolved."""

    @property
    def robot_id(self) -> int:
        return self.robot

    @property
    def entry(self) -> RobotEntry:
        """This robot's entry in the swarm file."""
        return self.swarm.robot(self.robot)

    def keys(self) -> tuple[bytes, ...]:
        """Keys accepted on receive, the signing key first: the swarm's key_file if it
        has one, then `key_files` (key rotation: accept old and new for a while)."""
        out: list[bytes] = []
        swarm_key = self.swarm.key()
        if swarm_key is not None:
            out.append(swarm_key)
        for path in self.key_files:
            k = load_key(path)
            if k not in out:
                out.append(k)
        return tuple(out)

    def identity_material(self) -> IdentityMaterial | None:
        """Per-robot auth: this robot's private key and every robot's public keys
        (None in the other modes). Raises IdentityFileError (KeyFileError)."""
        if self.swarm.auth_mode != "per-robot":
            return None
        if self.identity_file is None:
            raise IdentityFileError(f"{self.source}: identity_file is not set")
        return IdentityMaterial(read_private_key(self.identity_file),
                                public_keys(self.swarm), self.swarm.revoked,
                                retired_keys(self.swarm))


def load_robot(path: str | Path) -> RobotConfig:
    """Read and validate a robot file and the swarm file it names.

    Raises ConfigUnreadable (robot file unreadable) or ConfigError (every problem of
    both files; those of the swarm file name the swarm file)."""
    return from_source(read_source(path))


def parse_robot(text: str, name: str = "<string>", path: Path | None = None) -> RobotConfig:
    """Like `load_robot` for YAML text; `path` anchors relative paths."""
    return from_source(parse_source(text, name, path))


def load_referenced_swarm(src: Source, name: str, problems: list[Problem]) -> SwarmConfig | None:
    """The swarm file a robot or base-station file names (`swarm:`), resolved relative to
    that file; its problems are appended to `problems` (None when it cannot be used)."""
    swarm_path = src.resolve(name)
    try:
        return load_swarm(swarm_path)
    except ConfigUnreadable as exc:
        reason = exc.problems[0].message if exc.problems else "unreadable"
        problems.append(src.problem(("swarm",), f"swarm file {swarm_path}: {reason}"))
    except ConfigError as exc:
        problems.extend(exc.problems)
    return None


def from_source(src: Source) -> RobotConfig:
    """Validate a parsed robot file and load its swarm file. Raises ConfigError."""
    _refuse_swarm_file(src)
    f: RobotFile = validate(RobotFile, src)
    problems: list[Problem] = []
    swarm = load_referenced_swarm(src, f.swarm, problems)
    if swarm is not None:
        if f.robot not in swarm.robot_ids():
            ids = ", ".join(map(str, swarm.robot_ids()))
            problems.append(
                src.problem(("robot",), f"robot {f.robot} is not in swarm file "
                            f"{swarm.source} (robots: {ids})")
            )
        problems.extend(swarm.warnings)
    identity_file = src.resolve(f.identity_file) if f.identity_file is not None else None
    if swarm is not None:
        problems = _deployable(swarm, f.robot, identity_file, src, problems)
    key_files = tuple(src.resolve(k) for k in f.key_files)
    _check_keys_and_metrics(f, key_files, src, problems)
    link = _resolved_link(f, src, swarm)
    if swarm is None or any(p.severity == "error" for p in problems):
        raise ConfigError(problems)
    return RobotConfig(
        robot=f.robot,
        swarm=swarm,
        swarm_path=src.resolve(f.swarm),
        transport=f.transport,
        link=link,
        event_log=src.resolve(f.event_log) if f.event_log is not None else None,
        state_dir=src.resolve(f.state_dir),
        handover_on_stop=f.handover_on_stop,
        metrics=f.metrics,
        key_files=key_files,
        source=src.name,
        warnings=tuple(p for p in problems if p.severity == "warning"),
        identity_file=identity_file,
    )


def _refuse_swarm_file(src: Source) -> None:
    """Raise ConfigError when `src` is a swarm file where a robot file belongs."""
    data = src.data
    if isinstance(data, dict) and "robots" in data and "robot" not in data:
        # A swarm file where a robot file belongs (`swarmd start -c paper.yaml`): one
        # clear problem instead of a schema error for every swarm-file field.
        raise ConfigError([src.problem((), "this is a swarm file (it has `robots:`); give "
                                       "a robot file that names it (`robot: <id>`, "
                                       "`swarm: <this file>`; docs/config.md)")])


def _check_keys_and_metrics(f: RobotFile, key_files: tuple[Path, ...], src: Source,
                            problems: list[Problem]) -> None:
    """Append a problem for each unreadable key file and for metrics served off this
    machine without `allow_remote`."""
    for i, k in enumerate(key_files):
        try:
            load_key(k)
        except KeyFileError as exc:
            problems.append(src.problem(("key_files", i), str(exc)))
    if f.metrics is not None and not f.metrics.allow_remote and not _is_loopback(f.metrics.host):
        problems.append(
            src.problem(("metrics", "host"), f"{f.metrics.host} is not a loopback address; "
                        "set `allow_remote: true` to serve metrics off this machine")
        )


def _resolved_link(f: RobotFile, src: Source, swarm: SwarmConfig | None) -> LinkConfig:
    """The robot file's link, its socket path resolved and a ros2 link's names filled."""
    link = f.link
    if isinstance(link, SocketLinkConfig):
        link = link.model_copy(update={"path": str(src.resolve(link.path))})
    elif isinstance(link, Ros2LinkConfig):
        swarm_name = (swarm.swarm.name or f"swarm{swarm.swarm.id}") if swarm else "swarm"
        namespace = link.namespace if link.namespace is not None \
            else ros2_namespace(swarm_name, f.robot)
        link = link.model_copy(update={
            "node_name": link.node_name or f"swarmd_robot{f.robot}",
            "hardware_id": link.hardware_id or f"robot{f.robot}",
            "namespace": namespace})
    return link


def ros2_namespace(swarm_name: str, robot: int) -> str:
    """/swarmd/<swarm>/robot<id>, the swarm's name made a valid ROS 2 name token
    (letters, digits, underscores; not starting with a digit)."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", swarm_name)
    if not token or token[0].isdigit():
        token = f"swarm_{token}"
    return f"/swarmd/{token}/robot{robot}"


def _deployable(swarm: SwarmConfig, robot: int, identity_file: Path | None, src: Source,
                problems: list[Problem]) -> list[Problem]:
    """The auth checks of a swarm a robot runs in (config/auth.py with `deploying`):
    an unsigned swarm that does not say so and a missing keys dir become errors (they
    replace the swarm file's warnings about the same field); per-robot mode needs
    this robot's private key, matching its public key, and the robot not revoked."""
    deploying = [Problem(swarm.source, format_loc(i.loc), i.message, i.severity)
                 for i in auth_issues(swarm, deploying=True) if i.severity == "error"]
    fields = {p.field for p in deploying}
    out = [p for p in problems
           if not (p.file == swarm.source and p.field in fields)] + deploying
    if swarm.auth_mode != "per-robot":
        if identity_file is not None:
            out.append(src.problem(("identity_file",), f"ignored: swarm {swarm.source} "
                                   f"is not signed per robot (auth: {swarm.auth_mode})",
                                   "warning"))
        return out
    if robot in swarm.revoked:
        out.append(src.problem(("robot",), f"robot {robot} is revoked in swarm file "
                               f"{swarm.source} (auth.revoked): no robot accepts its frames"))
        return out
    if any(p.severity == "error" for p in deploying):
        return out  # no keys dir: its message says how to make every key
    problem = _identity_problem(swarm, robot, identity_file, src)
    if problem is not None:
        out.append(problem)
    return out


def _identity_problem(swarm: SwarmConfig, robot: int, identity_file: Path | None,
                      src: Source) -> Problem | None:
    """Per-robot mode: what is wrong with this robot's private key, if anything."""
    keys_dir = swarm.keys_dir_path
    if identity_file is None:
        return src.problem(("identity_file",), f"swarm {swarm.source} is signed per "
                           "robot: set identity_file to this robot's private key "
                           f"(make it: swarmd keygen --robot {robot} {keys_dir})")
    try:
        private = read_private_key(identity_file)
    except KeyFileError as exc:
        return src.problem(("identity_file",),
                           str(exc).replace("--robot ID", f"--robot {robot}"))
    try:
        mine = public_keys(swarm).get(robot, ())
    except KeyFileError:
        return None  # reported by the swarm file's own checks
    if public_key_of(private) not in mine:
        return src.problem(("identity_file",), f"{identity_file} is not robot {robot}'s "
                           f"key: it does not match {keys_dir}/robot-{robot}.pub (a key "
                           "of another robot, or the .pub was not updated after "
                           "a new key was made)")
    return None


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
