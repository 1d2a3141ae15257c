"""The asyncio runtime and daemon, in-process over real UDP multicast on loopback.

Each test uses its own random port; daemons run as tasks of the test's loop. Waiting is
on conditions with a deadline (never a sleep standing in for protocol logic).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import subprocess
import sys
import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from swarms import paper_text, unsigned_paper

import swarmd.daemon.daemon as daemon_mod
from swarmd.base.keys import generate_key
from swarmd.config import RobotConfig, load_robot, parse_robot
from swarmd.core import wire
from swarmd.core.events import Alert, AlertCause
from swarmd.core.node import Node
from swarmd.core.roles import Health, Role
from swarmd.daemon.daemon import Daemon, run_daemon
from swarmd.link.base import RobotLink
from swarmd.link.none import NoneLink
from swarmd.link.socket import SocketLink
from swarmd.services.runtime import Runtime
from swarmd.services.state import state_path
from swarmd.transport import socket_filter
from swarmd.transport.addresses import DEFAULT_GROUP
from swarmd.transport.base import EventCallback, FrameCallback
from swarmd.transport.udp import UdpTransport

GROUP = DEFAULT_GROUP


def _unsigned(tmp: Path) -> Path:
    path = tmp / "paper.yaml"
    if not path.exists():
        tmp.mkdir(parents=True, exist_ok=True)
        unsigned_paper(tmp)
    return path


def robot_cfg(tmp: Path, robot: int, port: int, *, handover: bool = True,
              event_log: bool = False) -> RobotConfig:
    text = textwrap.dedent(f"""\
        robot: {robot}
        swarm: {_unsigned(tmp)}
        transport: {{kind: udp, port: {port}}}
        link: {{kind: none}}
        state_dir: {tmp / "state"}
        handover_on_stop: {"true" if handover else "false"}
        """)
    if event_log:
        text += f"event_log: {tmp / f'events{robot}.jsonl'}\n"
    return parse_robot(text, name=f"robot{robot}.yaml", path=tmp / f"robot{robot}.yaml")


async def wait_until(cond: Callable[[], bool], timeout: float, what: str) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not cond():
        assert loop.time() < end, f"timed out after {timeout} s waiting for {what}"
        await asyncio.sleep(0.01)


@dataclass
class Running:
    """One in-process daemon: its task, stop event, events and (once ready) Daemon."""

    robot: int
    task: asyncio.Task[int]
    stop: asyncio.Event
    events: list[dict[str, Any]] = field(default_factory=list)
    heard: set[int] = field(default_factory=set)
    daemon: Daemon | None = None

    def names(self) -> list[str]:
        return [e["event"] for e in self.events]

    async def finish(self) -> int:
        self.stop.set()
        return await asyncio.wait_for(self.task, 10.0)


async def launch(cfg: RobotConfig, *, link: RobotLink | None = None,
                 keep: list[bytes] | None = None, config_path: Path | None = None) -> Running:
    """Run a daemon as a task until ready; `keep` collects every frame it receives;
    `config_path` is the file a `reload` (SIGHUP) reads."""
    stop = asyncio.Event()
    holder: list[Running] = []

    def sink(record: dict[str, Any]) -> None:
        holder[0].events.append(record)

    def heard(data: bytes, now: float) -> bool:
        # A pass-through filter that notes who we hear (sender id from the header).
        if len(data) >= wire.HEADER_LEN:
            holder[0].heard.add(wire.HEADER.unpack_from(data)[2])
        if keep is not None:
            keep.append(data)
        return True

    def ready(d: Daemon) -> None:
        holder[0].daemon = d

    task = asyncio.create_task(run_daemon(cfg, link=link, event_sink=sink, stop_event=stop,
                                          receive_filter=heard, on_ready=ready,
                                          config_path=config_path))
    holder.append(Running(cfg.robot, task, stop))
    await wait_until(lambda: holder[0].daemon is not None or task.done(), 5.0, "ready")
    assert not task.done(), f"daemon exited with {task.result()}"
    return holder[0]


def runtime_of(r: Running) -> Runtime:
    assert r.daemon is not None and r.daemon.runtime is not None
    return r.daemon.runtime


async def test_runtime_two_daemons_hear_each_other(tmp_path: Path, udp_port: int) -> None:
    port = udp_port
    a = await launch(robot_cfg(tmp_path, 1, port))
    b = await launch(robot_cfg(tmp_path, 2, port))
    try:
        await wait_until(lambda: 2 in a.heard and 1 in b.heard, 3.0, "heartbeats")
        await wait_until(lambda: 2 in runtime_of(a).snapshot().heard, 1.0, "node input")
        # Our own frames are dropped in the kernel, before the daemon (socket_filter.py).
        assert runtime_of(a).drop_counts().get("own", 0) == 0
        started = next(e for e in a.events if e["event"] == "started")
        assert (started["role"], started["function"]) == ("active", "f1")
    finally:
        assert await a.finish() == 0
        assert await b.finish() == 0
    assert a.names()[-2:] == ["leave", "stopped"]  # handover_on_stop: LEAVE goes out
    assert any(e["event"] == "leave" and e["robot"] == 1 for e in a.events)


class MemoryTransport:
    """In-memory transport for unit tests of the runtime's queue."""

    max_payload = 1472

    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.on_frame: FrameCallback | None = None

    async def start(self, on_frame: FrameCallback, on_event: EventCallback) -> None:
        self.on_frame = on_frame

    def send(self, frame: bytes) -> None:
        self.sent.append(frame)

    async def close(self) -> None:
        pass


