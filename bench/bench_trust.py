"""Per-robot signatures: frame sizes, Ed25519 verifies per second, CPU at 100 robots,
and the 802.15.4 budget (DESIGN section 2, "Who may say what").

    python bench/bench_trust.py [--seconds 20] [--verifies 2000]

1. Frame sizes per message in each mode (unsigned, shared key, per-robot), below 128
   functions, from the codec itself.
2. Ed25519 with `cryptography` (the library `swarmd.base.identity` uses): signs and
   verifies per second on this machine, and HMAC-SHA256 tag checks for comparison.
3. configs/grid100.yaml (100 robots) in `sim.virtual`, per-robot mode with real
   Ed25519 keys, `--seconds` of virtual time with a crash in the middle: signature
   verifies per robot per second (steady state and overall), and process CPU per
   robot-second (what one daemon's protocol core costs, the simulator's own work
   included, so an upper bound).
4. The `radio()` preset on one 802.15.4 channel: airtime at 60 robots and the largest
   swarm below 30%, shared-key and per-robot (as shipped: robot keys only; and with a
   swarm key beside them). Per robot a heartbeat carries its chain link and some are
   signed anchors (`swarmd.core.chain`); a failover costs more.
"""

from __future__ import annotations

import argparse
import hashlib
import hmac
import time
from collections.abc import Mapping
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)

from sim.shared.faults import parse_fault
from sim.virtual.simulator import VirtualSwarm
from swarmd.config import load_swarm
from swarmd.core import wire
from swarmd.core.auth import Identity
from swarmd.core.params import radio
from swarmd.services import budget

ROOT = Path(__file__).resolve().parent.parent
KEY = b"k" * 32


class Signer:
    def __init__(self, robot: int, key: Ed25519PrivateKey) -> None:
        self.robot = robot
        self._key = key

    def sign(self, data: bytes) -> bytes:
        return self._key.sign(data)


class Verifier:
    def __init__(self, keys: Mapping[int, Ed25519PublicKey]) -> None:
        self._keys = dict(keys)
        self.calls = 0

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        self.calls += 1
        key = self._keys.get(robot)
        if key is None or len(signature) != 64:
            return False
        try:
            key.verify(signature, data)
        except InvalidSignature:
            return False
        return True


def identities(robots: list[int]) -> tuple[dict[int, Identity], Verifier]:
    private = {r: Ed25519PrivateKey.generate() for r in robots}
    verifier = Verifier({r: k.public_key() for r, k in private.items()})
    return {r: Identity(Signer(r, k), verifier) for r, k in private.items()}, verifier


def frame_sizes() -> None:
    ids, _ = identities([1, 2, 3])
    messages: list[tuple[str, wire.Message]] = [
        ("HEARTBEAT", wire.Heartbeat(1, 0, 1, 0)), ("WARN", wire.Warn(2, 1, 0)),
        ("CLAIM", wire.Claim(2, 1, 1)), ("LEAVE", wire.Leave(1, 0, 0)),
    ]
    print("frame sizes, bytes (fewer than 128 functions):")
    print(f"  {'message':<10} {'unsigned':>9} {'shared key':>11} {'per-robot':>10}")
    warn = b""
    for name, msg in messages:
        frame = wire.Frame(1, 1, 1, msg)
        if name == "HEARTBEAT":
            print(f"  {name:<10} {len(wire.encode(frame)):>9} "
                  f"{len(wire.encode(frame, KEY)):>11} {'':>10}")
            continue
        per_robot = wire.encode(frame, KEY, ids[1].signer)
        if name == "WARN":
            warn = per_robot
        print(f"  {name:<10} {len(wire.encode(frame)):>9} {len(wire.encode(frame, KEY)):>11} "
              f"{len(per_robot):>10}")
    link = wire.Frame(1, 1, 1, wire.Heartbeat(1, 0, 1, 0, 1, bytes(8)))
    anchor = wire.Frame(1, 1, 1, wire.Heartbeat(1, 0, 1, 0, 1, bytes(8), anchor=True))
    print(f"  {'  link':<10} {'-':>9} {'-':>11} {len(wire.encode(link, None, ids[1].signer)):>10}"
          f"   (per robot: the chain link; {len(wire.encode(link, KEY, ids[1].signer))} B "
          f"with a swarm key's tag beside)")
    anchor_len = len(wire.encode(anchor, KEY, ids[1].signer))
    print(f"  {'  anchor':<10} {'-':>9} {'-':>11} {anchor_len:>10}"
          f"   (per robot: signed, one a second at udp(), one in 5 s at radio())")
    blank = wire.Frame(0, 0, 0, wire.Heartbeat(0, 0, 0, 0))
    cert = wire.encode(wire.Frame(1, 1, 1, wire.Cert(1, blank, warn)), KEY, ids[1].signer)
    print(f"  {'CERT':<10} {'-':>9} {'-':>11} {len(cert):>10}   (one per witness, with a claim)")
    print(f"  payload limits: 802.15.4 {budget.MAX_PAYLOAD['802.15.4']} B, "
          f"Zigbee {budget.MAX_PAYLOAD['zigbee']} B, DigiMesh {budget.MAX_PAYLOAD['digimesh']} B")


