"""A passive listener on the swarm channel: the paper's base station (section III-C).

`MonitorState` is sans-IO like the core: `feed(frame, now)` folds one frame into a view of
every robot heard; `rows(now)` / `alerts(now)` / `to_json(now)` read it. `listen()` is
the thin I/O part: it opens the swarm's transport, never sends anything (a base station
that transmitted would be a robot), and feeds received frames with the loop's clock.

What it shows, per robot: role, function and epoch from its last HEARTBEAT, how long ago
it was heard, its reported health, its status, who currently warns about it (the paper's
warnings, Fig. 2) and how many distinct witnesses that is within the vote window (what a
standby counts, Fig. 9 and DESIGN rule 3). The status is `live`; `silent` when nothing
was heard from it for longer than its heartbeat timeout (`t_max` for an active,
`standby_timeout` for a standby, whose heartbeats are rarer: DESIGN rule 6);
`superseded` when another robot has since been heard executing its function at a newer
epoch, so its last heartbeat is history, not the holder (DESIGN rule 2); `left` after a
LEAVE. Alerts are the things an operator must look at:
- a function whose holder has been silent longer than `t_max` (nobody heartbeats it);
- warnings about a robot for longer than `alert_after` with no CLAIM (DESIGN rule 8:
  nobody is coming to take over);
- a LEAVE with no CLAIM after `alert_after`;
- two robots heartbeating the same function at the same epoch (split brain: DESIGN
  rule 2 says this must never last).
Frames that do not decode (garbage, wrong key, another swarm, replays) are counted by
reason, never raised (DESIGN section 2).

The receive filter is the daemons' (`swarmd.core.replay`): a sliding window per sender,
and sequence numbers bounded by the monitor's own clock (`listen` starts it from the wall
clock), so one bit-flipped or forged frame far ahead is a `seq_jump` drop, not a robot
muted for good that shows `silent` with false alerts. What the monitor cannot verify it
shows as such: a heartbeat is no proof (per robot it is signed by no robot), so a
heartbeat at a newer epoch (or of another robot at the plan's epoch 0) is believed only
from the robot whose CLAIM for that slot and epoch was heard *with its certificate*,
judged exactly as a daemon judges it in every auth mode (`swarmd.daemon.monitor_claims`:
a CLAIM alone, which any insider can make for a slot it covers, vouches for nothing).
Any other is shown with the status `unverified` and moves nobody: no `superseded`, no
split brain. A monitor started after a takeover has not heard its claim, so the new
holder shows `unverified` until it overhears the claim again with its certificate (the
new holder relays both to any robot that still shows an older view). What the daemons
take, the monitor shows.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from swarmd.core import wire
from swarmd.core.auth import Verifier
from swarmd.core.belief import byte_level
from swarmd.core.chain import PeerChains
from swarmd.core.drops import DropReason
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.replay import ReplayFilter
from swarmd.core.roles import Health, Role
from swarmd.daemon.monitor_claims import MonitorClaims
from swarmd.transport.base import ChannelError, ChannelEvent, SendError, Transport


class MonitorDrop(StrEnum):
    """What only the monitor refuses; everything else it counts as the core would
    (`DropReason`)."""

    OTHER_SWARM = "other_swarm"
    """Another swarm's frame: a base station may share the channel with other swarms."""
    SEND_ERROR = "transport_send_error"
    """The monitor's own transport could not send (it sends nothing: a radio's report)."""
    CHANNEL_ERROR = "transport_error"
    """Its transport met an error that does not stop the channel (`ChannelError`)."""


@dataclass(slots=True)
class Heard:
    """What the monitor knows about one robot."""

    robot: int
    last_heard: float
    role: str | None = None
    function: str | None = None
    epoch: int | None = None
    health: str | None = None
    frames: int = 0
    last_seq: int = -1
    warned_by: dict[int, float] = field(default_factory=dict)
    """witness -> time of its last WARN naming this robot (its suspicion)."""
    warned_since: float | None = None
    leave_at: float | None = None
    leave_function: str | None = None
    unverified: bool = False
    """Its last heartbeat named a holder no certificate heard here backs (module
    docstring)."""


