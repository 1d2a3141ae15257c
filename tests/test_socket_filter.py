"""The udp transport's socket filter (swarmd/transport/socket_filter.py): run by a small
classic-BPF interpreter here, it drops exactly our own datagrams and exactly the
heartbeats the core drops as `irrelevant`, and keeps everything else whole; on a real
socket, a heartbeat this robot does not hear never reaches the transport."""

from __future__ import annotations

import asyncio
import ipaddress
import struct
from pathlib import Path

import pytest
from harness import send_to_group

from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.node import Node
from swarmd.core.plan import SwarmPlan, Unheard
from swarmd.transport import socket_filter
from swarmd.transport.udp import UdpTransport

ROOT = Path(__file__).resolve().parent.parent
KEY = bytes(range(32))


def run_bpf(code: bytes, source: tuple[str, int], payload: bytes) -> bool:
    """Does the kernel keep `payload` from `source` (a UDP socket filter's view: offset
    0 is the UDP header, SKF_NET_OFF + n the IP header's byte n)? Loads past the end
    drop, as the kernel's do."""
    insns = [struct.unpack_from("=HBBI", code, i) for i in range(0, len(code), 8)]
    udp = struct.pack(">HHHH", source[1], 9, 8 + len(payload), 0) + payload
    ip_header = bytes(12) + ipaddress.IPv4Address(source[0]).packed + bytes(4)
    a = x = pc = 0
    while True:
        op, jt, jf, k = insns[pc]
        pc += 1
        if op in (0x20, 0x28, 0x30):  # ld W/H/B at k
            size = {0x20: 4, 0x28: 2, 0x30: 1}[op]
            signed_k = k - (1 << 32) if k >= 1 << 31 else k
            data, at = (ip_header, signed_k - socket_filter.SKF_NET_OFF) \
                if signed_k < 0 else (udp, signed_k)
            if at + size > len(data):
                return False
            a = int.from_bytes(data[at:at + size], "big")
        elif op == 0x80:
            a = len(udp)
        elif op == 0x54:
            a &= k
        elif op == 0x07:
            x = a
        elif op == 0x87:
            a = x
        elif op == 0x05:
            pc += k
        elif op in (0x15, 0x35):
            pc += jt if (a == k if op == 0x15 else a >= k) else jf
        elif op == 0x06:
            return bool(k)
        else:
            raise AssertionError(f"opcode {op:#x} not emulated")


def plans() -> list[SwarmPlan]:
    return [load_swarm(ROOT / "configs" / name).to_plan()
            for name in ("paper.yaml", "ring8.yaml", "grid100.yaml")]


def heartbeat(swarm_id: int, sender: int, slot: int, *, key: bytes | None = None) -> bytes:
    frame = wire.Frame(swarm_id, sender, 1000, wire.Heartbeat(slot, 1, 1, 0))
    return wire.encode(frame, key)


def test_our_own_datagrams_and_only_ours_are_dropped() -> None:
    made = socket_filter.program(("127.0.0.1", 40000), None)
    assert made is not None and not made.unheard
    frame = heartbeat(1543, 1, 1)
    assert not run_bpf(made.code, ("127.0.0.1", 40000), frame)
    assert run_bpf(made.code, ("127.0.0.1", 40001), frame)  # another daemon, our id
    assert run_bpf(made.code, ("10.0.0.7", 40000), frame)  # another host, same port
    assert run_bpf(made.code, ("127.0.0.1", 40001), b"")  # an empty datagram: kept


@pytest.mark.parametrize("plan", plans(), ids=["paper", "ring8", "grid100"])
def test_the_filter_drops_exactly_the_heartbeats_the_core_finds_irrelevant(
        plan: SwarmPlan) -> None:
    # Every heartbeat a robot can be sent (any sender of the plan or not, any slot, a
    # standby's, signed or not, this swarm or another): kept by the filter exactly when
    # Node.receive does not drop it as `irrelevant` (DESIGN section 2, "What a robot
    # hears"), so dropping it in the kernel changes nothing the robot does.
    params = load_swarm(ROOT / "configs" / "paper.yaml").params()
    robots = sorted(plan.robots)
    # Every robot of the small swarms as receiver and sender; a spread of the grid's
    # (its every pair would take minutes through the interpreter).
    step = max(1, len(robots) // 16)
    senders = [*robots[::step], max(robots) + 1]
    slots = range(len(plan.functions) + 2)
    for robot in robots if step == 1 else robots[::step * 4]:
        made = socket_filter.program(("127.0.0.1", 40000), plan.unheard(robot))
        assert made is not None and made.unheard
        node = Node(robot, plan, params, 0.0)
        for swarm_id in (plan.swarm_id, plan.swarm_id ^ 1):
            for sender in senders:
                for slot in slots:
                    for key in (None, KEY):
                        data = heartbeat(swarm_id, sender, slot, key=key)
                        before = node.drops["irrelevant"]
                        node.receive(data, 0.0)
                        irrelevant = node.drops["irrelevant"] > before
                        kept = run_bpf(made.code, ("127.0.0.1", 40001), data)
                        assert kept != irrelevant, (robot, swarm_id, sender, slot, key)


def test_other_frames_and_garbage_are_kept() -> None:
    plan = plans()[0]
    made = socket_filter.program(None, plan.unheard(1))
    assert made is not None
    irrelevant = heartbeat(plan.swarm_id, 3, 3)  # robot 1 does not hear slot 3
    assert not run_bpf(made.code, ("127.0.0.1", 1), irrelevant)
    warn = wire.encode(wire.Frame(plan.swarm_id, 3, 1000, wire.Warn(4, 3, 1)))
    for data in (b"", b"\x11", irrelevant[:13], warn, bytes(64), b"\x21" + irrelevant[1:]):
        assert run_bpf(made.code, ("127.0.0.1", 1), data)


def test_a_swarm_too_large_for_classic_bpf_keeps_only_the_echo_filter() -> None:
    many = frozenset(range(1, 5000))
    made = socket_filter.program(("127.0.0.1", 40000), Unheard(7, many, frozenset(), many))
    assert made is not None and not made.unheard
    assert made == socket_filter.program(("127.0.0.1", 40000), None)



async def test_a_heartbeat_robot_1_does_not_hear_never_reaches_its_transport(
        udp_port: int) -> None:
    plan = plans()[0]
    t = UdpTransport(port=udp_port, unheard=plan.unheard(1))
    got: list[bytes] = []
    heard = asyncio.Event()

    def frame(data: bytes) -> None:
        got.append(data)
        heard.set()

    await t.start(frame, lambda event: None)
    try:
        assert t.echoes_filtered and t.unheard_filtered
        send_to_group(t.group, udp_port, heartbeat(plan.swarm_id, 3, 3))  # slot 3: not robot 1's
        send_to_group(t.group, udp_port, heartbeat(plan.swarm_id, 2, 2))  # its neighbour's
        await asyncio.wait_for(heard.wait(), 2.0)
        await asyncio.sleep(0.05)
        assert got == [heartbeat(plan.swarm_id, 2, 2)]
    finally:
        await t.close()
