"""Per-slot watchdog (paper Fig. 7; DESIGN rules 5 and 8), table-driven."""

from __future__ import annotations

import pytest

from swarmd.core.params import udp
from swarmd.core.watchdog import Fired, SlotWatch, WatchState

P = udp()  # t_max 0.5, warn 0.1, startup_grace 2.0, claim_hold 0.2, alert_after 2.0


def state(w: SlotWatch) -> WatchState:
    """Read the state through a call, so mypy does not narrow it across mutations."""
    return w.state


def test_waiting_fires_after_startup_grace() -> None:
    w = SlotWatch("f2", P, now=10.0)
    assert state(w) is WatchState.WAITING
    assert w.deadline == pytest.approx(10.0 + P.startup_grace)
    assert w.fire(w.deadline) == Fired(first=True, alert=False)
    assert state(w) is WatchState.SUSPECT
    assert w.deadline == pytest.approx(10.0 + P.startup_grace + P.warn_interval)


def test_recently_heard_starts_running() -> None:
    w = SlotWatch("f2", P, now=10.0, last_heard=9.8)
    assert state(w) is WatchState.RUNNING
    assert w.deadline == pytest.approx(9.8 + P.t_max)
    # Heard, but silent for T_max already: suspected at once (Fig. 7), not after the
    # start-up grace, which is for slots never heard.
    stale = SlotWatch("f2", P, now=10.0, last_heard=9.0)
    assert stale.state is WatchState.RUNNING and stale.deadline == pytest.approx(10.0)
    assert SlotWatch("f2", P, now=10.0).deadline == pytest.approx(10.0 + P.startup_grace)


def test_running_fires_t_max_after_last_heartbeat() -> None:
    w = SlotWatch("f2", P, now=0.0)
    assert w.heard(1.0) is False  # not a refutation: nothing was suspected
    assert state(w) is WatchState.RUNNING
    assert w.deadline == pytest.approx(1.0 + P.t_max)
    assert w.heard(1.3) is False
    assert w.deadline == pytest.approx(1.3 + P.t_max)
    assert w.fire(1.8).first
    assert w.suspecting


def test_heard_ends_suspicion_and_reports_refutation() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0)
    w.fire(0.5)
    assert w.heard(0.55) is True
    assert state(w) is WatchState.RUNNING and not w.suspecting
    assert w.since is None
    assert w.fire(1.05).first  # a new episode starts fresh


def test_repeated_fire_warns_every_warn_interval_not_first() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0)
    assert w.fire(0.5).first
    assert not w.fire(0.6).first
    assert w.deadline == pytest.approx(0.7)


def test_claim_heard_hands_over_then_suspects_again() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0)
    w.fire(0.5)
    w.claim_heard(0.6)
    assert state(w) is WatchState.HANDOVER and w.suspecting
    assert w.deadline == pytest.approx(0.6 + P.claim_horizon)  # DESIGN rule 10
    fired = w.fire(w.deadline)
    assert state(w) is WatchState.SUSPECT
    assert fired.first  # a handover that brought nobody is logged as a new suspicion
    assert w.since == pytest.approx(0.5)


def test_alert_once_after_alert_after() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0)
    t = 0.5
    alerts = []
    while t < 0.5 + 2 * P.alert_after:
        alerts.append((t, w.fire(t).alert))
        t = w.deadline
    raised = [at for at, alert in alerts if alert]
    assert len(raised) == 1
    assert raised[0] >= 0.5 + P.alert_after - 1e-9
    assert raised[0] < 0.5 + P.alert_after + P.warn_interval + 1e-9
    # after the alert, warnings slow to the standby heartbeat period
    last = w.deadline
    w.fire(last)
    assert w.deadline == pytest.approx(last + P.standby_heartbeat_interval)


def test_mark_alerted_suppresses_the_timed_alert() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.fire(w.deadline)
    w.mark_alerted()
    t = w.deadline
    for _ in range(50):
        assert not w.fire(t).alert
        t = w.deadline


@pytest.mark.parametrize(
    ("setup", "stall_at", "expect_state", "expect_deadline"),
    [
        # RUNNING: our own stall restarts the timer from now.
        ("running", 5.0, WatchState.RUNNING, 5.0 + P.t_max),
        # WAITING: at least t_max from now, never earlier than the grace deadline.
        ("waiting", 1.0, WatchState.WAITING, 0.0 + P.startup_grace),
        ("waiting", 4.0, WatchState.WAITING, 4.0 + P.t_max),
        # SUSPECT: a refresh does not end a suspicion.
        ("suspect", 5.0, WatchState.SUSPECT, 0.6),
    ],
)
def test_refresh_after_a_stall(setup: str, stall_at: float, expect_state: WatchState,
                               expect_deadline: float) -> None:
    w = SlotWatch("f2", P, now=0.0)
    if setup == "running":
        w.heard(0.1)
    elif setup == "suspect":
        w.heard(0.0)
        w.fire(0.5)
    w.refresh(stall_at)
    assert state(w) is expect_state
    assert w.deadline == pytest.approx(expect_deadline)


# ---------------------------------------------------------------------- beliefs
# DESIGN "Detection": a link whose belief gives it more patience than T_max is doubted
# from T_max on (warnings the holder answers, no standby counts) and suspected only when
# the patience runs out.
def test_a_patient_link_is_doubted_from_t_max_and_suspected_at_its_patience() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(1.0, patience=1.5)
    assert w.deadline == pytest.approx(1.0 + P.t_max)  # Fig. 7's T_max: the first doubt
    t, doubts = w.deadline, 0
    while (fired := w.fire(t)).doubt:
        assert state(w) is WatchState.DOUBT and not w.suspecting and not fired.first
        doubts += 1
        t = w.deadline
    assert t == pytest.approx(2.5) and fired.first and state(w) is WatchState.SUSPECT
    assert doubts == 10  # one every warn_interval from 1.5 to 2.4
    assert w.since == pytest.approx(2.5)  # the episode (and rule 8's alert) starts here


def test_a_doubt_heard_away_is_no_refutation() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0, patience=1.0)
    assert w.fire(0.5).doubt
    assert w.heard(0.6, patience=1.0) is False  # nothing was suspected: nothing to refute
    assert state(w) is WatchState.RUNNING and w.since is None


def test_a_stall_in_doubt_starts_again_from_t_max() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0, patience=1.0)
    w.fire(0.5)
    w.refresh(5.0)  # our own stall: the silence was ours
    assert state(w) is WatchState.RUNNING and w.deadline == pytest.approx(5.0 + P.t_max)


def test_a_clean_link_is_never_doubted() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0, patience=P.t_max)
    fired = w.fire(0.5)
    assert not fired.doubt and fired.first and state(w) is WatchState.SUSPECT


def test_a_claim_heard_in_doubt_hands_over() -> None:
    w = SlotWatch("f2", P, now=0.0)
    w.heard(0.0, patience=1.5)
    w.fire(0.5)
    w.claim_heard(0.6)  # another watcher's quorum was met first
    assert state(w) is WatchState.HANDOVER
    assert w.fire(w.deadline).first  # a claimant never heard: suspected, and logged
