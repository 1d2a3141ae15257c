"""swarmd.daemon.monitor: the passive base-station view, on virtual time, plus the CLI once."""

from __future__ import annotations

import json
import socket
import threading
from pathlib import Path

from typer.testing import CliRunner

from swarmd.cli import app
from swarmd.config import load_swarm
from swarmd.core import params, wire
from swarmd.core.belief import level_byte
from swarmd.core.plan import RobotPlan, SwarmPlan
from swarmd.core.roles import Health, Role
from swarmd.daemon.monitor import MonitorState
from swarmd.transport.addresses import DEFAULT_GROUP

PAPER = Path(__file__).resolve().parent.parent / "configs" / "paper.yaml"
SWARM = 1543


def paper_plan() -> SwarmPlan:
    """The paper's appendix swarm: 1-4 active in a ring, 5 covers f1/f4, 6 covers f2/f3."""
    robots = {r: RobotPlan(r, f"f{r}") for r in range(1, 5)}
    robots[5] = RobotPlan(5, None, ("f1", "f4"))
    robots[6] = RobotPlan(6, None, ("f2", "f3"))
    watches = {"f1": ("f2", "f4"), "f2": ("f1", "f3"), "f3": ("f2", "f4"), "f4": ("f1", "f3")}
    return SwarmPlan(SWARM, ("f1", "f2", "f3", "f4"), robots, watches)


class Sender:
    """Frames as robots would send them, with rising sequence numbers per sender."""

    def __init__(self, key: bytes | None = None) -> None:
        self.seq: dict[int, int] = {}
        self.key = key

    def frame(self, sender: int, msg: wire.Message, swarm: int = SWARM) -> bytes:
        self.seq[sender] = self.seq.get(sender, 100) + 1
        return wire.encode(wire.Frame(swarm, sender, self.seq[sender], msg), self.key)

    def hb(self, sender: int, slot: int, epoch: int = 0, role: Role = Role.ACTIVE) -> bytes:
        return self.frame(sender, wire.Heartbeat(slot, epoch, role, Health.OK))


def took_over(state: MonitorState, tx: Sender, now: float, claimant: int, failed: int,
              epoch: int, slot: int = 2, witnesses: tuple[int, ...] = (1, 3)) -> None:
    """`claimant`'s takeover of `slot` from `failed` at `epoch`, as the channel carries
    it: the witnesses' warnings about `failed` at the epoch before (its certificate),
    then the CLAIM. A heartbeat at a new entry is believed only with it, as by a daemon
    (module docstring of `swarmd.daemon.monitor`)."""
    for w in witnesses:
        state.feed(tx.frame(w, wire.Warn(failed, slot, epoch - 1)), now)
    state.feed(tx.frame(claimant, wire.Claim(failed, slot, epoch)), now)


def healthy_swarm(state: MonitorState, tx: Sender, now: float) -> None:
    for r in range(1, 5):
        state.feed(tx.hb(r, r), now)
    for r in (5, 6):
        state.feed(tx.hb(r, 0, role=Role.STANDBY), now)


def test_monitor_rows_show_role_function_epoch_health() -> None:
    state = MonitorState(paper_plan(), params.udp())
    tx = Sender()
    healthy_swarm(state, tx, 10.0)
    rows = {r["robot"]: r for r in state.rows(10.25)}
    assert rows[2]["role"] == "ACTIVE" and rows[2]["function"] == "f2"
    assert rows[2]["epoch"] == 0 and rows[2]["health"] == "OK"
    assert rows[2]["last_heard_s"] == 0.25
    assert rows[6]["role"] == "STANDBY" and rows[6]["function"] is None
    assert state.alerts(10.25) == []


def test_a_standby_row_shows_no_epoch_whatever_digest_its_heartbeat_carries() -> None:
    """A heartbeat without a slot carries its sender's view digest in the epoch field
    (DESIGN, "Convergence"): the monitor shows no epoch for it, not the digest."""
    state = MonitorState(paper_plan(), params.udp())
    tx = Sender()
    state.feed(tx.hb(6, 0, epoch=0b0110, role=Role.STANDBY), 1.0)
    row = {r["robot"]: r for r in state.rows(1.1)}[6]
    assert (row["role"], row["function"], row["epoch"]) == ("STANDBY", None, None)


