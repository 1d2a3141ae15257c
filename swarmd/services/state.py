"""Persisted state of one robot: the epochs it knows, what it held, its sequence reservation.

Why it exists (DESIGN rule 2): a robot that crashes while executing a
function and reboots must not resume that function if a standby took it over meanwhile.
So the daemon writes, on every role / function / epoch change, what it knows; on restart
it hands that to the core as `Restored(known, held)` and the node listens for
`rejoin_hold` before resuming.

The sequence number high-water mark closes a second hole: frames carry a per-sender seq
seeded from the wall clock (`swarmd.core.wire.seq_seed`) and receivers drop anything not
above the last seen. A robot whose clock went backwards across a reboot would be ignored
until its clock caught up. So the daemon persists `seq_reserved`, a value above every seq
it may have sent, and starts at `max(seq_seed(now), seq_reserved)`.

File format (JSON, one object)::

    {"version": 1, "robot": 2, "swarm": 1543,
     "known": {"f1": [1, 0], "f2": [6, 1]},   # function -> [holder, epoch]
     "held": ["f2", 1] | null,                # what this robot executed
     "seq_reserved": 123456789,
     "peer_seq": {"1": 4711, ...},            # robot -> highest seq accepted from it
     "certificate": ["<hex>", ...]}           # signed frames proving `held` (per-robot)

Writes are atomic: a temporary file in the same directory, fsync, os.replace, fsync of the
directory. A reader therefore sees the old file or the new one, never half of one. A
write interrupted before its rename (SIGKILL, power cut) leaves its temporary file; the
next start removes those of this robot (`clean_stale_tmp`).

Reading trusts nothing: only a regular file of at most `MAX_STATE_BYTES`; epochs,
holders, functions and the seq reservation are checked against the wire's ranges and the
swarm plan (`swarmd.core.limits`); any failure at all while reading (deep nesting, a
number of thousands of digits, ...) is a `StateError`, and the daemon sets the file aside
and starts fresh (docs/daemon.md).
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarmd.base.files import FileRefused, read_regular_file
from swarmd.core.limits import restored_problems
from swarmd.core.node import Restored, Snapshot
from swarmd.core.plan import SwarmPlan
from swarmd.core.roles import Role
from swarmd.core.wire import SEQ_MAX

FORMAT_VERSION = 1

SEQ_RESERVE = 1_000_000
"""How far ahead of the current seq a reservation reaches. At 10 Hz heartbeats this is a
rewrite of the file about once a day, and covers any burst of frames in between."""


MAX_STATE_BYTES = 256 * 1024
"""A state file of 255 functions is under 8 kB."""


class StateError(Exception):
    """The state file exists but cannot be used. The message says which file and why."""


class StateWriteError(OSError):
    """The state file could not be written (disk full, directory gone, read-only file
    system); the message names the file."""


@dataclass(frozen=True, slots=True)
class PersistedState:
    """What one robot persists; see the module docstring."""

    robot: int
    swarm: int
    known: Mapping[str, tuple[int, int]] = field(default_factory=dict)
    held: tuple[str, int] | None = None
    seq_reserved: int = 0
    peer_seq: Mapping[int, int] = field(default_factory=dict)
    """Peers' highest accepted seq: frames captured before a restart stay replays."""
    certificate: tuple[bytes, ...] = ()
    """The frames that certify `held` (every auth mode); the core verifies them again
    on restore."""

    def restored(self) -> Restored:
        """The core's view of it (`Node(..., restored=...)`)."""
        return Restored(known=dict(self.known), held=self.held,
                        peer_seq=dict(self.peer_seq), certificate=self.certificate)

    def to_json(self) -> dict[str, Any]:
        return {
            "version": FORMAT_VERSION,
            "robot": self.robot,
            "swarm": self.swarm,
            "known": {f: [h, e] for f, (h, e) in sorted(self.known.items())},
            "held": list(self.held) if self.held is not None else None,
            "seq_reserved": self.seq_reserved,
            "peer_seq": {str(r): q for r, q in sorted(self.peer_seq.items())},
            "certificate": [c.hex() for c in self.certificate],
        }


def state_path(state_dir: Path, swarm_id: int, robot_id: int) -> Path:
    """One file per (swarm, robot), so several daemons may share a state directory."""
    return Path(state_dir) / f"swarm{swarm_id}-robot{robot_id}.json"