async def test_runtime_queue_drops_oldest_and_counts(tmp_path: Path, udp_port: int) -> None:
    cfg = robot_cfg(tmp_path, 1, udp_port)
    loop = asyncio.get_running_loop()
    node = Node(1, cfg.swarm.to_plan(), cfg.swarm.params(), loop.time())
    transport = MemoryTransport()
    rt = Runtime(node, transport, NoneLink(), queue_size=100, batch=10)
    await rt.start()
    try:
        assert transport.on_frame is not None
        for i in range(1_000):  # all before the loop runs once: a burst
            transport.on_frame(b"garbage %d" % i)
        assert rt.stats()["queue_overflow"] == 900
        await wait_until(lambda: rt.stats()["queue"] == 0, 2.0, "drain")
        assert sum(node.drops.values()) == 100
        assert rt.stats()["received"] == 1_000
        assert transport.sent  # the first heartbeat went out meanwhile
    finally:
        await rt.stop(handover=False)


async def test_runtime_feeds_an_idle_robots_frame_at_once_and_queues_the_rest(
        tmp_path: Path, udp_port: int) -> None:
    """With nothing queued and no timer due, a frame goes from the transport's callback
    straight to the node (one turn of the loop per frame); after `batch` such frames, and
    behind any frame queued, frames wait for the drain, in order."""
    cfg = robot_cfg(tmp_path, 1, udp_port)
    loop = asyncio.get_running_loop()
    node = Node(1, cfg.swarm.to_plan(), cfg.swarm.params(), loop.time())
    transport = MemoryTransport()
    rt = Runtime(node, transport, NoneLink(), batch=2)
    await rt.start()
    try:
        await wait_until(lambda: bool(transport.sent), 2.0, "the first heartbeat")
        deadline = rt.next_deadline()
        while deadline is not None and loop.time() >= deadline:
            await asyncio.sleep(0)  # let the due tick run first
            deadline = rt.next_deadline()
        assert transport.on_frame is not None
        for i in range(4):  # no await: the loop does not turn meanwhile
            transport.on_frame(b"garbage %d" % i)
        assert node.drops["malformed"] == 2  # fed at once, up to the batch
        assert rt.stats()["queue"] == 2  # the rest wait for the drain
        await wait_until(lambda: rt.stats()["queue"] == 0, 2.0, "drain")
        assert node.drops["malformed"] == 4 and rt.stats()["received"] == 4
    finally:
        await rt.stop(handover=False)