def test_monitor_counts_garbage_replays_and_other_swarms_without_raising() -> None:
    state = MonitorState(paper_plan(), params.udp())
    tx = Sender()
    first = tx.hb(1, 1)
    state.feed(first, 1.0)
    state.feed(first, 1.1)  # replayed
    state.feed(b"\x00" * 20, 1.2)  # version 0
    state.feed(b"", 1.2)
    state.feed(tx.hb(1, 1)[:-1], 1.3)
    state.feed(tx.frame(1, wire.Heartbeat(1, 0, 1, 0), swarm=7), 1.4)
    state.feed(tx.frame(99, wire.Heartbeat(1, 0, 1, 0)), 1.5)
    assert state.frames == 1
    assert state.drops == {"replay": 1, "version": 1, "malformed": 2, "other_swarm": 1,
                           "unknown_sender": 1}


def test_monitor_with_key_rejects_unsigned_frames() -> None:
    key = bytes(range(32))
    state = MonitorState(paper_plan(), params.udp(), [key])
    state.feed(Sender().hb(1, 1), 1.0)
    state.feed(Sender(key).hb(2, 2), 1.0)
    assert state.drops == {"auth": 1}
    assert [r["robot"] for r in state.rows(1.0)] == [2]


def test_monitor_warnings_are_votes_within_the_window_and_a_claim_clears_them() -> None:
    p = params.udp()
    state = MonitorState(paper_plan(), p)
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    # A doubt (a level below suspect_level, DESIGN "Detection") is no vote, here either.
    state.feed(tx.frame(1, wire.Warn(2, 2, 0, belief=level_byte(p.suspect_level) - 1)), 0.9)
    assert next(r for r in state.rows(0.95) if r["robot"] == 2)["votes"] == 0
    state.feed(tx.frame(1, wire.Warn(2, 2, 0)), 1.0)
    state.feed(tx.frame(3, wire.Warn(2, 2, 0)), 1.05)
    row = next(r for r in state.rows(1.1) if r["robot"] == 2)
    assert row["warned_by"] == [1, 3] and row["votes"] == 2
    # Outside the vote window the warnings no longer count (Fig. 9 time window).
    later = next(r for r in state.rows(1.05 + p.vote_window + 0.01) if r["robot"] == 2)
    assert later["votes"] == 0
    state.feed(tx.frame(1, wire.Warn(2, 2, 0)), 3.0)
    state.feed(tx.frame(6, wire.Claim(2, 2, 1)), 3.1)
    row = next(r for r in state.rows(3.2) if r["robot"] == 2)
    assert row["votes"] == 0


def test_monitor_alerts_when_warnings_last_with_nobody_claiming() -> None:
    p = params.udp()
    state = MonitorState(paper_plan(), p)
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    t = 1.0
    while t < 1.0 + p.alert_after + 0.5:
        state.feed(tx.frame(1, wire.Warn(2, 2, 0)), t)
        state.feed(tx.frame(3, wire.Warn(2, 2, 0)), t)
        t += p.warn_interval
    alerts = state.alerts(t)
    assert any("robot 2: warned about by [1, 3]" in a and "nobody claimed" in a
               for a in alerts), alerts
    assert any("robot 2: holder of f2 silent" in a for a in alerts), alerts


def test_monitor_silent_holder_is_no_alert_once_replaced() -> None:
    p = params.udp()
    state = MonitorState(paper_plan(), p)
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    now = p.t_max + 1.0
    for r in (1, 3, 4):
        state.feed(tx.hb(r, r), now)
    assert any("holder of f2 silent" in a for a in state.alerts(now))
    took_over(state, tx, now, 6, 2, 1)
    state.feed(tx.hb(6, 2, epoch=1), now)
    assert not any("f2" in a for a in state.alerts(now)), state.alerts(now)
    assert next(r for r in state.rows(now) if r["robot"] == 6)["function"] == "f2"


