"""Channel budget, checked against hand-computed numbers."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.xbee_emu.swarm import paper_plan
from swarmd.budget import (
    airtime,
    budget_for,
    channel_budget,
    frame_overhead,
    heartbeat_size,
    largest_swarm,
    warn_size,
)
from swarmd.config import load_swarm
from swarmd.core.params import radio, udp

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
    assert heartbeat_size(True, 2) == 24 and warn_size(True, 3) == 11 + 4 + 3 + 8
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
