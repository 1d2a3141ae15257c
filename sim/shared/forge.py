"""What the `forge:R@T:ATTACK` fault sends: frames an insider holding robot R's key
forges (per-robot mode: R's own signing key and the swarm key; shared-key mode: the
swarm key). One definition, pure, so any simulator can deliver them.

- `epoch`: a HEARTBEAT as R for every slot R does not hold, at epoch 65535 (the probe
  that fenced a live holder and orphaned its slot on an unsigned swarm).
- `seq`: a HEARTBEAT and a WARN as R at sequence number 2^48-1 (the probe that made
  every robot drop R's later frames as replays).
- `claim`: a CLAIM as R for every slot R does not hold, at a new epoch each time (the
  wait state's silence, renewed forever).
- `warn`: WARNs in the names of every witness of every slot but R, about the slot's
  holder (a quorum of invented witnesses).
- `ahead`: two HEARTBEATs as R that anyone could make (no signature, a made-up chain
  link), one 91 minutes ahead of R's counter (beyond what receivers take, within what
  a robot that followed frames in its own name would have followed) and one 30 minutes
  ahead (within the receivers' clock bound, so they take it): a robot's counter must
  not move on them, and the receivers must keep hearing R's own next frames.
- `replay`: every frame R's radio recorded on the channel before T (the last
  `CAPTURE`), played back verbatim (the heartbeats of a robot that died since, to a
  standby that restarted since, say).

Forged frames in other robots' names carry R's signature (that is all R can make) and
a sequence number `CLEAR` above the last one R heard from that robot, clear of the
seqs the robot itself sends during a run: a forged frame that takes the very seq a
robot sends next gets that one frame of the robot dropped as a replay (one forged
frame per lost frame, a jam in that robot's name: DESIGN, "Sequence numbers"), which
is not what these attacks probe. R's own node hears them too (the insider is another
radio with R's key); its counter does not move on them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from swarmd.core import wire
from swarmd.core.auth import Signer
from swarmd.core.chain import LINK_LEN
from swarmd.core.node import Snapshot
from swarmd.core.plan import SwarmPlan

CLEAR = 100_000
"""How far above a robot's last seq forged frames start (about three hours of frames
at 10 Hz: clear of the robot's own; well within the receivers' clock bound)."""
REPEATING = frozenset({"claim", "warn", "replay"})
"""Attacks sent again every warn interval; `epoch` and `seq` are one burst."""
CAPTURE = 512
"""How many of the last frames on the channel a `replay` insider keeps."""


@dataclass
class _Insider:
    """The frames insider `snap.robot_id` has forged so far, and what it forges them
    with (`forged_frames`)."""

    plan: SwarmPlan
    snap: Snapshot
    seqs: Mapping[int, int]
    key: bytes | None
    signer: Signer | None
    out: list[bytes] = field(default_factory=list)

    def frame(self, sender: int, msg: wire.Message, seq: int | None = None) -> None:
        if seq is None:  # a little ahead of the last one heard, so it is not a replay
            seq = min(self.seqs.get(sender, self.snap.seq) + CLEAR + len(self.out), wire.SEQ_MAX)
        if self.signer is not None and isinstance(msg, wire.Heartbeat):
            # Per-robot mode: R's key signs a heartbeat of its own as an anchor, on a
            # chain of its own making (it cannot make another robot's links).
            msg = wire.Heartbeat(msg.function, msg.epoch, msg.role, msg.health, 0,
                                 bytes(LINK_LEN), anchor=True)
        self.out.append(wire.encode(wire.Frame(self.plan.swarm_id, sender, seq, msg),
                                    self.key, self.signer))


def forged_frames(attack: str, plan: SwarmPlan, snap: Snapshot, *, keys: Sequence[bytes],
                  signer: Signer | None, round_: int,
                  sniffed: Mapping[int, int] | None = None,
                  recorded: Sequence[bytes] = ()) -> list[bytes]:
    """The frames insider `snap.robot_id` sends at round `round_` (0, 1, ...);
    `sniffed`: the last seq of each robot on the channel (an insider's own radio hears
    every frame), else what R's node accepted; `recorded`: for `replay`, the frames its
    radio heard before the attack, oldest first."""
    seqs = sniffed if sniffed is not None else snap.peer_seq
    me = snap.robot_id
    key = keys[0] if keys else None
    insider = _Insider(plan, snap, seqs, key, signer)
    held = {f for f, (holder, _) in snap.known.items() if holder == me}
    match attack:
        case "epoch":
            for f in plan.functions:
                if f not in held:
                    insider.frame(me, wire.Heartbeat(plan.slot(f), 0xFFFF, 1, 0),
                                  snap.seq + CLEAR)
        case "seq":
            _seq_probe(insider)
        case "ahead":
            _ahead(insider)
        case "claim":
            _claims(insider, held, round_)
        case "warn":
            _warns(insider)
        case "replay":
            insider.out.extend(recorded[-CAPTURE:])
        case _:
            raise ValueError(f"unknown attack {attack!r}")
    return insider.out


def _seq_probe(insider: _Insider) -> None:
    """`seq`: a heartbeat and a warning as R at the highest sequence numbers."""
    plan, snap = insider.plan, insider.snap
    me = snap.robot_id
    mine = snap.function
    slot = plan.slot(mine) if mine is not None else 0
    insider.frame(me, wire.Heartbeat(slot, snap.epoch if slot else 0, int(snap.role), 0),
                  wire.SEQ_MAX - 1)
    some = plan.functions[0]
    holder, epoch = snap.known[some]
    insider.frame(me, wire.Warn(holder, plan.slot(some), max(0, epoch - 1)), wire.SEQ_MAX)


AHEAD_PROBES = (91 * 60 * 100_000, 30 * 60 * 100_000)
"""How far ahead of R's counter the `ahead` heartbeats are, in seq units (10 us)."""