def crypto_speed(n: int) -> float:
    key = Ed25519PrivateKey.generate()
    pub = key.public_key()
    data = bytes(16)
    start = time.perf_counter()
    for _ in range(n):
        sig = key.sign(data)
    signs = n / (time.perf_counter() - start)
    start = time.perf_counter()
    for _ in range(n):
        pub.verify(sig, data)
    verifies = n / (time.perf_counter() - start)
    start = time.perf_counter()
    for _ in range(n):
        hmac.compare_digest(hmac.new(KEY, data, hashlib.sha256).digest()[:8], bytes(8))
    tags = n / (time.perf_counter() - start)
    print(f"Ed25519 (cryptography): {signs:,.0f} signs/s, {verifies:,.0f} verifies/s; "
          f"HMAC-SHA256 tag checks: {tags:,.0f}/s (one core)")
    return verifies


def cpu_at_100(seconds: float, verifies_per_s: float) -> None:
    cfg = load_swarm(ROOT / "configs" / "grid100.yaml")
    plan, params = cfg.to_plan(), cfg.params()
    robots = sorted(plan.robots)
    ids, verifier = identities(robots)
    victim = next(r for r in robots if plan.robots[r].function is not None)
    half = seconds / 2
    steady = VirtualSwarm(plan, params, duration=half, keys=(KEY,), auth="per-robot",
                          identities=ids)
    steady.run()
    calls_steady = verifier.calls
    verifier.calls = 0
    swarm = VirtualSwarm(plan, params, duration=seconds, keys=(KEY,), auth="per-robot",
                         identities=ids, faults=[parse_fault(f"crash:{victim}@{half}")])
    start = time.process_time()
    res = swarm.run()
    cpu = time.process_time() - start
    robot_seconds = seconds * len(robots)
    took = [e for e in res.events if e["event"] == "takeover"]
    print(f"{len(robots)} robots (configs/grid100.yaml, udp preset), per-robot mode, "
          f"real Ed25519:")
    print(f"  steady state: {calls_steady / (half * len(robots)):.3f} verifies per robot per s "
          f"(the heartbeat anchors: one a second per robot; links are hash checks)")
    print(f"  with a crash at {half:.0f} s: {verifier.calls} signed frames in {seconds:.0f} s "
          f"(the simulator verifies a broadcast once; a daemon verifies each one it hears: "
          f"at most {verifier.calls} verifies, "
          f"{verifier.calls / verifies_per_s * 1000:.1f} ms of CPU), {len(took)} "
          f"takeover(s), violations: {len(res.violations)}")
    print(f"  process CPU {cpu:.2f} s for {robot_seconds:.0f} robot-seconds: "
          f"{100 * cpu / robot_seconds:.3f}% of one core per robot (simulator included)")


def radio_budget() -> None:
    params = radio()
    print("802.15.4 channel at the radio() preset (2/3 active, 1/3 standby, ring):")
    for mode, signed, per_robot in (("shared key", True, False), ("per-robot", False, True),
                                    ("per-robot+key", True, True)):
        b = budget.budget_for(40, 20, 2, params, medium="802.15.4", signed=signed,
                              per_robot=per_robot)
        most = budget.largest_swarm(params, per_robot=per_robot, signed=signed)
        share = b.airtime_share or 0.0
        peak = b.peak_airtime_share or 0.0
        print(f"  {mode:<13}: 60 robots {share:.1%} airtime steady, {peak:.1%} during a "
              f"failover; largest swarm below 30%: {most} robots")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--verifies", type=int, default=2000)
    args = ap.parse_args()
    frame_sizes()
    cpu_at_100(args.seconds, crypto_speed(args.verifies))
    radio_budget()


if __name__ == "__main__":
    main()
