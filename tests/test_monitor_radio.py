"""The base station on the radio: `swarmd monitor` through an XBee coordinator on the
emulated 802.15.4 channel hears a swarm whose robots each have their own radio, and
sends nothing on the air."""

from __future__ import annotations

import asyncio
import json
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

from sim.xbee_emu import Medium
from sim.xbee_emu.radio import EmulatedRadio, Transmit
from sim.xbee_emu.swarm import RadioSwarm, paper_plan
from swarmd.core.params import radio
from swarmd.daemon.monitor import MonitorState, listen
from swarmd.transport.base import Transport
from swarmd.transport.xbee import XBeeTransport

ROOT = Path(__file__).resolve().parent.parent

# radio() shapes the protocol; times shrunk 5x so a takeover happens within seconds.
FAST = dict(heartbeat_interval=0.1, standby_heartbeat_interval=0.3, t_max=0.4,
            warn_interval=0.1, vote_window=0.6, claim_hold=0.2, startup_grace=1.0,
            standby_timeout=1.0, alert_after=3.0, rejoin_hold=0.5)
BASE = 1  # radio 1, the coordinator (CE=1), is the base station; robot r has radio r + 1


def _record_senders(medium: Medium,
                    monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, bytes]]:
    """Every transmit put on the air, as (radio number, payload)."""
    sent: list[tuple[int, bytes]] = []
    transmit = medium._transmit

    def recording(radio_: EmulatedRadio, request: Transmit) -> None:
        sent.append((radio_.number, request.data))
        transmit(radio_, request)

    monkeypatch.setattr(medium, "_transmit", recording)
    return sent


def _no_drops(drops: Mapping[str, int]) -> None:
    """The monitor read every frame on the air and refused none: nobody repeats another
    robot's frame as heard (a proof travels inside CERTs of the robot that shows it,
    which no replay filter judges), so not even a `replay` of one."""
    assert dict(drops) == {}


def _robot_transports(medium: Medium) -> dict[int, Transport]:
    return {r: XBeeTransport(port=medium.path(r + 1), pan_id=0x0607, role="router")
            for r in range(1, 7)}


async def test_monitor_on_the_coordinator_sees_heartbeats_and_a_takeover(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    params = radio().with_overrides(**FAST)
    plan = paper_plan()
    with Medium(7, protocol="802.15.4", directory=tmp_path) as medium:
        sent = _record_senders(medium, monkeypatch)
        base = XBeeTransport(port=medium.path(BASE), pan_id=0x0607, role="coordinator")
        state = MonitorState(plan, params)
        listening = asyncio.create_task(listen(state, base, duration=None))
        swarm = RadioSwarm(plan, params, _robot_transports(medium))
        await swarm.start()
        try:
            loop = asyncio.get_running_loop()
            deadline = loop.time() + 10
            while len(state.robots) < 6 or not all(
                    state.robots[r].frames for r in range(1, 7)):
                assert loop.time() < deadline, state.rows(loop.time())
                await asyncio.sleep(0.05)
            await swarm.kill(2)
            takeover = await swarm.wait_for(lambda e: e["event"] == "takeover", 10)
            assert takeover is not None and takeover["robot"] == 6
            # The monitor reads the coordinator's serial port at its own pace: on a
            # loaded machine robot 2's last frames reach it late, and 2 shows `silent`
            # only t_max after the monitor read them, which may come after it saw 6's
            # takeover.
            deadline = loop.time() + 5
            while True:
                rows = {r["robot"]: r for r in state.rows(loop.time())}
                if (state.robots[6].epoch, state.robots[6].function) == (1, "f2") \
                        and rows[2]["status"] == "superseded, silent":
                    break
                assert loop.time() < deadline, rows
                await asyncio.sleep(0.05)
        finally:
            await swarm.close()
            listening.cancel()
            with pytest.raises(asyncio.CancelledError):
                await listening
    assert rows[2]["status"] == "superseded, silent"
    assert (rows[2]["function"], rows[2]["epoch"]) == ("f2", 0)
    assert (rows[6]["status"], rows[6]["role"], rows[6]["function"]) == ("live", "ACTIVE", "f2")
    assert all(rows[r]["status"] == "live" for r in (1, 3, 4, 5))
    _no_drops(state.drops)
    assert {radio_ for radio_, _ in sent} == {2, 3, 4, 5, 6, 7}  # the base sent nothing


@pytest.mark.slow
async def test_monitor_cli_with_a_base_station_file_on_an_xbee(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    params = radio().with_overrides(**FAST)
    plan = paper_plan()
    swarm_file = tmp_path / "swarm.yaml"
    swarm_file.write_text(json.dumps({
        "swarm": {"id": plan.swarm_id, "name": "radio"},
        "timing": {"preset": "radio", **FAST},
        "functions": {f"f{i}": {"kind": "slot", "position": [float(i), 0.0, 1.0]}
                      for i in range(1, 5)},
        "robots": [
            *({"id": r, "state": "active", "function": f"f{r}",
               "neighbors": [(r + 2) % 4 + 1, r % 4 + 1]} for r in range(1, 5)),
            {"id": 5, "state": "standby", "subs": [1, 4]},
            {"id": 6, "state": "standby", "subs": [2, 3]},
        ],
    }))
    with Medium(7, protocol="802.15.4", directory=tmp_path / "radios") as medium:
        sent = _record_senders(medium, monkeypatch)
        base_file = tmp_path / "base.yaml"
        base_file.write_text(
            "swarm: swarm.yaml\n"
            f"transport: {{kind: xbee, port: {medium.path(BASE)}, pan_id: '0x607', "
            "role: coordinator}\n")
        swarm = RadioSwarm(plan, params, _robot_transports(medium))
        await swarm.start()
        try:
            env = {**os.environ, "PYTHONPATH": str(ROOT)}
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "swarmd.cli", "monitor", "--config", str(base_file),
                "--json", "--duration", "2.5", cwd=ROOT, env=env,
                stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE)
            out, err = await asyncio.wait_for(proc.communicate(), 60)
        finally:
            await swarm.close()
    assert proc.returncode == 0, err.decode()[-2000:]
    doc: dict[str, Any] = json.loads(out)
    rows = {r["robot"]: r for r in doc["robots"]}
    assert set(rows) == {1, 2, 3, 4, 5, 6}
    assert {rows[r]["function"] for r in range(1, 5)} == {"f1", "f2", "f3", "f4"}
    assert rows[5]["role"] == rows[6]["role"] == "STANDBY"
    _no_drops(doc["drops"])
    assert doc["alerts"] == []
    assert BASE not in {radio_ for radio_, _ in sent}