def _name(enum: type[Role] | type[Health], value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return f"?{value}"


class MonitorState:
    """Everything heard on the channel, folded per robot. Pure: time is an argument."""

    def __init__(self, plan: SwarmPlan, params: Params, keys: Sequence[bytes] = (),
                 verifier: Verifier | None = None) -> None:
        self.plan = plan
        self.params = params
        self.keys = tuple(keys)
        self.verifier = verifier
        """Per-robot mode: the robots' public keys, to read signed WARN/CLAIM/LEAVE."""
        self.robots: dict[int, Heard] = {}
        self.drops: dict[str, int] = {}
        self.frames = 0
        self.claims: dict[str, tuple[int, int, float]] = {}
        """function -> (claimant, epoch, time) of the last CLAIM heard."""
        self.newest: dict[str, tuple[int, int]] = {}
        """function -> (epoch, robot) of the newest-epoch ACTIVE heartbeat heard for it."""
        self.certified = MonitorClaims(plan, params)
        """The takeovers a daemon would believe (`monitor_claims`)."""
        self.chains = PeerChains(1 / params.heartbeat_interval)
        """Per-robot mode: each robot's heartbeat chain (`swarmd.core.chain`)."""
        self.replay = ReplayFilter()
        """The daemons' filter; unbounded until `start_clock` (`listen` calls it)."""

    def start_clock(self, origin: int, now: float) -> None:
        """Bound sequence numbers by the monitor's own clock from `now` on: `origin` is
        the wall clock at `now` in sequence units (`wire.seq_seed`)."""
        self.replay.origin, self.replay.since = origin, now

    def _believed(self, function: str, epoch: int, robot: int) -> bool:
        """Whether a heartbeat of `robot` holding `function` at `epoch` is vouched for
        (module docstring)."""
        if epoch == 0 and self.plan.initial_holder(function) == robot:
            return True
        return self.certified.believed(function, epoch, robot)

    def _drop(self, reason: DropReason | MonitorDrop) -> None:
        self.drops[reason] = self.drops.get(reason, 0) + 1

    def feed(self, data: bytes, now: float) -> None:
        """Fold one frame in. Never raises on peer input (counted drop instead)."""
        frame = self._accept(data, now)
        if frame is None:
            return
        seen = self.robots.get(frame.sender)
        if seen is None:
            seen = self.robots[frame.sender] = Heard(frame.sender, now)
        self.frames += 1
        seen.last_seq = frame.seq
        seen.last_heard = now
        seen.frames += 1
        self.certified.frame(frame, now)  # evidence, refutes and claims, as a daemon
        match frame.msg:
            case wire.Heartbeat(function, epoch, role, health):
                self._on_heartbeat(seen, frame.sender, function, epoch, role, health)
            case wire.Warn(suspect, function, _epoch, belief) \
                    if byte_level(belief) >= self.params.suspect_level:
                # A suspicion; a doubt (a weaker level, DESIGN "Detection") only asks
                # the robot to answer, and no standby counts it: neither does the table.
                target = self.robots.get(suspect)
                if target is None and suspect in self.plan.robots:
                    target = self.robots[suspect] = Heard(suspect, float("-inf"))
                if target is not None and suspect != frame.sender:
                    if not self._fresh_warnings(target, now):
                        target.warned_since = now
                    target.warned_by[frame.sender] = now
            case wire.Claim(failed, function, epoch):
                self._on_claim(frame.sender, failed, function, epoch, now)
            case wire.Leave(function, _epoch, _reason):
                seen.leave_at = now
                seen.leave_function = self.plan.function_at(function)
                seen.function = None

    def _accept(self, data: bytes, now: float) -> wire.Frame | None:
        """The frame, if it is this swarm's, authentic and new (as the daemons judge);
        None when dropped (counted) or a certificate."""
        try:
            frame = wire.decode(data, self.keys, self.verifier)
        except wire.CodecError as exc:
            self._drop(exc.reason)
            return None
        if frame.swarm_id != self.plan.swarm_id:
            self._drop(MonitorDrop.OTHER_SWARM)
            return None
        if frame.sender not in self.plan.robots:
            self._drop(DropReason.UNKNOWN_SENDER)
            return None
        if isinstance(frame.msg, wire.Cert):
            # Relays a frame judged on its own: no replay filter, as in the daemons; a
            # piece of a certificate, perhaps (`monitor_claims`).
            self.certified.frame(frame, now)
            return None
        msg = frame.msg
        if isinstance(msg, wire.Heartbeat) and self.verifier is not None \
                and not self.chains.check(frame.sender, msg.n, msg.link, now,
                                          anchor=msg.anchor):
            # As the daemons: a heartbeat counts only if its link is its sender's own
            # (a monitor started late waits for each robot's next anchor).
            self._drop(DropReason.UNANCHORED)
            return None
        reason = self.replay.check(frame.sender, frame.seq, now)
        if reason is not None:
            self._drop(reason)
            return None
        if isinstance(msg, wire.Heartbeat) and self.verifier is not None:
            self.chains.commit(frame.sender, msg.n, msg.link, now, anchor=msg.anchor)
        return frame

    def _on_heartbeat(self, seen: Heard, sender: int, function: int, epoch: int, role: int,
                      health: int) -> None:
        seen.role = _name(Role, role)
        seen.function = self.plan.function_at(function)
        # Without a slot the field is the sender's view digest (`core/digest.py`), not
        # an epoch of its own: the row shows none.
        seen.epoch = epoch if seen.function is not None else None
        seen.health = _name(Health, health)
        seen.unverified = seen.function is not None \
            and seen.role == Role.ACTIVE.name \
            and not self._believed(seen.function, epoch, sender)
        if seen.function is not None and seen.role == Role.ACTIVE.name \
                and not seen.unverified:
            newest = self.newest.get(seen.function)
            if newest is None or epoch >= newest[0]:
                self.newest[seen.function] = (epoch, sender)

    def _on_claim(self, sender: int, failed: int, function: int, epoch: int,
                  now: float) -> None:
        name = self.plan.function_at(function)
        if name is not None:
            self.claims[name] = (sender, epoch, now)
        failed_seen = self.robots.get(failed)
        if failed_seen is not None:
            # A claim tells the watchers to stop warning (paper section IV-A).
            failed_seen.warned_by.clear()
            failed_seen.warned_since = None

    def _fresh_warnings(self, seen: Heard, now: float) -> dict[int, float]:
        window = self.params.vote_window
        return {w: t for w, t in seen.warned_by.items() if now - t <= window}

    def silent(self, seen: Heard, now: float) -> bool:
        """No frame from this robot for longer than its heartbeat timeout (rules 1, 6)."""
        if seen.frames == 0:
            return True
        timeout = (self.params.standby_timeout if seen.role == Role.STANDBY.name
                   else self.params.t_max)
        return now - seen.last_heard > timeout

    def superseded(self, seen: Heard) -> bool:
        """Another robot was heard executing this robot's function at a newer epoch."""
        if seen.function is None or seen.role != Role.ACTIVE.name or seen.epoch is None \
                or seen.unverified:
            return False
        newest = self.newest.get(seen.function)
        return newest is not None and newest[0] > seen.epoch and newest[1] != seen.robot

    def status(self, seen: Heard, now: float) -> str:
        """`live`, `silent`, `superseded`, `superseded, silent` or `left`; `unverified`
        first when its heartbeat names a holder no certificate heard here backs."""
        if seen.leave_at is not None and seen.last_heard <= seen.leave_at:
            return "left"  # nothing heard since its LEAVE
        parts = ["unverified"] if seen.unverified else []
        if self.superseded(seen):
            parts.append("superseded")
        if self.silent(seen, now):
            parts.append("silent")
        return ", ".join(parts) or "live"

    def rows(self, now: float) -> list[dict[str, Any]]:
        """One dict per robot heard (or warned about), by robot id."""
        out = []
        for rid in sorted(self.robots):
            seen = self.robots[rid]
            fresh = self._fresh_warnings(seen, now)
            out.append({
                "robot": rid,
                "role": seen.role,
                "function": seen.function,
                "epoch": seen.epoch,
                "last_heard_s": None if seen.frames == 0 else round(now - seen.last_heard, 3),
                "health": seen.health,
                "status": self.status(seen, now),
                "warned_by": sorted(fresh),
                "votes": len(fresh),
                "alerts": self._robot_alerts(seen, now),
            })
        return out

    def _live_holders(self, function: str, now: float) -> list[int]:
        return sorted(
            rid for rid, seen in self.robots.items()
            if seen.function == function and seen.role == Role.ACTIVE.name
            and seen.frames and now - seen.last_heard <= self.params.t_max
            and not self.superseded(seen) and not seen.unverified
        )

    def _robot_alerts(self, seen: Heard, now: float) -> list[str]:
        p = self.params
        alerts = []
        silent = seen.frames == 0 or now - seen.last_heard > p.t_max
        if (seen.function is not None and silent and seen.role == Role.ACTIVE.name
                and not self.superseded(seen) and not seen.unverified
                and not self._live_holders(seen.function, now)):
            alerts.append(f"holder of {seen.function} silent for "
                          f"{now - seen.last_heard:.1f} s")
        fresh = self._fresh_warnings(seen, now)
        if fresh and seen.warned_since is not None and now - seen.warned_since > p.alert_after:
            alerts.append(f"warned about by {sorted(fresh)} for {now - seen.warned_since:.1f} s "
                          "and nobody claimed")
        if seen.leave_at is not None and seen.leave_function is not None:
            claim = self.claims.get(seen.leave_function)
            if (claim is None or claim[2] < seen.leave_at) and now - seen.leave_at > p.alert_after:
                alerts.append(f"left {seen.leave_function} {now - seen.leave_at:.1f} s ago "
                              "and nobody claimed")
        return alerts

    def alerts(self, now: float) -> list[str]:
        """Swarm-wide alerts: per-robot ones plus split brain (two live holders)."""
        out = [f"robot {r['robot']}: {a}" for r in self.rows(now) for a in r["alerts"]]
        holders: dict[tuple[str, int], list[int]] = {}
        for rid, seen in self.robots.items():
            live = seen.frames and now - seen.last_heard <= self.params.t_max
            if (live and seen.function is not None and seen.role == Role.ACTIVE.name
                    and not self.superseded(seen) and not seen.unverified):
                holders.setdefault((seen.function, seen.epoch or 0), []).append(rid)
        for (function, epoch), rids in sorted(holders.items()):
            if len(rids) > 1:
                out.append(f"{function} executed by robots {sorted(rids)} at epoch {epoch} "
                           "(split brain)")
        return out

    def to_json(self, now: float, listened: float | None = None) -> dict[str, Any]:
        """The `--json` document."""
        doc: dict[str, Any] = {
            "swarm_id": self.plan.swarm_id,
            "robots": self.rows(now),
            "alerts": self.alerts(now),
            "frames": self.frames,
            "drops": dict(sorted(self.drops.items())),
        }
        if listened is not None:
            doc["listened_s"] = round(listened, 3)
        return doc

    def table(self, now: float) -> Any:
        """A rich renderable: the robots table and the alerts under it. It fits 80
        columns: no outer box, short cells that never wrap (ids, roles, numbers), and
        each robot's alerts in the ALERT lines under the table (full sentences that a
        column would cut), its id in red when it has one."""
        from rich import box
        from rich.console import Group
        from rich.table import Table
        from rich.text import Text

        table = Table(title=f"swarm {self.plan.swarm_id}: {len(self.robots)} robots heard, "
                            f"{self.frames} frames, {sum(self.drops.values())} dropped",
                      box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False,
                      padding=(0, 1, 0, 0), title_justify="left")
        for col, wrap in (("robot", False), ("status", True), ("role", False),
                          ("function", False), ("epoch", False), ("heard", False),
                          ("health", False), ("warned by", True), ("votes", False)):
            table.add_column(col, no_wrap=not wrap, min_width=6 if wrap else None)
        styles = {"live": "", "left": "dim"}
        for row in self.rows(now):
            heard = row["last_heard_s"]
            table.add_row(
                Text(str(row["robot"]), style="bold red" if row["alerts"] else ""),
                Text(row["status"], style=styles.get(row["status"], "bold yellow")),
                row["role"] or "-", row["function"] or "-",
                "-" if row["epoch"] is None else str(row["epoch"]),
                "never" if heard is None else f"{heard:.1f} s", row["health"] or "-",
                ", ".join(map(str, row["warned_by"])) or "-", str(row["votes"]),
            )
        alerts = self.alerts(now)
        lines = [Text(f"ALERT {a}", style="bold red") for a in alerts]
        return Group(table, *lines)


async def listen(
    state: MonitorState,
    transport: Transport,
    *,
    duration: float | None,
    on_refresh: Any = None,
    refresh: float = 0.25,
) -> float:
    """Feed every received frame to `state` for `duration` s (None: until cancelled).

    Passive: `transport.send` is never called. Returns the seconds listened.
    `on_refresh(now)` is called every `refresh` s (the live table)."""
    loop = asyncio.get_running_loop()
    start = loop.time()
    # The daemons' bound on sequence numbers: our own wall clock, from now on.
    state.start_clock(wire.seq_seed(time.time()), start)

    def on_frame(data: bytes) -> None:
        state.feed(data, loop.time())

    def on_event(event: ChannelEvent) -> None:
        match event:
            case SendError():
                state._drop(MonitorDrop.SEND_ERROR)
            case ChannelError():
                state._drop(MonitorDrop.CHANNEL_ERROR)

    await transport.start(on_frame, on_event)
    try:
        end = None if duration is None else start + duration
        while end is None or loop.time() < end:
            wait = refresh if end is None else max(0.0, min(refresh, end - loop.time()))
            await asyncio.sleep(wait)
            if on_refresh is not None:
                on_refresh(loop.time())
    finally:
        await transport.close()
    return loop.time() - start
