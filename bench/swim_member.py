"""One swim-protocol member for `bench_peers.py`, run by the interpreter of the venv that
holds swim-protocol (stdlib and swimprotocol only: it never imports swarmd).

    python swim_member.py --name 127.0.0.1:PORT --peer 127.0.0.1:PORT2 ... --scale 1

Timings are swim-protocol's defaults divided by `--scale` (ping 1 s, ping timeout 0.3 s,
ping-req timeout 0.9 s, suspect 5 s, sync 0.5 s). `--loss P` drops each received
datagram with probability P (drawn per datagram and per receiver, as `swarmd sim
--loss`); with `--burst-len L` the losses come in bursts, L datagrams long on average,
per sending member (Gilbert-Elliott, as `swarmd sim --loss-model burst --burst-len L`:
sim/shared/channel.py, rewritten here since this script never imports swarmd).
Prints JSON lines on stdout: one per status change it sees
(`{"t", "member", "status"}`, wall-clock t) and `{"t", "sent", "bytes"}` every 0.25 s
(datagrams and UDP payload bytes this member sent so far).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import signal
import sys
import time
from typing import Any

from swimprotocol.members import Member, Members
from swimprotocol.udp import UdpTransport
from swimprotocol.udp.config import UdpConfig
from swimprotocol.udp.pack import UdpPack
from swimprotocol.udp.protocol import UdpProtocol
from swimprotocol.worker import Worker

SENT = {"datagrams": 0, "bytes": 0}


def emit(record: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(record) + "\n")
    sys.stdout.flush()


class Bursts:
    """Per sending address, a two-state channel: a bad spell loses every datagram and
    lasts `burst_len` on average; the stationary share of bad is `loss`."""

    def __init__(self, loss: float, burst_len: float, rng: random.Random) -> None:
        self.to_good = 1.0 / burst_len
        self.to_bad = loss / (burst_len * (1.0 - loss)) if loss else 0.0
        self.rng = rng
        self.bad: set[tuple[str, int]] = set()

    def lost(self, addr: tuple[str, int]) -> bool:
        if addr in self.bad:
            if self.rng.random() < self.to_good:
                self.bad.discard(addr)
                return False
            return True
        if self.to_bad and self.rng.random() < self.to_bad:
            self.bad.add(addr)
            return True
        return False


def instrument(loss: float, seed: int, burst_len: float = 0.0) -> None:
    """Count what is sent (every packet is packed once) and drop received datagrams."""
    pack = UdpPack.pack
    rng = random.Random(seed)

    def counting_pack(self: UdpPack, packet: Any) -> bytes:
        data: bytes = pack(self, packet)
        SENT["datagrams"] += 1
        SENT["bytes"] += len(data)
        return data

    UdpPack.pack = counting_pack
    received = UdpProtocol.datagram_received

    bursts = Bursts(loss, burst_len, rng) if burst_len else None

    def lossy(self: UdpProtocol, data: bytes, addr: tuple[str, int]) -> None:
        lost = bursts.lost(addr) if bursts is not None else rng.random() < loss
        if not lost:
            received(self, data, addr)

    UdpProtocol.datagram_received = lossy


async def run(args: argparse.Namespace) -> None:
    s = args.scale
    config = UdpConfig(secret="bench", local_name=args.name, peers=args.peer,
                       ping_interval=1.0 / s, ping_timeout=0.3 / s,
                       ping_req_timeout=0.9 / s, suspect_timeout=5.0 / s,
                       sync_interval=0.5 / s)
    members = Members(config)
    worker = Worker(config, members)
    transport = UdpTransport(config, worker)
    done = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, done.set)
    loop.add_signal_handler(signal.SIGINT, done.set)

    async def on_update(member: Member) -> None:
        if not member.local:
            emit({"t": time.time(), "member": member.name, "status": member.status.name})

    async def counters() -> None:
        while True:
            emit({"t": time.time(), "sent": SENT["datagrams"], "bytes": SENT["bytes"]})
            await asyncio.sleep(0.25)

    async with transport, worker, members.listener.on_notify(on_update):
        task = asyncio.create_task(counters())
        await done.wait()
        task.cancel()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--name", required=True)
    ap.add_argument("--peer", action="append", default=[])
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--loss", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--burst-len", type=float, default=0.0,
                    help="mean loss burst in datagrams (0: independent losses)")
    args = ap.parse_args()
    instrument(args.loss, args.seed, args.burst_len)
    asyncio.run(run(args))


if __name__ == "__main__":
    main()
