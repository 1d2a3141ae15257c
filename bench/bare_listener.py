"""The floor of an idle daemon's CPU: a bare process on the daemon's event loop
(`swarmd.base.eventloop`: uvloop when installed) with none of swarmd's per-frame code
that joins the swarm's multicast group, reads every datagram as the udp
transport does and wakes as the heartbeat timer does, until SIGTERM. `bench_daemon.py`
runs it beside robot 1 and reports its CPU: what waking up for each frame and each tick
costs this machine at its current load, which no change to the daemon's own code removes.

With `--as ROBOT` it also does the work of that robot that no change to the daemon's
code removes without changing the frames on the wire (DESIGN section 2, "Who may say
what"), for the frames that robot checks at all (its neighbourhood, `SwarmPlan.relevant`:
the others it drops before any check):
- it is not woken by the heartbeats that robot does not hear: the daemon's own socket
  filter drops them in the kernel (`swarmd/transport/socket_filter.py`,
  `SwarmPlan.unheard`), so the floor's socket carries the same one;
- it sends a heartbeat-sized frame every period of that robot (active or standby), to a
  port nobody listens on, so the swarm hears nothing more;
- `--auth per-robot`: Ed25519 verification of every anchor it hears (a heartbeat with its
  sender's signature) with the sender's real public key, one BLAKE2b chain step
  (`chain.step`) for every other heartbeat, and an Ed25519 signature of its own anchor
  every `chain.anchor_every` seconds;
- `--auth shared`: the swarm key's tag (`wire.tag`, HMAC-SHA256) checked on every frame
  heard and computed on every frame sent;
- `--auth none`: nothing more.
The swarm file, keys and timings are read once at start; nothing of swarmd runs per
frame but `chain.step` and `wire.tag`, the two primitives themselves.

    python bench/bare_listener.py GROUP PORT [--as ROBOT --swarm FILE
                                  [--auth per-robot --keys DIR | --auth shared --key FILE]]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import hmac
import signal
import socket
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)

from swarmd.base import eventloop, identity
from swarmd.base.keys import load_key
from swarmd.config.swarm_rules import load_swarm
from swarmd.core import chain, wire
from swarmd.core.plan import Unheard
from swarmd.transport import socket_filter

READ_BATCH = 32
PERIOD = 0.1
SIGNATURE = 64
HEARTBEAT_LEN = 24
"""bytes of a per-robot heartbeat without its signature (wire.py's layout)."""


@dataclass
class Work:
    """What the floor does per frame heard and per period, as `--as` says."""

    robot: int | None = None
    period: float = PERIOD
    hear: frozenset[int] = frozenset()
    """Senders whose frames are checked (the robot's neighbourhood)."""
    unheard: Unheard | None = None
    """The heartbeats dropped in the kernel, as the daemon's socket drops them."""
    check: Callable[[int, bytes], None] | None = None
    sign: Callable[[bytes], bytes] | None = None
    anchor_every: float = float("inf")
    send: bool = False
    links: dict[int, bytes] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("frames", "checked", "anchors", "sent", "signed"), 0))
    """What it did, told on stderr at SIGTERM: the rates the floor stands for."""


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