def _int(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{what} must be a non-negative integer, got {value!r}")
    return value


def parse(data: Any, *, robot: int, swarm: int, plan: SwarmPlan | None = None) -> PersistedState:
    """Validate a decoded JSON object against the wire's ranges and, with `plan`, the
    swarm's robots. Raises ValueError saying what is wrong."""
    if not isinstance(data, dict):
        raise ValueError("top level is not a JSON object")
    if data.get("version") != FORMAT_VERSION:
        raise ValueError(f"version {data.get('version')!r}, expected {FORMAT_VERSION}")
    if data.get("robot") != robot or data.get("swarm") != swarm:
        raise ValueError(
            f"file is for robot {data.get('robot')!r} of swarm {data.get('swarm')!r}, "
            f"this daemon is robot {robot} of swarm {swarm}"
        )
    known = _known(data.get("known", {}))
    held = _held(data.get("held"))
    seq = _int(data.get("seq_reserved", 0), "seq_reserved")
    if seq > SEQ_MAX - SEQ_RESERVE:
        # Every frame would be sent with a seq receivers already saw (a mute robot).
        raise ValueError(f"seq_reserved {seq} leaves no room below the 48-bit maximum")
    peer_seq = _peer_seq(data.get("peer_seq", {}))
    certificate = _certificate(data.get("certificate", []))
    problems = restored_problems(known, held)
    if plan is not None:
        # A holder the swarm does not have: a foreign or corrupt file. (A function the
        # swarm file no longer has is fine: the node ignores its entries.)
        problems += [f"known[{f!r}] holder {h} is not a robot of the swarm"
                     for f, (h, _) in known.items() if h != 0 and h not in plan.robots]
    if problems:
        raise ValueError("; ".join(problems))
    if plan is not None:  # a robot since removed from the swarm file: forget it
        peer_seq = {r: q for r, q in peer_seq.items() if r in plan.robots}
    return PersistedState(robot=robot, swarm=swarm, known=known, held=held, seq_reserved=seq,
                          peer_seq=peer_seq, certificate=tuple(certificate))


def _known(known_raw: Any) -> dict[str, tuple[int, int]]:
    """`known`: function -> [holder, epoch]."""
    if not isinstance(known_raw, dict):
        raise ValueError("'known' is not an object")
    known: dict[str, tuple[int, int]] = {}
    for f, pair in known_raw.items():
        if not isinstance(pair, list) or len(pair) != 2:
            raise ValueError(f"known[{f!r}] is not [holder, epoch]")
        known[f] = (_int(pair[0], f"known[{f!r}] holder"), _int(pair[1], f"known[{f!r}] epoch"))
    return known


def _held(held_raw: Any) -> tuple[str, int] | None:
    """`held`: [function, epoch], or null."""
    if held_raw is None:
        return None
    if (not isinstance(held_raw, list) or len(held_raw) != 2
            or not isinstance(held_raw[0], str)):
        raise ValueError("'held' is not [function, epoch] or null")
    return (held_raw[0], _int(held_raw[1], "held epoch"))


def _peer_seq(peer_raw: Any) -> dict[int, int]:
    """`peer_seq`: robot id -> the highest sequence number accepted from it."""
    if not isinstance(peer_raw, dict):
        raise ValueError("'peer_seq' is not an object")
    peer_seq: dict[int, int] = {}
    for r, q in peer_raw.items():
        if not isinstance(r, str) or not r.isdigit() or len(r) > 5:
            raise ValueError(f"peer_seq key {r!r} is not a robot id")
        value = _int(q, f"peer_seq[{r}]")
        if value > SEQ_MAX:
            raise ValueError(f"peer_seq[{r}] {value} does not fit 48 bits")
        peer_seq[int(r)] = value
    return peer_seq


def _certificate(cert_raw: Any) -> list[bytes]:
    """`certificate`: the signed frames proving `held`, as hex strings."""
    if not isinstance(cert_raw, list) or len(cert_raw) > 64:
        raise ValueError("'certificate' is not a list of at most 64 frames")
    certificate: list[bytes] = []
    for c in cert_raw:
        if not isinstance(c, str) or len(c) > 512:
            raise ValueError("a certificate frame is not a hex string")
        certificate.append(bytes.fromhex(c))
    return certificate


def load(path: Path, *, robot: int, swarm: int,
         plan: SwarmPlan | None = None) -> PersistedState | None:
    """Read the state file. None when there is none (first start); StateError when it is
    unreadable or corrupt (the caller logs it, sets the file aside and starts fresh)."""
    try:
        raw = read_regular_file(path, MAX_STATE_BYTES)
    except FileNotFoundError:
        return None
    except FileRefused as exc:
        raise StateError(f"{path}: state file {exc.reason}") from exc
    except OSError as exc:
        raise StateError(f"{path}: cannot read state file: {exc}") from exc
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:  # binary garbage (a disk error, a wrong file)
        raise StateError(f"{path}: state file is not UTF-8 text ({exc.reason} at byte "
                         f"{exc.start})") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StateError(f"{path}: state file is not valid JSON ({exc})") from exc
    except RecursionError as exc:
        raise StateError(f"{path}: state file is nested too deeply") from exc
    except ValueError as exc:  # e.g. an integer beyond Python's 4300-digit limit
        raise StateError(f"{path}: state file is not usable JSON ({exc})") from exc
    try:
        return parse(data, robot=robot, swarm=swarm, plan=plan)
    except ValueError as exc:
        raise StateError(f"{path}: state file is invalid: {exc}") from exc


def clean_stale_tmp(path: Path) -> list[Path]:
    """Remove the temporary files of interrupted writes of `path` (`save`'s
    `.<name>.*.tmp`); other robots' files in a shared directory are left alone. Returns
    what was removed."""
    path = Path(path)
    removed: list[Path] = []
    try:
        candidates = list(path.parent.glob(f".{glob.escape(path.name)}.*.tmp"))
    except OSError:
        return removed
    for tmp in candidates:
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed.append(tmp)
    return removed


def set_aside(path: Path) -> Path | None:
    """Rename a corrupt state file to `<name>.corrupt-<unix time>` so that it can be
    inspected; returns the new path (None if it could not be moved)."""
    target = Path(f"{path}.corrupt-{int(time.time())}")
    try:
        os.replace(path, target)
    except OSError:
        return None
    return target


def save(path: Path, state: PersistedState) -> None:
    """Write atomically (temp file + fsync + os.replace + directory fsync). Raises OSError;
    the runtime counts and logs it and keeps running."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = json.dumps(state.to_json(), separators=(",", ":")) + "\n"
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    # The rename itself must survive a power cut: fsync the directory entry.
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def initial_seq(now_seq: int, persisted: PersistedState | None) -> int:
    """First sequence number: above the wall-clock seed and above every seq this robot
    may have used before (a reservation survives a clock that went backwards)."""
    reserved = persisted.seq_reserved if persisted is not None else 0
    return max(now_seq, reserved)


class StateFile:
    """The daemon's handle on its state file: remembers the reservation and turns core
    snapshots into `PersistedState` writes (used as the runtime's `state_writer`)."""

    def __init__(self, path: Path, *, robot: int, swarm: int,
                 plan: SwarmPlan | None = None) -> None:
        self.path = Path(path)
        self.robot = robot
        self.swarm = swarm
        self.plan = plan
        self.seq_reserved = 0

    def load(self) -> PersistedState | None:
        """`load()` of this file (raises StateError when unusable), after removing the
        temporary files of interrupted writes."""
        clean_stale_tmp(self.path)
        try:
            return load(self.path, robot=self.robot, swarm=self.swarm, plan=self.plan)
        except StateError:
            raise
        except Exception as exc:  # anything at all: the robot must still start fresh
            raise StateError(f"{self.path}: state file could not be read: "
                             f"{type(exc).__name__}: {exc}") from exc

    def write_initial(self, persisted: PersistedState | None, seq_start: int) -> int:
        """At start-up: keep what was persisted, reserve sequence numbers from
        `seq_start` before the first frame goes out. Returns the seq at which the next
        write is due (the runtime's `seq_write_at`)."""
        self.seq_reserved = seq_start + SEQ_RESERVE
        base = persisted or PersistedState(robot=self.robot, swarm=self.swarm)
        self._save(PersistedState(robot=self.robot, swarm=self.swarm, known=base.known,
                                  held=base.held, seq_reserved=self.seq_reserved,
                                  peer_seq=base.peer_seq, certificate=base.certificate))
        return self.seq_reserved - SEQ_RESERVE // 2

    def write_snapshot(self, snap: Snapshot) -> int:
        """Persist a core snapshot; `held` is the function while ACTIVE (rule 2: only a
        function the robot was executing is ever resumed, after the rejoin hold)."""
        held = (snap.function, snap.epoch) if snap.role == Role.ACTIVE and snap.function else None
        if snap.seq + SEQ_RESERVE // 2 >= self.seq_reserved:
            self.seq_reserved = min(SEQ_MAX, snap.seq + SEQ_RESERVE)
        self._save(PersistedState(robot=self.robot, swarm=self.swarm, known=snap.known,
                                  held=held, seq_reserved=self.seq_reserved,
                                  peer_seq=snap.peer_seq,
                                  certificate=snap.certificate if held else ()))
        return self.seq_reserved - SEQ_RESERVE // 2

    def _save(self, state: PersistedState) -> None:
        try:
            save(self.path, state)
        except OSError as exc:
            raise StateWriteError(f"{self.path}: cannot write the state file: "
                                  f"{exc.strerror or exc}") from exc