def _ahead(insider: _Insider) -> None:
    """`ahead`: R's current heartbeat, far ahead, made without R's key."""
    plan, snap = insider.plan, insider.snap
    slot = plan.slot(snap.function) if snap.function is not None else 0
    linked = insider.signer is not None  # per-robot mode: a heartbeat carries a link
    for i, ahead in enumerate(AHEAD_PROBES):
        msg = wire.Heartbeat(slot, snap.epoch if slot else 0, int(snap.role), 0,
                             (7 + i) % 256 if linked else 0,
                             bytes([0x5A + i]) * LINK_LEN if linked else b"")
        frame = wire.Frame(plan.swarm_id, snap.robot_id, min(snap.seq + ahead, wire.SEQ_MAX),
                           msg)
        # The signer only makes `encode` lay out the link: a heartbeat that is no anchor
        # is not signed, so nothing here needs R's key.
        insider.out.append(wire.encode(frame, insider.key, insider.signer))


def _claims(insider: _Insider, held: set[str], round_: int) -> None:
    """`claim`: a claim as R for every slot it does not hold, a new epoch each round."""
    plan, snap = insider.plan, insider.snap
    for f in plan.functions:
        if f not in held:
            holder, epoch = snap.known[f]
            insider.frame(snap.robot_id,
                          wire.Claim(holder, plan.slot(f), min(0xFFFF, epoch + 1 + round_)),
                          snap.seq + CLEAR + round_ * len(plan.functions)
                          + len(insider.out))


def _warns(insider: _Insider) -> None:
    """`warn`: warnings in every other witness's name about each slot's holder."""
    plan, snap = insider.plan, insider.snap
    for f in plan.functions:
        holder, epoch = snap.known[f]
        for g in plan.watched_by(f):
            witness = snap.known[g][0]
            if witness not in (snap.robot_id, holder, 0):
                insider.frame(witness, wire.Warn(holder, plan.slot(f), epoch))
