"""The `ros2` robot link (docs/ros2.md): health in from /diagnostics, the function out as
a goal pose and a name, the swarm's view on /diagnostics.

The pure parts (the health fold, the swarm statuses) on plain data; then one real-time
run of the paper's swarm with `--link ros2` (six robot processes, each its daemon's rclpy
node and a small rclpy robot stack), watched by a real rclpy listener in this process on
the run's own ROS domain. Skipped only when rclpy (the `ros2` extra) is not installed;
`make` installs it.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from sim.realtime.orchestrator import run_realtime_async
from sim.run import SimError, SimOptions
from sim.shared.faults import parse_fault
from swarmd.config import load_swarm
from swarmd.core.events import Alert, AlertCause
from swarmd.core.records import Holder, Snapshot
from swarmd.core.roles import Health, Role
from swarmd.link.ros2_health import HealthFold
from swarmd.link.ros2_status import ERROR, OK, STALE, WARN, SwarmStatus

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"


# -- pure parts ------------------------------------------------------------------------------
def test_the_worst_fresh_level_of_the_robots_own_statuses_decides() -> None:
    fold = HealthFold((), "robot2", timeout=2.0)
    assert fold.level(0.0) == STALE  # nothing heard: a fault
    stack = "/swarmd/paper/robot2/stack"
    assert fold.hear(stack, "robot2/battery", "robot2", OK, 0.0)
    assert not fold.hear(stack, "robot3/battery", "robot3", ERROR, 0.0)  # another robot's
    assert not fold.hear(stack, "swarmd/paper/f2", "robot2", ERROR, 0.0)  # the swarm's view
    assert fold.hear(stack, "robot2/motors", "robot2", WARN, 0.5)
    assert fold.level(1.0) == WARN
    assert fold.hear(stack, "robot2/motors", "robot2", OK, 1.0)
    assert fold.level(1.5) == OK
    assert fold.level(3.5) == STALE  # no status within the timeout


def test_health_names_select_statuses_whatever_their_hardware_id() -> None:
    fold = HealthFold(("flight",), "robot2", timeout=1.0)
    assert not fold.hear("/r2/px4", "battery", "robot2", ERROR, 0.0)
    assert fold.hear("/r2/px4", "flight", "px4", ERROR, 0.0)
    assert fold.level(0.5) == ERROR


def _snap(**kw: Any) -> Snapshot:
    base: dict[str, Any] = dict(
        robot_id=1, role=Role.ACTIVE, function="f1", epoch=0, health=Health.OK,
        known={f: Holder(i + 1, 0) for i, f in enumerate(("f1", "f2", "f3", "f4"))},
        suspects={}, votes={}, drops={}, seq=0, heard={2: 10.0, 4: 10.0})
    base.update(kw)
    return Snapshot(**base)


def test_swarm_statuses_name_the_holder_and_say_ok_warn_error_stale() -> None:
    cfg = load_swarm(PAPER)
    view = SwarmStatus(cfg.to_plan(), 1, "paper", t_max=0.5)
    assert "f3" not in view.functions  # robot 1 does not hear f3's slot
    by_name = {s.name: s for s in view.statuses(_snap(), 10.2)}
    f2 = by_name["swarmd/paper/f2"]
    assert (f2.level, f2.hardware_id, dict(f2.values)) == (
        OK, "robot1", {"holder": "2", "epoch": "0", "role": "active"})
    assert by_name["swarmd/paper/f1"].level == OK  # its own
    assert by_name["swarmd/paper/robot1"].level == OK
    by_name = {s.name: s for s in view.statuses(_snap(suspects={"f2": 2}), 10.7)}
    assert by_name["swarmd/paper/f2"].level == WARN
    assert by_name["swarmd/paper/f4"].level == STALE  # 4 not heard for 0.7 s > t_max
    view.on_event(Alert("f4", AlertCause.NO_STANDBY))
    assert {s.name: s.level for s in view.statuses(_snap(), 10.2)}["swarmd/paper/f4"] == ERROR
    # A new holder answers the alert.
    after = _snap(known={"f1": Holder(1, 0), "f2": Holder(2, 0), "f4": Holder(5, 1)},
                  heard={2: 10.0, 5: 10.0})
    f4 = {s.name: s for s in view.statuses(after, 10.2)}["swarmd/paper/f4"]
    assert f4.level == OK and dict(f4.values)["holder"] == "5"


def test_ros2_options() -> None:
    assert SimOptions(swarm=PAPER, link="ros2").robot_link == "ros2-quad"
    assert SimOptions(swarm=PAPER, link="ros2", physics=False).robot_link == "ros2-bare"
    with pytest.raises(SimError, match="--link: ros2 runs real processes"):
        SimOptions(swarm=PAPER, link="ros2", virtual=True)


def test_domain_leases_are_exclusive_and_leave_nothing_behind() -> None:
    """A leased id is nobody else's until released (another run, another test worker:
    those may hold ids now, so this takes two, not all), and leasing writes no file."""
    import socket
    import tempfile

    from sim.realtime.ros2_robot import DomainLease

    tmp = Path(tempfile.gettempdir())
    before = set(tmp.iterdir())
    first, second = DomainLease(), DomainLease()
    assert first.domain_id != second.domain_id
    name = f"\0swarmd-ros2-domain-{first.domain_id}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as rival, pytest.raises(OSError):
        rival.bind(name)  # what a third lease would try
    first.release()
    first.release()  # idempotent
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as rival:
        rival.bind(name)  # free again
    second.release()
    assert {p for p in set(tmp.iterdir()) - before if "swarmd-ros2-domain" in p.name} == set()


async def test_a_blocked_ros_thread_never_blocks_the_loop() -> None:
    pytest.importorskip("rclpy", reason="needs the ros2 extra: pip install 'swarmd[ros2]'")
    import threading

    from sim.realtime.ros2_robot import DomainLease
    from swarmd.link.ros2_node import RosThread

    lease = DomainLease()
    ros = RosThread("blocked", domain_id=lease.domain_id)
    gate, done = threading.Event(), threading.Event()

    def stuck(_node: Any) -> None:  # a callback stuck in the executor thread
        gate.wait(30)

    try:
        await asyncio.to_thread(ros.start, lambda node: None)
        ros.call(stuck)
        ros.call(lambda node: done.set())
        turns = 0
        for _ in range(5):  # the loop keeps turning while rclpy is stuck
            await asyncio.sleep(0.01)
            turns += 1
        assert turns == 5 and not done.is_set()
        gate.set()
        assert await asyncio.to_thread(done.wait, 30)  # the queue runs on once unstuck
    finally:
        gate.set()
        await asyncio.to_thread(ros.stop)
        lease.release()


# -- real processes --------------------------------------------------------------------------
class Listener:
    """A real rclpy node on the run's domain: every swarm status on /diagnostics, and
    later (`join_late`) the latched function and goal topics of some robots."""

    def __init__(self, domain: int) -> None:
        from swarmd.link.ros2_node import RosThread

        self.ros = RosThread("test_listener", domain_id=domain)
        self.statuses: list[tuple[float, str, str, int, dict[str, str]]] = []
        self.late: dict[str, list[Any]] = {}

    def start(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        from swarmd.link.ros2 import level_of

        def on_diag(msg: Any) -> None:
            now = time.time()
            for s in msg.status:
                if s.name.startswith("swarmd/"):
                    self.statuses.append((now, s.name, s.hardware_id, level_of(s),
                                          {kv.key: kv.value for kv in s.values}))

        self.ros.start(lambda node: node.create_subscription(DiagnosticArray, "/diagnostics",
                                                             on_diag, 100))

    def join_late(self, robot: int) -> None:
        from geometry_msgs.msg import PoseStamped
        from std_msgs.msg import String

        from swarmd.link.ros2 import latched_qos

        def subscribe(node: Any) -> None:
            for topic, kind, read in (
                    ("swarmd/function", String, lambda m: m.data),
                    ("swarmd/goal_pose", PoseStamped, lambda m: (
                        m.header.frame_id, m.pose.position.x, m.pose.position.y,
                        m.pose.position.z))):
                name = f"/swarmd/paper/robot{robot}/{topic}"
                got = self.late.setdefault(name, [])
                node.create_subscription(kind, name, lambda m, g=got, r=read: g.append(r(m)),
                                         latched_qos())

        self.ros.call(subscribe)

    def holders(self, function: str, publisher: str) -> list[str]:
        """The holders of `function` as `publisher` showed them, changes only."""
        out: list[str] = []
        for _, name, hw, _, values in self.statuses:
            if name == f"swarmd/paper/{function}" and hw == publisher \
                    and (not out or out[-1] != values["holder"]):
                out.append(values["holder"])
        return out


async def _wait_for(path: Path, timeout: float) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        assert time.monotonic() < end, f"{path} never written"
        await asyncio.sleep(0.05)


@pytest.mark.slow
async def test_ros2_swarm_health_in_goal_out_and_the_swarm_on_diagnostics(
        tmp_path: Path) -> None:
    pytest.importorskip("rclpy", reason="needs the ros2 extra: pip install 'swarmd[ros2]'")
    crash, unhealthy = 4.0, 4.0
    # The run and the monitor last well past the takeover (about crash + 1.5 s): robot 1's
    # next status, and the monitor's view of it, must reach them before the run ends, and
    # on a loaded machine (tests in parallel) ROS delivery can take seconds; with 7 s
    # both had about 1.4 s to spare.
    duration = 12.0
    run = asyncio.create_task(run_realtime_async(
        PAPER, duration=duration, physics=False, link="ros2-bare", report_dir=tmp_path,
        faults=[parse_fault(f"crash:2@{crash:g}"), parse_fault(f"unhealthy:4@{unhealthy:g}")]))
    robot_file = tmp_path / "realtime" / "robots" / "robot1.yaml"
    await _wait_for(robot_file, 60)
    domain = yaml.safe_load(robot_file.read_text())["link"]["domain_id"]
    listener = Listener(domain)
    await asyncio.to_thread(listener.start)
    # The base station: `swarmd monitor --ros2` on the run's channel and domain.
    monitor = subprocess.Popen(
        [sys.executable, "-m", "swarmd.cli", "monitor", "--config", str(robot_file), "--once",
         "--json", "--duration", f"{duration:g}", "--ros2"], stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, cwd=ROOT,
        env={**os.environ, "ROS_DOMAIN_ID": str(domain), "PYTHONPATH": str(ROOT)})
    try:
        # Join late, once robot 6 has taken f2 over (as its neighbours show it).
        end = time.monotonic() + 60
        while "6" not in listener.holders("f2", "robot1"):
            assert not run.done() and time.monotonic() < end, "no f2 takeover shown"
            await asyncio.sleep(0.1)
        listener.join_late(6)
        listener.join_late(1)
        result = await asyncio.wait_for(run, 90)
        out, err = await asyncio.to_thread(monitor.communicate, timeout=60)
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait()
        await asyncio.to_thread(listener.ros.stop)
    assert monitor.returncode == 0, err[-2000:]
    rows = {r["robot"]: r for r in json.loads(out)["robots"]}
    assert rows[6]["function"] == "f2"  # the table it printed agrees with what it published
    assert not result.problems, result.problems
    events = result.events

    def one(event: str, **fields: Any) -> dict[str, Any]:
        found = [e for e in events if e["event"] == event
                 and all(e.get(k) == v for k, v in fields.items())]
        assert len(found) == 1, (event, fields, found)
        return found[0]

    # Health from /diagnostics: robot 4's stack reports ERROR, its daemon leaves, 5 takes f4.
    leave = one("leave", robot=4, function="f4")
    assert leave["t"] >= unhealthy
    # 5's takeover after the leave (on a loaded machine a late heartbeat may have had 4
    # suspected, taken over and fenced back before: rule 2).
    assert [e for e in events if e["event"] == "takeover" and e["robot"] == 5
            and e["function"] == "f4" and e["t"] >= leave["t"]]
    # The crash: robot 6 takes f2; its stack gets f2's goal pose.
    takeover = one("takeover", robot=6, function="f2", replaced=2)
    received = [json.loads(line) for line in
                (tmp_path / "realtime" / "ros2" / "robot6.jsonl").read_text().splitlines()]
    # The first goal after the takeover: on a loaded machine 6 may have flown another
    # slot it covers for a while before (a late heartbeat suspected, rule 2 fenced it).
    goal = next(r for r in received
                if r["kind"] == "goal" and r["w"] - result.t0 >= takeover["t"] - 0.01)
    assert goal["position"] == [0.0, 2.0, 1.5] and goal["frame"] == "map"
    delay = goal["w"] - result.t0 - takeover["t"]
    print(f"robot 6's stack got f2's goal {delay * 1000:.1f} ms after its takeover event")
    # Causal, and within the run. How soon is the printed figure, not an assertion: a
    # bound of 1 s failed at 1.4 s with the suite running twice over on two cores.
    assert -0.01 <= delay < duration - takeover["t"], delay
    # A late subscriber gets the current assignment (transient-local).
    assert listener.late["/swarmd/paper/robot6/swarmd/function"][:1] == ["f2"]
    assert listener.late["/swarmd/paper/robot6/swarmd/goal_pose"][:1] == [("map", 0.0, 2.0, 1.5)]
    assert listener.late["/swarmd/paper/robot1/swarmd/function"][:1] == ["f1"]
    # The swarm on /diagnostics: f2's holder goes 2 -> 6, as robots 1, 3 and 6 show it.
    # A publisher the listener discovered only after the crash (DDS discovery on a loaded
    # machine takes seconds) could not have been seen showing 2: then 6 alone.
    for publisher in ("robot1", "robot3", "robot6"):
        first = min(t for t, name, hw, _, _ in listener.statuses
                    if name == "swarmd/paper/f2" and hw == publisher)
        shown = listener.holders("f2", publisher)
        if first - result.t0 < crash:
            assert shown == ["2", "6"], publisher
        else:
            assert shown in (["2", "6"], ["6"]), (publisher, shown)
    # The base station shows it too. It is a process started once the run's files
    # exist: on a loaded machine its interpreter, rclpy and DDS discovery took past the
    # crash (4 s). Up before the crash, it shows 2 then 6. Up later, it may have missed
    # 6's claim and certificate: per robot it then keeps the plan's holder and shows 6
    # `unverified` (swarmd/daemon/monitor.py), never another robot.
    base = listener.holders("f2", "base_station")
    first_base = min(t for t, name, hw, _, _ in listener.statuses
                     if name == "swarmd/paper/f2" and hw == "base_station")
    if first_base - result.t0 < crash:
        assert base == ["2", "6"], base
    else:
        assert base in (["2", "6"], ["6"], ["2"]), base
    first_6 = min(t for t, name, _, _, v in listener.statuses
                  if name == "swarmd/paper/f2" and v["holder"] == "6")
    assert first_6 - result.t0 >= crash
    heard_1 = [(t, lv) for t, name, hw, lv, _ in listener.statuses
               if name == "swarmd/paper/f2" and hw == "robot1"]
    if min(t for t, _ in heard_1) - result.t0 < crash:  # discovered in time to see it
        assert {OK, WARN} <= {lv for _, lv in heard_1}  # suspected before the takeover
    own = [v for _, name, _, _, v in listener.statuses if name == "swarmd/paper/robot6"]
    assert own and own[-1]["role"] == "active" and own[-1]["function"] == "f2"


def test_a_robot_file_with_the_ros2_link_fills_in_the_robots_names(tmp_path: Path) -> None:
    from swarms import unsigned_paper

    from swarmd.config import parse_robot
    from swarmd.config.robot import Ros2LinkConfig
    from swarmd.link.factory import make_link

    swarm = unsigned_paper(tmp_path)
    cfg = parse_robot(f"robot: 2\nswarm: {swarm}\nlink: {{kind: ros2, domain_id: 7}}\n",
                      "robot.yaml", tmp_path / "robot.yaml")
    link = cfg.link
    assert isinstance(link, Ros2LinkConfig)
    assert (link.node_name, link.hardware_id, link.domain_id, link.frame_id, link.release) == (
        "swarmd_robot2", "robot2", 7, "map", "hold")
    pytest.importorskip("rclpy", reason="needs the ros2 extra: pip install 'swarmd[ros2]'")
    assert type(make_link(link)).__name__ == "Ros2Link"