class CountingNode(Node):
    """A node that counts the full snapshots its driver takes."""

    snapshots = 0

    def snapshot(self) -> Any:
        self.snapshots += 1
        return super().snapshot()


async def test_runtime_ticks_without_a_snapshot_and_writes_state_when_due(
        tmp_path: Path, udp_port: int) -> None:
    """A tick that changes neither the role nor what is persisted takes no full snapshot
    (it copies every table); the state file is still written each time seq reaches the
    reservation the last write returned, with that moment's snapshot."""
    cfg = robot_cfg(tmp_path, 1, udp_port)
    loop = asyncio.get_running_loop()
    node = CountingNode(1, cfg.swarm.to_plan(), cfg.swarm.params(), loop.time())
    transport = MemoryTransport()
    written: list[int] = []

    def write(snap: Any) -> int:
        written.append(snap.seq)
        return int(snap.seq) + 4  # the next write is due 4 frames on

    rt = Runtime(node, transport, NoneLink(), state_writer=write)
    await rt.start()
    try:
        await wait_until(lambda: len(transport.sent) >= 16, 10.0, "sixteen frames out")
    finally:
        await rt.stop(handover=False)
    ticks = rt.stats()["ticks"]
    assert ticks >= 8 and node.snapshots <= len(written) + 2 < ticks
    running = written[:-1]  # the last one is the stop's
    assert len(running) >= 4 and running[0] == 0
    assert all(b - a >= 4 for a, b in itertools.pairwise(running)), written


class ExplodingLink(NoneLink):
    def assign(self, function: str, epoch: int, params: Mapping[str, Any]) -> None:
        raise RuntimeError("robot on fire")


async def test_runtime_survives_a_link_that_raises(tmp_path: Path, udp_port: int) -> None:
    cfg = robot_cfg(tmp_path, 1, udp_port)
    loop = asyncio.get_running_loop()
    node = Node(1, cfg.swarm.to_plan(), cfg.swarm.params(), loop.time())
    transport = MemoryTransport()
    rt = Runtime(node, transport, ExplodingLink())
    await rt.start()
    try:
        await wait_until(lambda: len(transport.sent) >= 2, 2.0, "heartbeats after the error")
        assert rt.stats()["link_errors"] == 1
    finally:
        await rt.stop(handover=False)


FLOOD_SCRIPT = r"""
import json, os, socket, struct, sys, threading, time
group, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
sys.path.insert(0, sys.argv[4])
from swarmd.core import wire

def member():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    s.bind((group, port))
    iface = socket.inet_aton("127.0.0.1")
    s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton(group) + iface)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, iface)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    return s

times = []
done = threading.Event()
listener = member()
listener.settimeout(0.05)
def listen():
    while not done.is_set():
        try:
            data = listener.recv(2048)
        except socket.timeout:
            continue
        if len(data) >= 11 and data[0] & 0x07 == 1 and struct.unpack_from(">BHH", data)[2] == 1:
            times.append(time.monotonic())
t = threading.Thread(target=listen); t.start()
time.sleep(1.0)
sender = member()
rnd = __import__("random").Random(7)
seq = wire.seq_seed(time.time())
valid = wire.encode(wire.Frame(1543, 2, seq, wire.Heartbeat(2, 0, 1, 0)))
sender.sendto(valid, (group, port))
flood_start = time.monotonic()
for i in range(n):
    if i % 2:
        frame = valid  # replayed: same seq again
    else:
        frame = bytes(rnd.getrandbits(8) for _ in range(rnd.randrange(1, 40)))
    sender.sendto(frame, (group, port))
flood_end = time.monotonic()
time.sleep(1.0)
done.set(); t.join()
gaps = [b - a for a, b in zip(times, times[1:])]
during = [b - a for a, b in zip(times, times[1:]) if b >= flood_start and a <= flood_end + 0.2]
print(json.dumps({"heartbeats": len(times), "max_gap": max(gaps), "max_gap_flood": max(during),
                  "flood_s": flood_end - flood_start}))
"""


