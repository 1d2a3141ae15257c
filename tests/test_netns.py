"""Multicast failover across real interfaces: one daemon per network namespace.

Six namespaces (one per robot of the paper's swarm), each with a veth whose other end
is on a bridge in a seventh namespace: the only path between two daemons is a real
Ethernet-like link, as between robots on a Wi-Fi network. Each robot file sets the UDP
transport's `interface` to the namespace's own address (IP_MULTICAST_IF), TTL 1.
Addresses (10.77.0.0/24) exist only inside the namespaces this test creates, and every
namespace is deleted in `finally`.

Needs root (CAP_SYS_ADMIN) and iproute2; skips with the reason otherwise. CI runs as root.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from swarms import unsigned_paper

from swarmd.transport.addresses import DEFAULT_GROUP

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
ROBOTS = (1, 2, 3, 4, 5, 6)

pytestmark = pytest.mark.slow


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


@pytest.fixture
def namespaces() -> Iterator[dict[int, str]]:
    """{robot: namespace}, wired to one bridge; all deleted afterwards."""
    if shutil.which("ip") is None:
        pytest.skip("iproute2 `ip` is not installed")
    suffix = secrets.token_hex(3)
    bridge_ns = f"swbr-{suffix}"
    try:
        ip("netns", "add", bridge_ns)
    except subprocess.CalledProcessError as exc:
        pytest.skip(f"cannot create network namespaces (needs root / CAP_SYS_ADMIN): "
                    f"{exc.stderr.decode().strip()}")
    made = [bridge_ns]
    try:
        ip("-n", bridge_ns, "link", "add", "br0", "type", "bridge")
        # No IGMP querier on this bridge: without snooping it floods multicast to every
        # port, like a Wi-Fi access point does for a group.
        ip("-n", bridge_ns, "link", "set", "br0", "type", "bridge", "mcast_snooping", "0")
        ip("-n", bridge_ns, "link", "set", "br0", "up")
        spaces = {}
        for r in ROBOTS:
            ns = f"swr{r}-{suffix}"
            ip("netns", "add", ns)
            made.append(ns)
            ip("link", "add", "eth0", "netns", ns, "type", "veth",
               "peer", "name", f"p{r}", "netns", bridge_ns)
            ip("-n", bridge_ns, "link", "set", f"p{r}", "master", "br0", "up")
            ip("-n", ns, "addr", "add", f"10.77.0.{r}/24", "dev", "eth0")
            ip("-n", ns, "link", "set", "lo", "up")
            ip("-n", ns, "link", "set", "eth0", "up")
            ip("-n", ns, "route", "add", "224.0.0.0/4", "dev", "eth0")
            spaces[r] = ns
        yield spaces
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=10)


def read_events(path: Path) -> list[dict[str, Any]]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        with contextlib.suppress(ValueError):  # a line being written right now
            out.append(json.loads(line))
    return out


def test_netns_multicast_failover_across_real_interfaces(
    namespaces: dict[int, str], tmp_path: Path
) -> None:
    port = 47000 + secrets.randbelow(1000)
    procs: dict[int, subprocess.Popen[bytes]] = {}
    t0 = time.time() + 2.5  # all daemons start together once their interpreters are up
    try:
        for r, ns in namespaces.items():
            cfg = {
                "robot": r, "swarm": str(unsigned_paper(tmp_path)),
                "transport": {"kind": "udp", "group": DEFAULT_GROUP, "port": port,
                              "interface": f"10.77.0.{r}", "ttl": 1, "loopback": True},
                "link": {"kind": "none"}, "event_log": None,
                "state_dir": str(tmp_path / "state" / str(r)), "handover_on_stop": False,
            }
            path = tmp_path / f"robot{r}.yaml"
            path.write_text(yaml.safe_dump(cfg))
            log = open(tmp_path / f"robot{r}.log", "wb")  # noqa: SIM115
            procs[r] = subprocess.Popen(
                ["ip", "netns", "exec", ns, sys.executable, "-m", "sim.realtime.robot_proc",
                 "--config", str(path), "--events", str(tmp_path / f"events{r}.jsonl"),
                 "--t0", repr(t0)],
                cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                env={**os.environ, "PYTHONPATH": str(ROOT)},
            )
            log.close()
        # Let every robot hear its neighbours across the bridge, then crash robot 2.
        time.sleep(max(0.0, t0 + 1.5 - time.time()))
        for r, p in procs.items():
            assert p.poll() is None, (tmp_path / f"robot{r}.log").read_text()
        procs[2].send_signal(signal.SIGKILL)
        crashed_at = time.time() - t0
        # Generous: on a loaded machine the robots' processes are starved (the latency is
        # a figure for bench/, not a pass mark; this test is about the bridge).
        deadline = time.monotonic() + 30.0
        takeover: list[dict[str, Any]] = []
        while time.monotonic() < deadline and not takeover:
            time.sleep(0.1)
            takeover = [e for e in read_events(tmp_path / "events6.jsonl")
                        if e["event"] == "takeover" and e["function"] == "f2"]
        assert takeover, (tmp_path / "robot6.log").read_text()[-2000:]
        assert takeover[0]["replaced"] == 2
        latency = takeover[0]["t"] - crashed_at
        print(f"netns: crash -> takeover {latency:.3f} s")
        assert latency > 0.0
        # The warnings that made the quorum came from robots 1 and 3, across the bridge.
        votes = [e for e in read_events(tmp_path / "events6.jsonl") if e["event"] == "vote"]
        assert {e["from"] for e in votes} == {1, 3}
        # Before the crash nobody suspected anybody: heartbeats crossed the bridge.
        for r in (1, 3, 4, 5):
            early = [e for e in read_events(tmp_path / f"events{r}.jsonl")
                     if e["event"] == "suspect" and e["t"] < crashed_at]
            assert early == [], early
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