def test_monitor_flags_split_brain_and_leave_without_claim() -> None:
    """Standbys 5 and 6 both cover f2 here, and both take it over at epoch 1 (each
    claim certified by the same warnings: a race won on each side of a partition)."""
    p = params.udp()
    plan = paper_plan()
    robots = dict(plan.robots)
    robots[5] = RobotPlan(5, None, ("f1", "f2", "f4"))
    state = MonitorState(SwarmPlan(plan.swarm_id, plan.functions, robots, plan.watches), p)
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    took_over(state, tx, 0.1, 5, 2, 1)
    took_over(state, tx, 0.1, 6, 2, 1, witnesses=())
    state.feed(tx.hb(5, 2, epoch=1), 0.1)
    state.feed(tx.hb(6, 2, epoch=1), 0.1)
    assert any("split brain" in a and "[5, 6]" in a for a in state.alerts(0.1))
    state.feed(tx.frame(4, wire.Leave(4, 0, wire.LeaveReason.FAULT)), 0.2)
    assert not any("left f4" in a for a in state.alerts(0.3))
    assert any("robot 4: left f4" in a for a in state.alerts(0.3 + p.alert_after))
    doc = state.to_json(0.3 + p.alert_after, listened=2.0)
    assert json.loads(json.dumps(doc))["listened_s"] == 2.0


def test_monitor_table_renders() -> None:
    from rich.console import Console

    state = MonitorState(paper_plan(), params.udp())
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    console = Console(width=160, record=True)
    console.print(state.table(0.5))
    text = console.export_text()
    assert "f2" in text and "STANDBY" in text


def test_monitor_cli_once_json_hears_the_loopback_channel(udp_port: int) -> None:
    swarm = load_swarm(PAPER)
    port = udp_port
    group = DEFAULT_GROUP
    stop = threading.Event()
    tx = Sender()

    def send() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
            while not stop.wait(0.05):
                for r in (1, 2):
                    s.sendto(tx.frame(r, wire.Heartbeat(r, 0, Role.ACTIVE, Health.OK),
                                      swarm=swarm.to_plan().swarm_id), (group, port))

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    try:
        result = CliRunner().invoke(app, ["monitor", "--swarm", str(PAPER), "--port", str(port),
                                          "--once", "--json", "--duration", "0.6"])
    finally:
        stop.set()
        thread.join(timeout=2)
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    robots = {r["robot"]: r for r in doc["robots"]}
    assert set(robots) == {1, 2}
    assert robots[2]["function"] == "f2" and robots[2]["role"] == "ACTIVE"
    assert doc["frames"] >= 4


def test_monitor_cli_needs_exactly_one_source() -> None:
    result = CliRunner().invoke(app, ["monitor", "--once"])
    assert result.exit_code == 2


