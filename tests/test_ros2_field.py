"""ROS 2 in the field (docs/ros2.md, "In the field"): real `swarmd start` daemons with the
ros2 link and robot stacks written from the docs alone (tests/fixtures/ros2_stack.py),
each in its own process, on a ROS domain leased for the test.

The swarm is small (`swarms.ring_text`: three actives in a ring, one standby for all
three: the paper's rules with the fewest processes): start order, several swarms in one
domain, who may fault a robot, a daemon killed and restarted, a stack restarted, and
`swarmd sim --link ros2` in the user's domain. Each test waits for what must happen
with a bound; what must not happen (a robot leaving) is checked after a wait longer
than the health timeout it would need. Skipped only without rclpy (the `ros2` extra).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from swarms import ring_text

pytest.importorskip("rclpy", reason="needs the ros2 extra: pip install 'swarmd[ros2]'")

ROOT = Path(__file__).resolve().parent.parent
STACK = ROOT / "tests" / "fixtures" / "ros2_stack.py"
GROUP = "239.255.77.9"
FUNCTIONS = {1: "f1", 2: "f2", 3: "f3"}

pytestmark = pytest.mark.slow
WAIT = 90.0
"""s: how long a wait may take before the test fails. Generous: four daemons and their
rclpy stacks start beside the rest of the suite on two cores, and 30 s was seen to run
out; a wait ends as soon as its condition holds, so a healthy run does not pay it."""


def wait_until(check: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < end, f"not within {timeout:g} s: {what}"
        time.sleep(0.1)


class Field:
    """One swarm's daemons and stacks on the test's own domain and multicast port."""

    def __init__(self, tmp: Path, domain: int, name: str = "field", *,
                 health_timeout: float = 2.0) -> None:
        from sim.realtime.ports import PortLease

        self.dir, self.domain, self.name = tmp / name, domain, name
        self.port = PortLease(GROUP)
        (self.dir / "record").mkdir(parents=True)
        (self.dir / "control").mkdir()
        swarm = self.dir / "swarm.yaml"
        swarm.write_text(ring_text(name))
        self.files: dict[int, Path] = {}
        for r in (1, 2, 3, 4):
            doc = {"robot": r, "swarm": str(swarm),
                   "transport": {"kind": "udp", "group": GROUP, "port": self.port.port,
                                 "interface": "127.0.0.1", "ttl": 0, "loopback": True},
                   "link": {"kind": "ros2", "domain_id": domain,
                            "health_timeout": health_timeout},
                   "event_log": str(self.dir / f"events{r}.jsonl"),
                   "state_dir": str(self.dir / "state" / str(r))}
            self.files[r] = self.dir / f"robot{r}.yaml"
            self.files[r].write_text(yaml.safe_dump(doc))
        self.daemons: dict[int, subprocess.Popen[bytes]] = {}
        self.stacks: list[subprocess.Popen[bytes]] = []
        self.env = {**os.environ, "PYTHONPATH": str(ROOT), "ROS_DOMAIN_ID": str(domain),
                    "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

    def start_daemon(self, robot: int) -> None:
        log = (self.dir / f"daemon{robot}.log").open("ab")
        self.daemons[robot] = subprocess.Popen(
            [sys.executable, "-m", "swarmd.cli", "start", "--config", str(self.files[robot]),
             "--log-format", "json"], stdout=log, stderr=subprocess.STDOUT, env=self.env)

    def start_stacks(self, *robots: int, attacker: str | None = None,
                     swarm: str | None = None) -> subprocess.Popen[bytes]:
        args = ["--attacker", attacker] if attacker else [
            "--robots", ",".join(map(str, robots))]
        proc = subprocess.Popen(
            [sys.executable, str(STACK), "--swarm", swarm or self.name,
             "--record", str(self.dir / "record"), "--control", str(self.dir / "control"),
             "--seconds", "120", *args], env=self.env)
        self.stacks.append(proc)
        return proc

    def set_health(self, robot: int, level: int) -> None:
        (self.dir / "control" / f"robot{robot}.health").write_text(str(level))

    def events(self, robot: int) -> list[dict[str, Any]]:
        path = self.dir / f"events{robot}.jsonl"
        if not path.exists():
            return []
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]

    def record(self, robot: int) -> list[dict[str, Any]]:
        path = self.dir / "record" / f"robot{robot}.jsonl"
        if not path.exists():
            return []
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]

    def flying(self, robot: int) -> str | None:
        """What robot's stack executes now (None: no stack record yet)."""
        entries = [e for e in self.record(robot) if e["kind"] == "flying"]
        return entries[-1]["function"] if entries else None

    def all_fly_their_function(self) -> bool:
        return all(self.flying(r) == f for r, f in FUNCTIONS.items())

    def each_function_flown_once(self) -> bool:
        """f1, f2 and f3 each executed by exactly one stack, whoever holds it (a daemon
        started late on a loaded machine may have lost its slot at the start, which is
        the start-up grace's business, docs/operations.md, not the link's)."""
        flying = [self.flying(r) for r in (1, 2, 3, 4)]
        return all(flying.count(f) == 1 for f in FUNCTIONS.values())

    def leaves(self) -> list[dict[str, Any]]:
        return [e for r in self.daemons for e in self.events(r) if e["event"] == "leave"]

    def kill(self, proc: subprocess.Popen[bytes], sig: int = signal.SIGKILL) -> None:
        if proc.poll() is None:
            proc.send_signal(sig)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def close(self) -> None:
        for proc in [*self.daemons.values(), *self.stacks]:
            self.kill(proc, signal.SIGTERM)
        self.port.release()


