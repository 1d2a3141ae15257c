"""Timing parameters (swarmd.core.params): presets and the consistency rules."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from swarmd.core.params import PRESETS, Params, ParamsError, radio, udp


def test_udp_preset() -> None:
    p = udp()
    assert (p.heartbeat_interval, p.t_max, p.quorum) == (0.1, 0.5, 2)
    assert (p.warn_interval, p.vote_window, p.claim_hold) == (0.1, 1.0, 0.2)
    assert (p.standby_heartbeat_interval, p.standby_timeout) == (0.5, 2.0)
    assert (p.startup_grace, p.alert_after, p.rejoin_hold) == (2.0, 2.0, 0.7)


def test_radio_preset() -> None:
    p = radio()
    assert (p.heartbeat_interval, p.t_max, p.quorum) == (0.6, 2.0, 2)
    assert (p.warn_interval, p.vote_window, p.claim_hold) == (0.5, 4.0, 0.8)
    assert (p.standby_heartbeat_interval, p.standby_timeout) == (8.0, 24.0)
    assert (p.startup_grace, p.alert_after, p.rejoin_hold) == (10.0, 8.0, 3.0)


def test_presets_registry() -> None:
    assert PRESETS["udp"]() == udp()
    assert PRESETS["radio"]() == radio()


def test_t_max_under_two_heartbeats_raises_naming_t_max() -> None:
    with pytest.raises(ParamsError, match="t_max"):
        udp().with_overrides(t_max=0.19)
    udp().with_overrides(t_max=0.2)  # exactly two is allowed


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"vote_window": 0.15}, "vote_window"),
        ({"standby_timeout": 0.9}, "standby_timeout"),
        ({"quorum": 0}, "quorum"),
        ({"quorum": 1.5}, "quorum"),
        ({"claim_hold": 0.0}, "claim_hold"),
        ({"heartbeat_interval": -1.0}, "heartbeat_interval"),
    ],
)
def test_bad_values_raise_naming_the_field(overrides: dict[str, float], needle: str) -> None:
    with pytest.raises(ParamsError, match=needle):
        udp().with_overrides(**overrides)


def test_as_dict_round_trips() -> None:
    p = radio()
    fields: dict[str, Any] = dict(p.as_dict())
    assert Params(**fields) == p


@pytest.mark.parametrize(("preset", "horizon"), [(udp, 0.7), (radio, 2.8)])
def test_a_claim_is_believed_for_the_claim_hold_and_one_t_max(
        preset: Callable[[], Params], horizon: float) -> None:
    # DESIGN rule 10: long enough for the claimant's hold and its first heartbeat at the
    # new epoch to be missed only if it is dead; then the watchers warn again.
    p = preset()
    assert p.claim_horizon == pytest.approx(horizon)
    assert p.claim_horizon > p.claim_hold and p.claim_horizon > p.t_max
    assert "claim_horizon" not in p.as_dict()  # derived, never a swarm file's field


@pytest.mark.parametrize("preset", [udp, radio])
def test_one_takeover_bound_for_check_and_the_checker(preset: Callable[[], Params]) -> None:
    # `swarmd check` prints Params.takeover_bound; the invariant checker must hold runs
    # to the same figure, with and without loss.
    from sim.shared.invariants import Bounds

    p = preset()
    assert p.takeover_bound() == pytest.approx(p.t_max + p.vote_window + p.claim_hold)
    assert Bounds.of(p, 0.0).takeover == pytest.approx(p.takeover_bound())
    assert Bounds.of(p, 0.1).takeover == pytest.approx(p.takeover_bound(lossy=True))
    # DESIGN "Detection": on a lossy channel a link's patience may reach t_max_bursty,
    # and so may a clean one's after a link fault taught it a long silence.
    assert p.takeover_bound(lossy=True) == pytest.approx(
        p.t_max_bursty + 3 * p.vote_window + p.claim_hold)
    assert Bounds.of(p, 0.0).takeover_faded == pytest.approx(
        p.takeover_bound(patience=p.t_max_bursty))
    assert p.takeover_bound(patience=0.0) == p.takeover_bound()  # never below t_max
    assert p.takeover_bound(patience=1e9) == p.takeover_bound(patience=p.t_max_bursty)