def test_monitor_unusable_swarm_file_exits_2_like_start_and_sim(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("swarm: {id: 1}\nfunctions: {f1: {kind: slot, position: [0, 0]}}\n")
    result = CliRunner().invoke(app, ["monitor", "--swarm", str(bad), "--once"])
    assert result.exit_code == 2
    assert "position" in result.stderr and "[" in result.stderr  # plain text, not markup


def test_a_robot_taken_over_at_a_newer_epoch_is_superseded_and_a_quiet_one_silent() -> None:
    p = params.udp()  # t_max 0.5 s, standby_timeout 2 s
    state = MonitorState(paper_plan(), p)
    tx = Sender()
    for t in (0.0, 0.1, 0.2):
        healthy_swarm(state, tx, t)
    status = {r["robot"]: r["status"] for r in state.rows(0.3)}
    assert set(status.values()) == {"live"}
    # Robot 2 dies; standby 6 takes f2 over at epoch 1 and heartbeats it; the rest go on.
    took_over(state, tx, 1.0, 6, 2, 1)
    for t in (1.0, 1.1, 1.2, 3.1):
        for r in (1, 3, 4):
            state.feed(tx.hb(r, r), t)
        state.feed(tx.hb(6, 2, epoch=1), t)
    state.feed(tx.hb(5, 0, role=Role.STANDBY), 1.0)
    rows = {r["robot"]: r for r in state.rows(3.2)}
    assert rows[2]["status"] == "superseded, silent"
    assert (rows[2]["role"], rows[2]["function"], rows[2]["epoch"]) == ("ACTIVE", "f2", 0)
    assert rows[6]["status"] == "live" and rows[6]["epoch"] == 1
    assert rows[2]["alerts"] == []  # f2 has a live holder: nothing to do
    # Standby 5, last heard at 1.0: its heartbeats are rarer, so it is silent only past
    # standby_timeout (2 s), not past t_max.
    assert {r["robot"]: r["status"] for r in state.rows(2.9)}[5] == "live"
    assert {r["robot"]: r["status"] for r in state.rows(3.05)}[5] == "silent"
    # An active that stops is silent after t_max (0.5 s), not after the standby timeout.
    assert {r["robot"]: r["status"] for r in state.rows(3.5)}[1] == "live"
    assert {r["robot"]: r["status"] for r in state.rows(3.7)}[1] == "silent"
    # Robot 2 restarts and wins f2 back at a newer epoch: now 6's heartbeat is the old one.
    took_over(state, tx, 4.0, 2, 6, 2)
    state.feed(tx.hb(2, 2, epoch=2), 4.0)
    rows = {r["robot"]: r for r in state.rows(4.0)}
    assert rows[2]["status"] == "live" and rows[6]["status"] == "superseded, silent"
    assert not any("split brain" in a for a in state.alerts(4.0))


def test_the_table_shows_the_status() -> None:
    from rich.console import Console

    state = MonitorState(paper_plan(), params.udp())
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    took_over(state, tx, 1.0, 6, 2, 1)
    state.feed(tx.hb(6, 2, epoch=1), 1.0)
    console = Console(width=200, record=True)
    console.print(state.table(1.0))
    text = console.export_text()
    assert "superseded, silent" in text and "live" in text


def test_the_table_fits_80_columns_without_cutting_a_word() -> None:
    from rich.console import Console

    p = params.udp()
    state = MonitorState(paper_plan(), p)
    tx = Sender()
    healthy_swarm(state, tx, 0.0)
    t = 1.0
    while t < 1.0 + p.alert_after + 0.5:  # 1 and 3 warn about 4 and nobody claims
        state.feed(tx.frame(1, wire.Warn(4, 4, 0)), t)
        state.feed(tx.frame(3, wire.Warn(4, 4, 0)), t)
        t += p.warn_interval
    took_over(state, tx, t, 6, 2, 1)  # and 6 takes f2 over: 2 is superseded
    state.feed(tx.hb(6, 2, epoch=1), t)
    console = Console(width=80, record=True)
    console.print(state.table(t))
    lines = console.export_text().splitlines()
    assert all(len(line) <= 80 for line in lines)
    assert "…" not in "".join(lines)
    header = next(line for line in lines if line.startswith("robot"))
    assert header.split() == ["robot", "status", "role", "function", "epoch", "heard",
                              "health", "warned", "by", "votes"]
    row2 = next(line for line in lines if line.startswith("2 "))
    assert row2.split() == ["2", "superseded,", "ACTIVE", "f2", "0", "3.5", "s", "OK", "-",
                            "0"]
    row4 = next(line for line in lines if line.startswith("4 "))
    assert row4.split() == ["4", "silent", "ACTIVE", "f4", "0", "3.5", "s", "OK", "1,", "3",
                            "2"]
    assert "ALERT robot 4: warned about by [1, 3] for 2.5 s and nobody claimed" in lines


def test_the_base_station_never_shows_ok_a_function_its_holder_does_not_execute() -> None:
    """`swarmd monitor --ros2` in the daemons' words: robot 1 heard as a standby (it
    left f1 and nobody took it) is not "held by robot 1"; a silent holder is STALE
    "not heard", as the daemons say it."""
    from swarmd.daemon.monitor_ros2 import monitor_statuses
    from swarmd.link.ros2_status import OK, STALE, WARN

    state = MonitorState(paper_plan(), params.udp())
    tx = Sender()
    for r in (2, 3, 4):
        state.feed(tx.hb(r, r), 10.0)
    state.feed(tx.hb(1, 0, role=Role.STANDBY), 10.0)  # robot 1 executes nothing
    by_name = {s.name: s for s in monitor_statuses(state, "paper", 10.1)}
    f1 = by_name["swarmd/paper/f1"]
    assert f1.level == WARN and f1.message == "robot 1 does not execute f1 (standby)"
    assert dict(f1.values)["role"] == "monitor"
    assert (by_name["swarmd/paper/f2"].level, by_name["swarmd/paper/f2"].message) == (
        OK, "held by robot 2")
    later = {s.name: s for s in monitor_statuses(state, "paper", 12.0)}
    assert (later["swarmd/paper/f2"].level, later["swarmd/paper/f2"].message) == (
        STALE, "robot 2 not heard")
