"""Channel budget, checked against hand-computed numbers."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.xbee_emu.swarm import paper_plan
from swarmd.config import load_swarm
from swarmd.core.params import radio, udp
from swarmd.services.budget import (
    airtime,
    budget_for,
    channel_budget,
    fragments,
    frame_airtime,
    frame_overhead,
    heartbeat_size,
    largest_swarm,
    warn_size,
)

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def test_paper_swarm_on_802154_by_hand() -> None:
    b = channel_budget(paper_plan(), radio(), medium="802.15.4", signed=True)
    # 4 active every 0.6 s + 2 standby every 8 s = 6.92 heartbeats/s of 23 B (+33 B
    # overhead).
    rate = 4 / 0.6 + 2 / 8
    assert (b.active, b.standby) == (4, 2)
    assert b.frames_per_s == pytest.approx(rate)
    assert b.bytes_per_s == pytest.approx(rate * (23 + 33))
    assert b.airtime_share == pytest.approx(rate * ((23 + 33) * 32e-6 + 640e-6))
    assert b.heartbeat_bytes == 23 and b.heartbeat_fits
    assert b.warnings == ()


def test_zigbee_broadcast_limit_is_warned() -> None:
    b = channel_budget(paper_plan(), radio(), medium="zigbee", signed=True)
    assert any("one broadcast per second" in w or "1 broadcast per second" in w
               for w in b.warnings)
    assert b.airtime_share is not None and b.airtime_share > 0.3  # relays, 3x each
    slow = radio().with_overrides(heartbeat_interval=10.0, standby_heartbeat_interval=10.0,
                                  t_max=20.0, standby_timeout=20.0)
    quiet = channel_budget(paper_plan(), slow, medium="zigbee", signed=False)
    assert not any("broadcast per second" in w for w in quiet.warnings)


def test_heartbeat_that_does_not_fit_is_flagged() -> None:
    assert heartbeat_size(True) == 23 and heartbeat_size(False) == 15
    assert frame_overhead("802.15.4") == 6 + 127 - 100
    b = budget_for(1, 0, 0, udp(), medium="udp", signed=True)
    assert b.airtime_share is None and b.heartbeat_fits


def test_airtime_ceiling_warning_and_largest_swarm() -> None:
    n = largest_swarm(radio(), medium="802.15.4", signed=True)
    assert n > 6
    standby = round((n + 1) / 3)
    over = budget_for(n + 1 - standby, standby, 2, radio(), medium="802.15.4", signed=True)
    assert over.airtime_share is not None and over.airtime_share >= 0.3
    assert any("CSMA ceiling" in w for w in over.warnings)
    assert largest_swarm(udp(), medium="802.15.4") < n  # 10 Hz heartbeats cost 5x
    assert airtime("digimesh", 10) > airtime("802.15.4", 10)


def test_a_hundred_robots_fit_one_802154_channel_at_radio() -> None:
    assert largest_swarm(radio(), medium="802.15.4", signed=True) >= 100
    cfg = load_swarm(CONFIGS / "grid100-radio.yaml")
    plan = cfg.to_plan()
    assert len(plan.robots) >= 100 and cfg.params() == radio()
    for signed in (True, False):
        b = channel_budget(plan, radio(), medium="802.15.4", signed=signed)
        assert b.airtime_share is not None and b.airtime_share < 0.3
        assert not b.warnings


def test_the_slot_field_widens_the_budget_past_127_functions() -> None:
    # A WARN: suspect, epoch and belief (DESIGN "Detection") besides the slot and tag.
    assert heartbeat_size(True, 2) == 24 and warn_size(True, 3) == 11 + 5 + 3 + 8
    small = budget_for(60, 20, 4, radio(), medium="802.15.4", signed=True)
    wide = budget_for(60, 20, 4, radio(), medium="802.15.4", signed=True, slot_bytes=2)
    assert wide.heartbeat_bytes == small.heartbeat_bytes + 1
    assert wide.airtime_share is not None and small.airtime_share is not None
    assert wide.airtime_share > small.airtime_share


def test_lines_are_human_readable() -> None:
    text = "\n".join(channel_budget(paper_plan(), radio(), medium="802.15.4",
                                    signed=True).lines())
    assert "6.9 frames/s" in text and "airtime at 250 kbps" in text and "fits" in text
    with pytest.raises(ValueError):
        frame_overhead("carrier-pigeon")


def test_per_robot_frames_on_digimesh_are_counted_in_fragments() -> None:
    # An 81 B signed WARN on DigiMesh (73 B): 2 fragments of 6 + 41 and 6 + 40 B; a 93 B
    # CERT: 2 of 6 + 47 and 6 + 46 B (transport/fragment.py). Each pays the full
    # per-frame overhead. (A WARN carries its belief byte, DESIGN "Detection".)
    assert fragments("digimesh", 81) == 2 and fragments("digimesh", 93) == 2
    assert fragments("802.15.4", 93) == 1 and fragments("serial", 93) == 2
    assert fragments("digimesh", 1000) == 0  # more than 8 fragments
    assert frame_airtime("digimesh", 81) == pytest.approx(
        airtime("digimesh", 47) + airtime("digimesh", 46))
    assert frame_airtime("digimesh", 93) == pytest.approx(
        airtime("digimesh", 53) + airtime("digimesh", 52))
    b = channel_budget(paper_plan(), radio(), medium="digimesh", signed=True,
                       per_robot=True)
    assert (b.warn_bytes, b.cert_bytes) == (81, 93)
    assert (b.warn_fragments, b.cert_fragments) == (2, 2)
    assert not any("payload limit" in w for w in b.warnings)
    # The peak by hand: heartbeats (links of 32 B, and anchors of 88 B in 2 fragments of
    # 6 + 44 B: each active robot's every 5 s and its chain's first 3 in 1024, each
    # standby's every one at 8 s), WARNs of 2 watchers and the CLAIM, and a CERT per
    # backer (2 watchers + the claimant's own ears), all sent MT + 1 = 4 times.
    p = radio()
    assert (b.anchor_bytes, b.anchor_fragments) == (88, 2)
    hb_rate = 4 / p.heartbeat_interval + 2 / p.standby_heartbeat_interval
    anchors = 4 * (1 / 5.0 + 3 / (1024 * p.heartbeat_interval)) + 2 / p.standby_heartbeat_interval
    assert b.anchors_per_s == pytest.approx(anchors)
    claim_rate = 1 / p.claim_hold
    peak = ((hb_rate - anchors) * airtime("digimesh", 32)
            + anchors * 2 * airtime("digimesh", 50)
            + (2 / p.warn_interval + claim_rate) * frame_airtime("digimesh", 81)
            + claim_rate * 3 * frame_airtime("digimesh", 93)) * 4
    assert b.peak_airtime_share == pytest.approx(peak)
    assert "warning/claim 81 B (2 fragments), certificate frame 93 B (2 fragments)" in (
        "\n".join(b.lines()))
    on_154 = channel_budget(paper_plan(), radio(), medium="802.15.4", signed=True,
                            per_robot=True)
    assert (on_154.warn_fragments, on_154.cert_fragments) == (1, 1)


def test_a_frame_that_cannot_be_split_is_warned(monkeypatch: pytest.MonkeyPatch) -> None:
    # No real medium refuses a swarmd frame (8 fragments of 64 - 6 B carry 464 B); a
    # 15 B payload (9 B per fragment) would need 9 fragments for an 81 B WARN.
    from swarmd.services import budget

    monkeypatch.setitem(budget.MAX_PAYLOAD, "serial", 15)
    b = budget_for(4, 2, 2, radio(), medium="serial", signed=True, per_robot=True)
    assert b.warn_fragments == 0 and b.cert_fragments == 0
    assert any("93 B frame needs more than 8 fragments" in w for w in b.warnings)