@pytest.fixture
def domain() -> Iterator[int]:
    from sim.realtime.ros2_robot import DomainLease

    lease = DomainLease()
    yield lease.domain_id
    lease.release()


@pytest.fixture
def field(tmp_path: Path, domain: int) -> Iterator[Field]:
    f = Field(tmp_path, domain)
    yield f
    f.close()


def test_stacks_that_boot_after_their_daemons_are_waited_for(field: Field) -> None:
    """A slow boot: the stacks come up well past health_timeout (2 s) after the
    daemons. Nobody leaves, and every function is then executed, once."""
    for r in (1, 2, 3, 4):
        field.start_daemon(r)
    wait_until(lambda: all(field.events(r) for r in (1, 2, 3, 4)), WAIT, "daemons started")
    time.sleep(4.0)  # twice health_timeout with no stack at all
    field.start_stacks(1, 2, 3, 4)
    wait_until(field.each_function_flown_once, WAIT, "each function executed once")
    assert field.leaves() == []


def test_stacks_that_are_up_before_their_daemons_never_make_them_leave(
        field: Field) -> None:
    """Start order does not matter: DDS discovery took seconds on a loaded machine,
    and a daemon counts its robot's silence only once it was heard."""
    stacks = field.start_stacks(1, 2, 3, 4)
    wait_until(lambda: all(field.record(r) for r in (1, 2, 3, 4)), WAIT, "stacks up")
    assert stacks.poll() is None
    for r in (1, 2, 3, 4):
        field.start_daemon(r)
    wait_until(field.each_function_flown_once, WAIT, "each function executed once")
    time.sleep(2.5)  # more than health_timeout with every stack publishing
    assert field.leaves() == []


START_TRIES = 3
"""Starts of a field a test may discard (`started`)."""


def started(tmp: Path, domain: int, *, health_timeout: float = 2.0,
            alone: int | None = None) -> tuple[Field, subprocess.Popen[bytes] | None]:
    """A field of robots 1-4, stacks and daemons up, each robot executing its own function
    (robot `alone`'s stack in a process of its own, which is returned). On a loaded
    machine a daemon may start so late that standby 4 took its slot at the start: the
    start-up grace's business (docs/operations.md), not what these tests are about, so
    such a start is discarded and the field started anew, as bench_ros2_field.py
    discards it, at most START_TRIES times."""
    for attempt in range(START_TRIES):
        field = Field(tmp, domain, f"field{attempt}", health_timeout=health_timeout)
        others = [r for r in (1, 2, 3, 4) if r != alone]
        field.start_stacks(*others)
        own = field.start_stacks(alone) if alone is not None else None
        for r in (1, 2, 3, 4):
            field.start_daemon(r)
        wait_until(field.each_function_flown_once, WAIT, "each function executed once")
        if field.all_fly_their_function():
            return field, own
        field.close()
    raise AssertionError(f"{START_TRIES} starts in a row moved a function at the start")