async def test_runtime_flood_keeps_heartbeats_on_time_and_counts_drops(
        tmp_path: Path, udp_port: int) -> None:
    port = udp_port
    cfg = robot_cfg(tmp_path, 1, port)
    a = await launch(cfg)
    root = str(Path(__file__).resolve().parent.parent)
    try:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", FLOOD_SCRIPT, GROUP, str(port), "10000", root,
            stdout=subprocess.PIPE)
        out, _ = await asyncio.wait_for(proc.communicate(), 30.0)
        assert proc.returncode == 0
        result = json.loads(out)
        rt = runtime_of(a)
        await wait_until(lambda: rt.stats()["queue"] == 0, 5.0, "drain")
        stats = rt.stats()
    finally:
        await a.finish()
    t_max = cfg.swarm.params().t_max
    print(f"\nflood: 10000 frames in {result['flood_s'] * 1000:.0f} ms; heartbeat max gap "
          f"{result['max_gap_flood'] * 1000:.1f} ms during the flood, "
          f"{result['max_gap'] * 1000:.1f} ms overall (period 100 ms, t_max "
          f"{t_max * 1000:.0f} ms); tick lateness max {stats['max_lateness'] * 1000:.2f} ms; "
          f"received {stats['received']}, queue_overflow {stats['queue_overflow']}, "
          f"core drops {stats['drops']}")
    # Behaviour: the neighbours never go t_max without a heartbeat, so no false suspicion.
    assert result["max_gap"] < t_max
    # Design check (generous bound for a loaded CI machine): timers run between batches,
    # so the flood never holds a due tick back for a whole heartbeat period.
    assert stats["max_lateness"] < cfg.swarm.params().heartbeat_interval
    assert stats["drops"].get("replay", 0) > 1000
    assert stats["drops"].get("malformed", 0) + stats["drops"].get("version", 0) > 1000
    assert stats["node_errors"] == 0


async def test_socket_link_silence_stops_heartbeats_and_leaves(
        tmp_path: Path, udp_port: int) -> None:
    link = SocketLink(tmp_path / "robot.sock", health_timeout=0.3)
    a = await launch(robot_cfg(tmp_path, 1, udp_port), link=link)
    try:
        # The robot never connects: after 0.3 s it counts as faulty (DESIGN rule 7).
        await wait_until(lambda: "leave" in a.names(), 3.0, "leave on fault")
        rt = runtime_of(a)
        assert rt.snapshot().health == Health.FAULTY
        leave = next(e for e in a.events if e["event"] == "leave")
        assert leave["reason"] == "fault" and leave["function"] == "f1"
        sent = rt.stats()["sent"]
        deadline = rt.next_deadline()
        assert deadline is None or deadline > asyncio.get_running_loop().time()
        await asyncio.sleep(0.25)  # 2.5 heartbeat periods: none may go out
        assert rt.stats()["sent"] == sent
    finally:
        await a.finish()


async def test_daemon_corrupt_state_file_starts_fresh(tmp_path: Path, udp_port: int) -> None:
    cfg = robot_cfg(tmp_path, 1, udp_port)
    path = state_path(cfg.state_dir, 1543, 1)
    path.parent.mkdir(parents=True)
    path.write_text("{half a json")
    a = await launch(cfg)
    try:
        assert a.daemon is not None and a.daemon.state_errors == 1
        started = next(e for e in a.events if e["event"] == "started")
        assert started["role"] == "active"
        assert list(path.parent.glob("*.corrupt-*"))  # kept for inspection
    finally:
        await a.finish()
    assert json.loads(path.read_text())["robot"] == 1  # a valid file again


