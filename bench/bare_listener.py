"""The floor of an idle daemon's CPU: a bare asyncio process with none of swarmd's code
that joins the swarm's multicast group, reads every datagram as the udp transport does
and wakes at 10 Hz as the heartbeat timer does, until SIGTERM. `bench_daemon.py` runs it
beside robot 1 and reports its CPU: what waking up for each frame and each tick costs
this machine at its current load, which no change to the daemon's own code removes.

    python bench/bare_listener.py GROUP PORT
"""

from __future__ import annotations

import asyncio
import signal
import socket
import sys

READ_BATCH = 32
PERIOD = 0.1


def member(group: str, port: int) -> socket.socket:
    """A socket on `group:port` as swarmd.transport.udp opens it (loopback interface)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    sock.bind((group, port))
    iface = socket.inet_aton("127.0.0.1")
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton(group) + iface)
    sock.setblocking(False)
    return sock


async def listen(group: str, port: int) -> None:
    loop = asyncio.get_running_loop()
    sock = member(group, port)
    frames: list[bytes] = []

    def read() -> None:
        for _ in range(READ_BATCH):
            try:
                frames.append(sock.recv(2048))
            except (BlockingIOError, InterruptedError):
                break
        frames.clear()

    def tick(when: float) -> None:
        loop.call_at(when + PERIOD, tick, when + PERIOD)

    loop.add_reader(sock.fileno(), read)
    tick(loop.time())
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    print("ready", flush=True)
    await stop.wait()
    sock.close()


if __name__ == "__main__":
    asyncio.run(listen(sys.argv[1], int(sys.argv[2])))