def test_a_daemon_killed_and_restarted_after_a_takeover_releases_its_robot(
        tmp_path: Path, domain: int) -> None:
    """Robot 2's daemon is SIGKILLed while holding f2; standby 4 takes f2; the daemon
    restarts (now a standby) and tells its robot to release before anything else:
    exactly one stack executes f2 at the end."""
    field, _ = started(tmp_path, domain)
    try:
        _kill_and_restart_daemon(field)
    finally:
        field.close()


def _kill_and_restart_daemon(field: Field) -> None:
    field.kill(field.daemons[2])
    wait_until(lambda: any(e["event"] == "takeover" and e["function"] == "f2"
                           for e in field.events(4)), WAIT, "robot 4 takes f2")
    boots = {e.get("boot") for e in field.record(2) if e["kind"] == "assignment"}
    field.start_daemon(2)
    wait_until(lambda: sum(e["event"] == "started" for e in field.events(2)) >= 2, WAIT,
               "robot 2's daemon restarted")
    wait_until(lambda: any(e["kind"] == "assignment" and e.get("boot") not in boots
                           for e in field.record(2)), WAIT, "the restarted daemon speaks")
    first = next(e for e in field.record(2) if e["kind"] == "assignment"
                 and e.get("boot") not in boots)
    assert (first["action"], first["function"]) == ("hold", "")
    wait_until(lambda: field.flying(4) == "f2", WAIT, "robot 4's stack executes f2")
    assert [r for r in (1, 2, 3, 4) if field.flying(r) == "f2"] == [4]


def test_a_stack_restarted_at_once_gets_one_consistent_assignment(
        tmp_path: Path, domain: int) -> None:
    """Robot 2's stack dies and is restarted 0.2 s later: it gets its whole assignment
    in one message (function, action, seq, boot, lease) and executes f2 again. A
    Python stack takes about 2 s to start here, so health_timeout is 6 s (docs/ros2.md:
    above the time the stack takes to restart)."""
    field, two = started(tmp_path, domain, health_timeout=6.0, alone=2)
    try:
        assert two is not None
        _restart_stack(field, two)
    finally:
        field.close()


def _restart_stack(field: Field, two: subprocess.Popen[bytes]) -> None:
    field.kill(two)
    before = len(field.record(2))
    time.sleep(0.2)
    field.start_stacks(2)
    wait_until(lambda: any(e["kind"] == "assignment" for e in field.record(2)[before:]),
               30, "the new stack's assignment")
    after = field.record(2)[before:]
    got = next(e for e in after if e["kind"] == "assignment")
    assert (got["function"], got["action"]) == ("f2", "execute")
    assert int(got["seq"]) >= 1 and float(got["lease"]) > 0 and got["boot"]
    assert (got["frame_id"], float(got["y"])) == ("map", 2.0)
    assert [e["function"] for e in after if e["kind"] == "flying"] == ["f2"]
    assert field.leaves() == []