async def test_restarted_daemon_does_not_resume_a_function_taken_over(
        tmp_path: Path, udp_port: int) -> None:
    port = udp_port
    others = [await launch(robot_cfg(tmp_path, r, port)) for r in (1, 3, 4, 6)]
    two = await launch(robot_cfg(tmp_path, 2, port, handover=False))
    six = others[-1]
    try:
        # Its neighbours (robot 4's heartbeats, about a slot it does not hear, its
        # transport drops in the kernel: robot 1 hears those).
        await wait_until(lambda: {1, 3} <= two.heard and 4 in others[0].heard, 3.0,
                         "neighbours")
        # Robot 2 dies without a LEAVE (handover off): the swarm must notice by silence.
        await two.finish()
        held = json.loads(state_path(tmp_path / "state", 1543, 2).read_text())["held"]
        assert held == ["f2", 0]
        await wait_until(lambda: "takeover" in six.names(), 5.0, "robot 6 takes over f2")
        takeover = next(e for e in six.events if e["event"] == "takeover")
        assert takeover["function"] == "f2" and takeover["epoch"] == 1
        # Robot 2 comes back with its state file: it must not execute f2 again.
        link = NoneLink()
        back = await launch(robot_cfg(tmp_path, 2, port, handover=False), link=link)
        try:
            await wait_until(lambda: "started" in back.names(), 3.0, "rejoin outcome")
            started = next(e for e in back.events if e["event"] == "started")
            assert started["role"] == "standby" and started["function"] is None
            # Never assigned f2; told at once to release whatever it executed.
            assert link.history == [("release", "", None)]
            snap = runtime_of(back).snapshot()
            assert snap.role == Role.STANDBY and snap.known["f2"] == (6, 1)
        finally:
            await back.finish()
        saved = json.loads(state_path(tmp_path / "state", 1543, 2).read_text())
        assert saved["held"] is None and saved["known"]["f2"] == [6, 1]
        assert "fenced" not in six.names()
    finally:
        for r in others:
            await r.finish()


async def test_sighup_rotates_the_keys_of_the_running_node(tmp_path: Path, udp_port: int) -> None:
    # docs/operations.md "Rotating the swarm key", steps 1-3, by Daemon.reload (what
    # SIGHUP calls) on a running daemon; the keys reach the node through set_keys.
    old, new = tmp_path / "old.key", tmp_path / "new.key"
    k_old, k_new = generate_key(old), generate_key(new)
    port = udp_port
    swarm, robot = tmp_path / "swarm.yaml", tmp_path / "robot.yaml"

    def write(signing: Path | None, accepted: list[Path]) -> None:
        auth = "auth: none" if signing is None else f"key_file: {signing}"
        swarm.write_text(paper_text(auth))
        robot.write_text(
            f"robot: 1\nswarm: {swarm}\ntransport: {{kind: udp, port: {port}}}\n"
            f"link: {{kind: none}}\nstate_dir: {tmp_path / 'state'}\n"
            f"key_files: [{', '.join(str(p) for p in accepted)}]\n")

    write(old, [])
    frames: list[bytes] = []
    # What the daemon sends, heard as its neighbours hear it (its own echoes never
    # reach it: the udp transport drops them in the kernel).
    ears = UdpTransport(port=port)
    await ears.start(frames.append, lambda event: None)
    a = await launch(load_robot(robot), config_path=robot)
    assert a.daemon is not None
    daemon, rt = a.daemon, runtime_of(a)

    def keys() -> tuple[bytes, ...]:
        return rt.keys()

    async def signs_with(key: bytes) -> None:
        mark = len(frames)

        def seen() -> bool:
            for data in frames[mark:]:
                with contextlib.suppress(wire.CodecError):
                    if wire.decode(data, [key]).sender == 1:
                        return True
            return False
        await wait_until(seen, 3.0, "a heartbeat signed with the new signing key")

    try:
        write(old, [new])
        daemon.reload()
        assert keys() == (k_old, k_new)
        write(new, [old])
        daemon.reload()
        assert keys() == (k_new, k_old)
        await signs_with(k_new)
        write(new, [])
        daemon.reload()
        assert keys() == (k_new,) and daemon.reload_errors == 0
        write(None, [])  # key lines lost: refused, signing goes on with the new key
        daemon.reload()
        assert keys() == (k_new,) and daemon.reload_errors == 1
        await signs_with(k_new)
        assert rt.drop_counts().get("auth", 0) == 0
    finally:
        assert await a.finish() == 0
        await ears.close()