def sender_socket() -> tuple[socket.socket, int]:
    """A socket sending to the group on a port nobody listens on: its own, bound to
    127.0.0.1 (a multicast datagram matches no socket bound to a unicast address), so
    the swarm's daemons hear none of the floor's frames. TTL 1, loopback interface."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    sock.bind(("127.0.0.1", 0))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    sock.setblocking(False)
    port: int = sock.getsockname()[1]
    return sock, port


def per_robot_check(keys_dir: Path, robots: frozenset[int], links: dict[int, bytes],
                    counts: dict[str, int]) -> Callable[[int, bytes], None]:
    """An anchor's signature verified with its sender's key, any other heartbeat's link
    hashed once and compared with the last one (`chain.PeerChains.check`)."""
    public = {r: Ed25519PublicKey.from_public_bytes(
        identity.read_public_keys(identity.public_key_path(keys_dir, r))[0]) for r in robots}

    def check(sender: int, data: bytes) -> None:
        if data[0] & 0x08 and len(data) > SIGNATURE:
            counts["anchors"] += 1
            with contextlib.suppress(InvalidSignature):
                public[sender].verify(data[-SIGNATURE:], data[:-SIGNATURE])
            links[sender] = data[-SIGNATURE - chain.LINK_LEN:-SIGNATURE]
            return
        link = data[-chain.LINK_LEN:]
        hmac.compare_digest(chain.step(sender, link), links.get(sender, b""))
        links[sender] = link

    return check


def shared_check(key: bytes) -> Callable[[int, bytes], None]:
    def check(sender: int, data: bytes) -> None:
        hmac.compare_digest(wire.tag(key, data[:-wire.TAG_LEN]), data[-wire.TAG_LEN:])

    return check


def work_of(args: argparse.Namespace) -> Work:
    """What robot `args.robot` does beyond waking up, read from its swarm file."""
    if args.robot is None:
        return Work()
    cfg = load_swarm(args.swarm)
    plan, params = cfg.to_plan(), cfg.params()
    near = plan.relevant(args.robot)
    # Idle, every slot is held by its initial holder: the senders of its frames.
    holders = {plan.initial_holder(f) for f in map(plan.function_at, near.slots) if f}
    hear = frozenset(r for r in holders | near.standbys if r and r != args.robot)
    standby = plan.robots[args.robot].function is None
    period = params.standby_heartbeat_interval if standby else params.heartbeat_interval
    work = Work(robot=args.robot, period=period, hear=hear, unheard=plan.unheard(args.robot),
                send=True)
    if args.auth == "per-robot":
        work.check = per_robot_check(args.keys, hear, work.links, work.counts)
        key = Ed25519PrivateKey.from_private_bytes(
            identity.read_private_key(identity.private_key_path(args.keys, args.robot)))
        work.sign, work.anchor_every = key.sign, chain.anchor_every(params)
    elif args.auth == "shared":
        swarm_key = load_key(args.key)
        work.check = shared_check(swarm_key)
        work.sign, work.anchor_every = (lambda data: wire.tag(swarm_key, data)), 0.0
    return work


async def listen(group: str, port: int, work: Work) -> None:
    loop = asyncio.get_running_loop()
    sock = member(group, port)
    made = socket_filter.program(None, work.unheard)
    if made is not None and not socket_filter.attach(sock, made.code):
        print("floor: no socket filter here; it wakes for every heartbeat", file=sys.stderr)
    out, out_port = sender_socket()
    frames: list[bytes] = []
    hear, check, counts = work.hear, work.check, work.counts
    last_anchor = [float("-inf")]
    frame = bytes(HEARTBEAT_LEN)

    def read() -> None:
        for _ in range(READ_BATCH):
            try:
                data = sock.recv(2048)
            except (BlockingIOError, InterruptedError):
                break
            frames.append(data)
            counts["frames"] += 1
            if check is not None and len(data) > wire.HEADER_LEN:
                sender = (data[3] << 8) | data[4]
                if sender in hear:
                    counts["checked"] += 1
                    check(sender, data)
        frames.clear()

    def beat(now: float) -> None:
        data = frame
        if work.sign is not None and now - last_anchor[0] >= work.anchor_every:
            last_anchor[0] = now
            data = frame + work.sign(frame)
            counts["signed"] += 1
        counts["sent"] += 1
        with contextlib.suppress(OSError):
            out.sendto(data, (group, out_port))

    def tick(when: float) -> None:
        if work.send:
            beat(when)
        loop.call_at(when + work.period, tick, when + work.period)

    loop.add_reader(sock.fileno(), read)
    tick(loop.time())
    stop = asyncio.Event()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    print("ready", flush=True)
    started = loop.time()
    await stop.wait()
    seconds = loop.time() - started
    rates = ", ".join(f"{n / seconds:.1f} {what}/s" for what, n in counts.items())
    print(f"floor of robot {work.robot}: {rates} over {seconds:.0f} s", file=sys.stderr)
    sock.close()
    out.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("group")
    ap.add_argument("port", type=int)
    ap.add_argument("--as", dest="robot", type=int, help="do this robot's unavoidable work")
    ap.add_argument("--swarm", type=Path, help="the swarm file (with --as)")
    ap.add_argument("--auth", choices=("none", "per-robot", "shared"), default="none")
    ap.add_argument("--keys", type=Path, help="per-robot keys directory")
    ap.add_argument("--key", type=Path, help="shared swarm key file")
    args = ap.parse_args()
    if args.robot is not None and args.swarm is None:
        ap.error("--as needs --swarm")
    # The daemon's own loop (uvloop when installed): waking up is most of the floor.
    eventloop.run(listen(args.group, args.port, work_of(args)))


if __name__ == "__main__":
    main()