def test_the_same_robot_of_another_swarm_in_the_domain_never_faults_this_one(
        tmp_path: Path, domain: int) -> None:
    """Two swarms in one domain: swarm alpha's robot 2 reports ERROR; swarm beta's
    robot 2 (its stack OK) neither leaves nor flaps."""
    beta = Field(tmp_path, domain, name="beta")
    try:
        beta.start_stacks(2)
        beta.set_health(2, 0)
        alpha_dir = tmp_path / "alpha"
        (alpha_dir / "control").mkdir(parents=True)
        (alpha_dir / "record").mkdir()
        (alpha_dir / "control" / "robot2.health").write_text("2")
        beta.stacks.append(subprocess.Popen(
            [sys.executable, str(STACK), "--swarm", "alpha", "--robots", "2", "--record",
             str(alpha_dir / "record"), "--control", str(alpha_dir / "control"),
             "--seconds", "120"], env=beta.env))
        beta.start_daemon(2)
        wait_until(lambda: beta.flying(2) == "f2", WAIT, "beta's robot 2 executes f2")
        time.sleep(3.0)  # past health_timeout, alpha's ERROR twice a second
        assert beta.leaves() == []
        assert beta.flying(2) == "f2"
    finally:
        beta.close()


def test_a_node_outside_the_robots_namespace_cannot_fault_it(field: Field) -> None:
    """Any node in the domain publishing ERROR with hardware_id robot3 is not robot
    3's health: robot 3 keeps f3."""
    field.start_stacks(3)
    field.start_daemon(3)
    wait_until(lambda: field.flying(3) == "f3", WAIT, "robot 3 executes f3")
    field.start_stacks(attacker="robot3")
    time.sleep(3.5)  # past health_timeout, the forged ERROR 3 times a second
    assert field.leaves() == []
    assert field.flying(3) == "f3"


def test_sim_with_ros2_runs_in_the_users_domain(tmp_path: Path, domain: int) -> None:
    """`ROS_DOMAIN_ID=D swarmd sim --link ros2`: the swarm's statuses are on D, and the
    run says so and how to watch it."""
    from diagnostic_msgs.msg import DiagnosticArray

    from swarmd.link.ros2_node import RosThread

    heard: list[str] = []
    listener = RosThread("field_listener", domain_id=domain)
    listener.start(lambda node: node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda msg: heard.extend(s.name for s in msg.status), 50))
    try:
        done = subprocess.run(
            [sys.executable, "-m", "swarmd.cli", "sim", str(ROOT / "configs" / "paper.yaml"),
             "--link", "ros2", "--no-physics", "--duration", "8", "--report",
             str(tmp_path / "out"), "--json"], capture_output=True, text=True, timeout=180,
            env={**os.environ, "PYTHONPATH": str(ROOT), "ROS_DOMAIN_ID": str(domain)})
    finally:
        listener.stop()
    # Exit 1 is a run the loaded machine could not keep up with (its summary says so);
    # what this checks is where the swarm ran.
    assert done.returncode in (0, 1), done.stderr[-2000:]
    assert f"ROS 2 domain {domain} (from ROS_DOMAIN_ID)" in done.stderr
    assert "ros2 topic echo /diagnostics" in done.stderr
    assert "swarmd/paper/f2" in heard


def test_the_docs_robot_node_runs_as_written(tmp_path: Path, domain: int) -> None:
    """The rclpy node of docs/ros2.md ("A robot-side node"), run as printed beside robot
    2's daemon of a swarm named `paper`: its health counts and it executes f2."""
    import re

    text = (ROOT / "docs" / "ros2.md").read_text()
    section = text[text.index("## A robot-side node"):text.index("## In the field")]
    code = re.search(r"```python\n(.*?)```", section, re.S)
    assert code is not None
    node = tmp_path / "robot_node.py"
    node.write_text(code.group(1))
    field = Field(tmp_path, domain, name="paper")
    try:
        out = (tmp_path / "node.log").open("wb")
        field.stacks.append(subprocess.Popen([sys.executable, str(node)], stdout=out,
                                             stderr=subprocess.STDOUT, env=field.env))
        field.start_daemon(2)
        wait_until(lambda: "execute f2" in (tmp_path / "node.log").read_text(), WAIT,
                   "the docs' node executes f2")
        found = "robot health publisher found: /swarmd/paper/robot2/robot_stack"
        wait_until(lambda: found in (field.dir / "daemon2.log").read_text(), WAIT,
                   "the daemon finds the docs' node")
        time.sleep(2.5)  # past health_timeout: its statuses keep the robot healthy
        assert field.leaves() == []
    finally:
        field.close()