async def test_alert_hook_runs_with_the_alert_and_a_hung_one_is_killed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture, udp_port: int) -> None:
    # DESIGN rule 8; the hook runs through the exec link's run_command.
    out = tmp_path / "alert.txt"
    daemon = Daemon(robot_cfg(tmp_path, 1, udp_port))
    daemon._alert_hook = ["sh", "-c", f'echo "$SWARMD_ROBOT $SWARMD_FUNCTION '
                                      f'$SWARMD_REASON" > {out}; exit 3']
    daemon.on_event(0.0, Alert("f2", AlertCause.NO_STANDBY))
    await asyncio.wait_for(asyncio.gather(*daemon._hook_tasks), 10.0)
    assert out.read_text() == "1 f2 no standby left\n"
    monkeypatch.setattr(daemon_mod, "ALERT_HOOK_TIMEOUT", 0.2)
    daemon._alert_hook = f"echo $$ > {out}; exec sleep 30"
    daemon.on_event(0.0, Alert("f2", AlertCause.NO_CLAIM))
    await asyncio.wait_for(asyncio.gather(*daemon._hook_tasks), 10.0)
    pid = int(out.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # killed and reaped, not left running
    assert [r.getMessage() for r in caplog.records if r.name == "swarmd.daemon"
            and r.levelname == "ERROR"] == ["alert hook failed", "alert hook timed out; killed"]


@pytest.mark.parametrize("filtered", [True, False], ids=["echoes_filtered", "echoes_heard"])
async def test_runtime_second_daemon_with_our_id_is_reported_not_our_echo(
        tmp_path: Path, caplog: pytest.LogCaptureFixture, udp_port: int,
        monkeypatch: pytest.MonkeyPatch, filtered: bool) -> None:
    # A copied robot file: two daemons as robot 1. Each drops the other's frames (as
    # it drops its multicast echoes), so it used to go unnoticed while both could hold
    # f1 (DESIGN rule 2). The one started first reports the other: its frames are
    # above its own start and it did not send them (`own`). The one started second
    # counts the first one's frames as replays of its own from before it started
    # (`replay`: they are indistinguishable), and no frame moves either's counter.
    # Whether our own echoes are dropped in the kernel (the udp transport's filter)
    # or reach the core (where no filter can be attached), only the other's count.
    if not filtered:
        monkeypatch.setattr(socket_filter, "attach", lambda sock, code: False)
    port = udp_port
    a = await launch(robot_cfg(tmp_path / "a", 1, port))
    try:
        rt_a = runtime_of(a)
        await wait_until(lambda: rt_a.stats()["sent"] >= 3, 3.0, "frames sent")
        if filtered:
            await asyncio.sleep(0.05)  # an echo, were it delivered, is in by then
            assert rt_a.drop_counts().get("own", 0) == 0  # none reached the daemon
        else:
            await wait_until(lambda: rt_a.drop_counts().get("own", 0) >= 3, 3.0,
                             "own echoes")
        assert rt_a.stats()["duplicate_id"] == 0  # our echoes are recognised
        b = await launch(robot_cfg(tmp_path / "b", 1, port))
        try:
            rt_b = runtime_of(b)
            await wait_until(lambda: rt_a.stats()["duplicate_id"] > 0
                             and rt_b.drop_counts().get("replay", 0) > 0, 3.0,
                             "duplicate id")
        finally:
            assert await b.finish() == 0
    finally:
        assert await a.finish() == 0
    errors = [r.getMessage() for r in caplog.records if r.name == "swarmd.runtime"
              and r.levelname == "ERROR"]
    # Reported once (rate-limited to one line per 10 s).
    assert errors == ["another daemon is sending as robot 1: two robot files with the "
                      "same id?"]
