"""Channel budget: what a swarm puts on the air, and whether the radio can carry it.

`swarmd check` prints this. The numbers come from the plan and the
timing parameters, not from measurement:

- frames/s: every ACTIVE robot heartbeats each `heartbeat_interval`, every STANDBY each
  `standby_heartbeat_interval` (DESIGN section 2). During a failover the watchers of the
  failed slot also WARN each `warn_interval` and one CLAIM goes out: the peak.
- bytes/s on the air: frame + the radio's per-frame overhead. For the XBee protocols the
  overhead is what the firmware reserves of the 127-byte 802.15.4 PSDU for its headers
  (127 - max payload: 27 B for 802.15.4, 35 B Zigbee MAC/NWK/APS, 54 B DigiMesh) plus
  6 B of PHY preamble, start delimiter and length.
- airtime share at 250 kbps (the 2.4 GHz O-QPSK PHY): each transmission occupies
  (bytes x 32 us) plus the 640 us long inter-frame spacing the MAC must leave after it.
  CSMA back-off is idle time other senders can use and is not counted. 30% is the
  usual ceiling for unslotted CSMA before collisions grow fast.
- broadcast copies: an 802.15.4 broadcast is one transmission. Zigbee routers relay
  every broadcast with up to 3 transmissions each (passive acknowledgement), and the
  broadcast transaction table (8 entries, 8 s) limits a network to about one broadcast
  per second (docs/radios.md, Digi 90001539): 3 x robots transmissions, worst case.
  A DigiMesh broadcast goes out MT + 1 = 4 times (MT default 3); with every robot in
  one hop and NH=1 nobody relays it (more hops add relays: not counted here).
- per-robot mode (DESIGN section 2, "Who may say what"): a heartbeat carries its hash
  chain's next link (`core/chain.py`: 1 + 8 B, so 24 B below 128 functions, 32 B with a
  swarm key's tag beside), and some are anchors signed with the robot's own key (88 B):
  an active robot's at most one each `chain.anchor_every` (1 s at `udp()`, 5 s at
  `radio()`) plus `ANCHOR_RUN` per chain of `CHAIN_LEN` heartbeats, a standby's every
  one when its period is as long; WARN, CLAIM and LEAVE carry a 64-byte Ed25519
  signature instead of the tag (80, 80 and 79 B below 128 functions), and a claim goes
  out with its certificate: one CERT frame (92 B) per witness backing it, with every
  claim (re)sent.
- fragments: a frame larger than the medium's payload goes out in fragments
  (transport/fragment.py: 6 B of header each, at most 8), every fragment a transmission
  of its own with the radio's full per-frame overhead. On DigiMesh (73 B) a per-robot
  WARN, CLAIM or CERT takes 2 fragments; on a default serial radio (64 B) also 2. The
  airtime figures count every fragment; only a frame that cannot be split is a warning.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

from swarmd.core import chain
from swarmd.core.auth import SIGNATURE_LEN
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.wire import HEADER_LEN, TAG_LEN, slot_size
from swarmd.transport import fragment, media

AIR_RATE_BPS = 250_000
BYTE_TIME = 8 / AIR_RATE_BPS  # 32 us
IFS = 640e-6  # 802.15.4 long inter-frame spacing (40 symbols of 16 us)
PHY_OVERHEAD = 6  # preamble 4, SFD 1, PHR 1
PSDU_MAX = 127
AIRTIME_CEILING = 0.30
ZIGBEE_BROADCASTS_PER_S = 1.0

MAX_PAYLOAD = {**media.MAX_PAYLOAD, "serial": media.SERIAL_MAX_PAYLOAD,
               "udp": media.UDP_MAX_PAYLOAD}
"""Largest payload per medium (transport/media.py): XBee 3 broadcast limits
(unencrypted); the serial transport's default frame limit; a UDP datagram that fits a
1500-byte Ethernet MTU."""

HEARTBEAT_BODY = 3  # wire.py: epoch (2), role|health (1), plus the slot field
WARN_BODY = 5  # suspect (2), epoch (2), belief (1), plus the slot field; a CLAIM has no
# belief byte, and is counted as large as a WARN (one byte to spare)
MEDIA = tuple(MAX_PAYLOAD)


def frame_overhead(medium: str) -> int:
    """Bytes a frame costs on the air beyond its payload."""
    if medium in media.PROTOCOLS:
        return PHY_OVERHEAD + PSDU_MAX - MAX_PAYLOAD[medium]
    if medium == "serial":
        # COBS + CRC framing (transport/framing.py) carried by a transparent-mode radio,
        # costed like an 802.15.4 frame.
        return 7 + PHY_OVERHEAD + PSDU_MAX - MAX_PAYLOAD["802.15.4"]
    if medium == "udp":
        return 42  # Ethernet 14 + IPv4 20 + UDP 8
    raise ValueError(f"unknown medium {medium!r}; one of {', '.join(MEDIA)}")


def broadcast_copies(medium: str, robots: int) -> int:
    """Transmissions one broadcast costs network-wide (see module docstring)."""
    if medium == "zigbee":
        return 3 * robots
    if medium == "digimesh":
        return 4
    return 1


def airtime(medium: str, payload: int) -> float:
    """s. Channel time of one transmission of `payload` bytes (no relays)."""
    return (payload + frame_overhead(medium)) * BYTE_TIME + IFS


def _transmissions(medium: str, size: int) -> list[int]:
    """Datagram sizes a `size`-byte frame goes out as on `medium` (`fragment.sizes`);
    empty when it cannot be carried."""
    try:
        return fragment.sizes(size, MAX_PAYLOAD[medium])
    except fragment.FragmentError:
        return []


def fragments(medium: str, size: int) -> int:
    """Transmissions a `size`-byte frame takes on `medium` (1: unsplit; 0: it cannot be
    carried, more than `fragment.MAX_FRAGMENTS` would be needed)."""
    return len(_transmissions(medium, size))


def frame_airtime(medium: str, size: int) -> float:
    """s. Channel time of one `size`-byte frame, every fragment counted (no relays); a
    frame that cannot be carried costs nothing (it never goes out)."""
    return sum(airtime(medium, p) for p in _transmissions(medium, size))


@dataclass(frozen=True, slots=True)
class Budget:
    """The channel budget of one swarm on one medium (steady state and peak)."""

    medium: str
    signed: bool
    robots: int
    active: int
    standby: int
    frames_per_s: float
    """Frames the swarm originates per second in steady state (heartbeats)."""
    bytes_per_s: float
    """Bytes per second on the air in steady state, overhead and relays included."""
    airtime_share: float | None
    """Fraction of the 250 kbps channel used in steady state (None for UDP)."""
    peak_frames_per_s: float
    """Originated frames per second during a failover (heartbeats + WARNs + CLAIM and
    the CERTs that carry its certificate)."""
    peak_airtime_share: float | None
    heartbeat_bytes: int
    max_payload: int
    heartbeat_fits: bool
    warnings: tuple[str, ...]
    per_robot: bool = False
    """WARN, CLAIM and LEAVE signed with each robot's own key (otherwise tagged with the
    swarm key, or nothing)."""
    warn_bytes: int = 0
    """Bytes of a WARN (a CLAIM, one byte less, is counted as large)."""
    cert_bytes: int = 0
    """Bytes of one CERT frame (a claim's certificate, relayed: every mode)."""
    warn_fragments: int = 1
    """Transmissions a WARN or CLAIM takes (>1: split, fragment.py; 0: cannot be sent)."""
    cert_fragments: int = 0
    """Transmissions a CERT frame takes (0 if it cannot be sent)."""
    anchor_bytes: int = 0
    """Bytes of an anchor heartbeat (per-robot mode, `core/chain.py`; 0 otherwise)."""
    anchor_fragments: int = 0
    """Transmissions an anchor takes (per-robot mode; 0 otherwise or if it cannot)."""
    anchors_per_s: float = 0.0
    """Of `frames_per_s`, the anchors (per-robot mode)."""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def lines(self) -> list[str]:
        """Human-readable summary for `swarmd check`."""
        out = [
            f"channel budget on {self.medium} ({'signed' if self.signed else 'unsigned'} "
            f"frames, {self.active} active + {self.standby} standby robots):",
            f"  steady state: {self.frames_per_s:.1f} frames/s, "
            f"{self.bytes_per_s:.0f} B/s on the air"
            + (f", {self.airtime_share:.1%} airtime at 250 kbps"
               if self.airtime_share is not None else ""),
            f"  during a failover: {self.peak_frames_per_s:.1f} frames/s"
            + (f", {self.peak_airtime_share:.1%} airtime"
               if self.peak_airtime_share is not None else ""),
            f"  heartbeat {self.heartbeat_bytes} B, payload limit {self.max_payload} B: "
            + ("fits" if self.heartbeat_fits else "DOES NOT FIT"),
        ]
        if self.per_robot:
            out.append(f"  heartbeat chain: anchors {self.anchor_bytes} B"
                       + _in_fragments(self.anchor_fragments)
                       + f", {self.anchors_per_s:.2f}/s of the heartbeats")
            out.append(f"  per-robot signatures: warning/claim {self.warn_bytes} B"
                       + _in_fragments(self.warn_fragments)
                       + f", certificate frame {self.cert_bytes} B"
                       + _in_fragments(self.cert_fragments))
        elif self.warn_fragments > 1 or self.cert_fragments > 1:
            out.append(f"  warning/claim {self.warn_bytes} B"
                       + _in_fragments(self.warn_fragments)
                       + f", certificate frame {self.cert_bytes} B"
                       + _in_fragments(self.cert_fragments))
        out += [f"  WARNING: {w}" for w in self.warnings]
        return out


def _in_fragments(n: int) -> str:
    return f" ({n} fragments)" if n > 1 else ""


def heartbeat_size(signed: bool, slot_bytes: int = 1, *, per_robot: bool = False,
                   anchor: bool = False) -> int:
    """Bytes of a heartbeat; `slot_bytes` 1 below 128 functions, 2 or 3 above (wire.py).
    Per robot it carries its chain link; an anchor a signature in place of the tag."""
    link = 1 + chain.LINK_LEN if per_robot else 0
    auth = SIGNATURE_LEN if per_robot and anchor else TAG_LEN if signed else 0
    return HEADER_LEN + HEARTBEAT_BODY + slot_bytes + link + auth


def anchor_rates(active: int, standby: int, params: Params) -> float:
    """Anchors a second a per-robot swarm sends in steady state (`core/chain.py`)."""
    every = chain.anchor_every(params)
    per_active = 1 / max(every, params.heartbeat_interval) \
        + chain.ANCHOR_RUN / (chain.CHAIN_LEN * params.heartbeat_interval)
    per_standby = 1 / max(every, params.standby_heartbeat_interval)
    return active * per_active + standby * per_standby


def warn_size(signed: bool, slot_bytes: int = 1, *, per_robot: bool = False) -> int:
    """Bytes of a WARN (a CLAIM is one byte less: counted as a WARN); per-robot mode signs
    them with Ed25519."""
    auth = SIGNATURE_LEN if per_robot else TAG_LEN if signed else 0
    return HEADER_LEN + WARN_BODY + slot_bytes + auth


def cert_size(slot_bytes: int = 1, signed: bool = True, *, per_robot: bool = True) -> int:
    """Bytes of a CERT frame: a header, the slot, and the WARN it relays (signed per
    robot, tagged with a swarm key, or neither)."""
    return HEADER_LEN + slot_bytes + warn_size(signed, slot_bytes, per_robot=per_robot)


def budget_for(
    active: int,
    standby: int,
    max_watchers: int,
    params: Params,
    *,
    medium: str,
    signed: bool,
    slot_bytes: int = 1,
    per_robot: bool = False,
) -> Budget:
    """The budget from counts alone (what `channel_budget` derives from a plan);
    `slot_bytes` is the widest slot field the swarm sends (`wire.slot_size`)."""
    robots = active + standby
    overhead = frame_overhead(medium)
    copies = broadcast_copies(medium, robots)
    sizes = _frame_sizes(signed, slot_bytes, per_robot=per_robot)
    hb, anchor, warn, cert = sizes
    rates = _frame_rates(active, standby, max_watchers, params, per_robot=per_robot)
    link_rate = rates.heartbeats - rates.anchors
    peak_rate = rates.heartbeats + rates.warns + rates.claims * (1 + rates.backers)
    bytes_per_s = (link_rate * (hb + overhead) + rates.anchors * sum(
        n + overhead for n in _transmissions(medium, anchor))) * copies
    airtime_share, peak_share = _airtime_shares(medium, sizes, rates, copies)
    max_payload = MAX_PAYLOAD[medium]
    warnings = _size_warnings(medium, hb, warn, cert, anchor, per_robot=per_robot)
    warnings += _rate_warnings(medium, robots, rates.heartbeats, airtime_share, peak_share)
    return Budget(
        medium=medium, signed=signed, robots=robots, active=active, standby=standby,
        frames_per_s=rates.heartbeats, bytes_per_s=bytes_per_s, airtime_share=airtime_share,
        peak_frames_per_s=peak_rate, peak_airtime_share=peak_share, heartbeat_bytes=hb,
        max_payload=max_payload, heartbeat_fits=hb <= max_payload, warnings=tuple(warnings),
        per_robot=per_robot, warn_bytes=warn, cert_bytes=cert,
        warn_fragments=fragments(medium, warn),
        cert_fragments=fragments(medium, cert),
        anchor_bytes=anchor if per_robot else 0,
        anchor_fragments=fragments(medium, anchor) if per_robot else 0,
        anchors_per_s=rates.anchors,
    )


class _Sizes(NamedTuple):
    """Bytes of each frame a swarm sends (`budget_for`)."""

    heartbeat: int
    anchor: int
    warn: int
    cert: int


def _frame_sizes(signed: bool, slot_bytes: int, *, per_robot: bool) -> _Sizes:
    return _Sizes(
        heartbeat_size(signed, slot_bytes, per_robot=per_robot),
        heartbeat_size(signed, slot_bytes, per_robot=True, anchor=True),
        warn_size(signed, slot_bytes, per_robot=per_robot),
        cert_size(slot_bytes, signed, per_robot=per_robot),
    )


class _Rates(NamedTuple):
    """Frames per second swarm-wide, by kind (`budget_for`)."""

    heartbeats: float
    anchors: float
    """Of the heartbeats, those that are anchors (per-robot mode)."""
    warns: float
    claims: float
    backers: int
    """Frames that back a CLAIM, relayed with it in CERTs."""


def _frame_rates(active: int, standby: int, max_watchers: int, params: Params, *,
                 per_robot: bool) -> _Rates:
    backers = max_watchers + 1  # the witnesses and rule 9's own ears
    hb_rate = active / params.heartbeat_interval + standby / params.standby_heartbeat_interval
    anchor_rate = min(hb_rate, anchor_rates(active, standby, params)) if per_robot else 0.0
    warn_rate = max_watchers / params.warn_interval
    claim_rate = 1 / params.claim_hold  # at most one CLAIM per hold, counted as a rate
    return _Rates(hb_rate, anchor_rate, warn_rate, claim_rate, backers)


def _airtime_shares(medium: str, sizes: _Sizes, rates: _Rates,
                    copies: int) -> tuple[float | None, float | None]:
    """The share of the channel's time heartbeats take, and a failover at its peak
    (None for UDP, which has no airtime to share)."""
    if medium == "udp":
        return None, None
    link_rate = rates.heartbeats - rates.anchors
    beats = link_rate * airtime(medium, sizes.heartbeat) \
        + rates.anchors * frame_airtime(medium, sizes.anchor)
    peak_share = (
        beats
        + (rates.warns + rates.claims) * frame_airtime(medium, sizes.warn)
        + rates.claims * rates.backers * frame_airtime(medium, sizes.cert)
    ) * copies
    return beats * copies, peak_share


def _size_warnings(medium: str, hb: int, warn: int, cert: int, anchor: int, *,
                   per_robot: bool) -> list[str]:
    """A heartbeat over the medium's payload limit; a frame in more fragments than a
    message may have."""
    max_payload = MAX_PAYLOAD[medium]
    warnings: list[str] = []
    if hb > max_payload:
        warnings.append(f"a {hb} B heartbeat does not fit the {max_payload} B payload limit")
    warn_parts = fragments(medium, warn)
    cert_parts = fragments(medium, cert)
    if warn_parts == 0 or cert_parts == 0 or (per_robot and fragments(medium, anchor) == 0):
        warnings.append(
            f"a {max(warn, cert, anchor if per_robot else 0)} B frame needs more than "
            f"{fragment.MAX_FRAGMENTS} "
            f"fragments of the {max_payload} B payload limit: it cannot be sent")
    return warnings


def _rate_warnings(medium: str, robots: int, hb_rate: float, airtime_share: float | None,
                   peak_share: float | None) -> list[str]:
    """More broadcasts than Zigbee carries; more airtime than CSMA leaves usable."""
    warnings: list[str] = []
    if medium == "zigbee" and hb_rate > ZIGBEE_BROADCASTS_PER_S:
        needed = robots / ZIGBEE_BROADCASTS_PER_S
        warnings.append(
            f"Zigbee carries about {ZIGBEE_BROADCASTS_PER_S:.0f} broadcast per second "
            f"network-wide (8-entry broadcast table held 8 s, Digi 90001539); this swarm "
            f"broadcasts {hb_rate:.1f} heartbeats/s. Use 802.15.4 (single-hop MAC "
            f"broadcast) or DigiMesh, or slow every heartbeat to >= {needed:.0f} s"
        )
    if airtime_share is not None and airtime_share > AIRTIME_CEILING:
        warnings.append(
            f"heartbeats alone take {airtime_share:.0%} of the channel, above the "
            f"{AIRTIME_CEILING:.0%} CSMA ceiling: expect collisions and false suspicions"
        )
    elif peak_share is not None and peak_share > AIRTIME_CEILING:
        warnings.append(
            f"a failover raises airtime to {peak_share:.0%}, above {AIRTIME_CEILING:.0%}"
        )
    return warnings


def channel_budget(plan: SwarmPlan, params: Params, *, medium: str, signed: bool,
                   per_robot: bool = False) -> Budget:
    """Budget of `plan` on `medium` (zigbee, 802.15.4, digimesh, serial, udp)."""
    active = sum(1 for r in plan.robots.values() if r.function is not None)
    standby = len(plan.robots) - active
    max_watchers = max((len(plan.watched_by(f)) for f in plan.functions), default=0)
    return budget_for(active, standby, max_watchers, params, medium=medium, signed=signed,
                      slot_bytes=slot_size(len(plan.functions)), per_robot=per_robot)


def largest_swarm(
    params: Params,
    *,
    medium: str = "802.15.4",
    signed: bool = True,
    ceiling: float = AIRTIME_CEILING,
    standby_share: float = 1 / 3,
    limit: int = 10_000,
    per_robot: bool = False,
) -> int:
    """Largest robot count whose steady-state heartbeats stay below `ceiling` airtime.

    The swarm is shaped like the paper's (4 active, 2 standby: `standby_share` 1/3);
    each slot has two watchers (a ring, the paper's neighbourhood)."""
    best = 0
    for n in range(1, limit + 1):
        standby = round(n * standby_share)
        b = budget_for(n - standby, standby, 2, params, medium=medium, signed=signed,
                       per_robot=per_robot)
        if b.airtime_share is None or b.airtime_share >= ceiling:
            break
        best = n
    return best
