"""Detection by beliefs on virtual time, in every auth mode (DESIGN "Detection"): a
watcher that measured a link fading in bursts doubts before it suspects, its warnings
carry how strongly it suspects, and a standby counts only suspicions; a crash is still
taken over, within the bound for the measured link."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from harness import MODE_KEY as KEY
from harness import Net, Radio

from sim.shared.fakeid import fake_identities
from swarmd.core import events as ev
from swarmd.core import wire
from swarmd.core.actions import Action, Broadcast
from swarmd.core.belief import level_byte
from swarmd.core.node import Node
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

MODES = ["none", "shared", "per-robot"]


def run(node: Node, until: float, now: float) -> list[Action]:
    """Fire the node's deadlines from `now` up to `until`."""
    out: list[Action] = []
    while (d := node.next_deadline()) is not None and d <= until:
        out += node.tick(max(d, now))
    return out


def warns_about(radio: Radio, actions: list[Action], suspect: int) -> list[wire.Warn]:
    """The warnings about `suspect` among a node's actions, decoded as the swarm would."""
    verifier = radio.ids[min(radio.ids)].verifier if radio.ids else None
    msgs = (wire.decode(a.frame, radio.keys, verifier).msg for a in actions
            if isinstance(a, Broadcast))
    return [m for m in msgs if isinstance(m, wire.Warn) and m.suspect == suspect]


def fading(period: float, quiet: float, until: float, h: float) -> Iterator[tuple[float, bool]]:
    """Heartbeat times, and whether robot 2's gets through: it fades for `quiet` s at
    the end of every `period`."""
    t = 0.0
    while t < until:
        yield t, (t % period) < period - quiet
        t = round(t + h, 6)


@pytest.mark.parametrize("mode", MODES)
def test_a_link_that_fades_in_bursts_is_doubted_not_suspected(
        paper_plan: SwarmPlan, udp_params: Params, mode: str) -> None:
    radio = Radio(paper_plan, udp_params, mode)
    node = radio.node(1)  # robot 1 watches f2 (robot 2) and f4 (robot 4)
    late: list[Action] = []
    last = 0.0
    for t, through in fading(3.0, 1.0, 90.0, udp_params.heartbeat_interval):
        out = run(node, t, t) + node.receive(radio.beat(4, "f4"), t)
        if through:
            out += node.receive(radio.beat(2, "f2"), t)
            last = t
        if t >= 60.0:
            late += out
    # After a minute of fades the silences of 1 s are no news: doubts, no suspicion.
    assert not [e for e in late if isinstance(e, ev.Suspect)]
    doubts = warns_about(radio, late, 2)
    assert doubts and all(w.belief < level_byte(udp_params.suspect_level) for w in doubts)
    patience = node._ears.patience(2)
    assert 1.0 < patience <= udp_params.t_max_bursty
    # Robot 2 crashes: suspected a patience after the last heartbeat, and that warning
    # says so strongly.
    out, t = [], 90.0
    while t < last + patience + 0.05:
        out += run(node, t, t) + node.receive(radio.beat(4, "f4"), t)
        t = round(t + udp_params.heartbeat_interval, 6)
    suspects = [e for e in out if isinstance(e, ev.Suspect)]
    assert [e.fields()["subject"] for e in suspects] == [2]
    assert [w.belief >= level_byte(udp_params.suspect_level)
            for w in warns_about(radio, out, 2)][-1]


@pytest.mark.parametrize("mode", MODES)
def test_a_standby_counts_suspicions_not_doubts(paper_plan: SwarmPlan,
                                                udp_params: Params, mode: str) -> None:
    radio = Radio(paper_plan, udp_params, mode)
    six = radio.node(6)  # covers f2; its witnesses are f1's and f3's holders (rule 3)
    level = level_byte(udp_params.suspect_level)
    for rid, f in ((1, "f1"), (3, "f3")):  # both witnesses alive: rule 9 stays out
        six.receive(radio.beat(rid, f), 2.95)
    out = six.receive(radio.warn(1, 2, "f2", level - 1), 3.0)
    out += six.receive(radio.warn(3, 2, "f2", level - 1), 3.01)
    assert not [a for a in out if isinstance(a, (ev.Vote, ev.Claim))]
    assert six.snapshot().votes == {}
    out = six.receive(radio.warn(1, 2, "f2", level), 3.02)
    out += six.receive(radio.warn(3, 2, "f2", 255), 3.03)
    assert [a.fields()["from"] for a in out if isinstance(a, ev.Vote)] == [1, 3]
    assert [a for a in out if isinstance(a, ev.Claim)]


def stopped_warning(radio: Radio, six: Node, *, heard: bool, cadence: float) -> list[Action]:
    """Standby 6 (covers f2) hears witness 1 warn about robot 2 three times at `cadence`,
    then, if `heard`, robot 1's own heartbeats and no warning (it heard robot 2 again);
    witness 3 warns 0.6 s after 1's last warning, within the vote window."""
    level = level_byte(radio.params.suspect_level)
    out: list[Action] = []
    t = 3.0
    for _ in range(3):
        out += run(six, t, t) + six.receive(radio.warn(1, 2, "f2", level), t)
        last, t = t, round(t + cadence, 6)
    for dt in (0.15, 0.25, 0.35, 0.45, 0.55):
        t = round(last + dt, 6)
        out += run(six, t, t) + six.receive(radio.beat(3, "f3"), t)
        if heard:
            out += six.receive(radio.beat(1, "f1"), t)
    t = round(last + 0.6, 6)
    return out + run(six, t, t) + six.receive(radio.warn(3, 2, "f2", level), t)


@pytest.mark.parametrize("mode", MODES)
def test_a_witness_that_stopped_warning_is_no_vote(paper_plan: SwarmPlan,
                                                   udp_params: Params, mode: str) -> None:
    """A live robot faded to witness 1, then to witness 3, and to the standby all along:
    1's vote must not meet 3's suspicion once 1 heard the robot again (DESIGN
    "Detection", the standby's votes stand for witnesses silent now)."""
    radio = Radio(paper_plan, udp_params, mode)
    six = radio.node(6)
    for rid, f in ((1, "f1"), (3, "f3")):  # both witnesses alive: rule 9 stays out
        six.receive(radio.beat(rid, f), 2.95)
    out = stopped_warning(radio, six, heard=True, cadence=udp_params.warn_interval)
    assert not [a for a in out if isinstance(a, ev.Claim)]
    assert six.snapshot().votes == {"f2": 1}


@pytest.mark.parametrize(("heard", "cadence"), [(False, 0.1), (True, 0.5)],
                         ids=["warnings lost", "an alerted witness, slower"])
@pytest.mark.parametrize("mode", MODES)
def test_a_witness_still_warning_keeps_its_vote(paper_plan: SwarmPlan, udp_params: Params,
                                                mode: str, heard: bool,
                                                cadence: float) -> None:
    """Its warnings lost (and its heartbeats too), or sent slower after its alert (rule
    8): the vote stays its window and the quorum meets."""
    radio = Radio(paper_plan, udp_params, mode)
    six = radio.node(6)
    for rid, f in ((1, "f1"), (3, "f3")):
        six.receive(radio.beat(rid, f), 2.95)
    out = stopped_warning(radio, six, heard=heard, cadence=cadence)
    assert [a for a in out if isinstance(a, ev.Claim)]


@pytest.mark.parametrize("mode", MODES)
def test_the_suspect_answers_a_doubt(paper_plan: SwarmPlan, udp_params: Params,
                                     mode: str) -> None:
    radio = Radio(paper_plan, udp_params, mode)
    two = radio.node(2)
    out = two.receive(radio.warn(1, 2, "f2", 3), 1.0)  # rule 4: ask, and it answers
    assert any(isinstance(a, Broadcast) and a.frame[0] & 0x07 == wire.MsgType.HEARTBEAT
               for a in out)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("cap", [1.0, 4.0], ids=["fig7 as is", "beliefs"])
def test_a_swarm_learns_a_fading_robot_and_still_replaces_it_when_it_dies(
        paper_plan: SwarmPlan, udp_params: Params, mode: str, cap: float) -> None:
    # Robot 2's radio fades, to every robot at once: for 0.4 s every 1.5 s, then for
    # 0.8 s every 3 s. Fig. 7 as is (patience_cap 1: T_max always) takes it over at the
    # first long fade; with beliefs the swarm has learnt the fades from the short ones
    # and leaves it alone, and its crash is still taken over within the bound for the
    # link as measured.
    params = udp_params.with_overrides(patience_cap=cap)
    Cut = tuple[int | None, int | None, float, float]
    short: list[Cut] = [(2, None, t - 0.4, t) for t in (1.5 * k for k in range(1, 21))]
    long: list[Cut] = [(2, None, t - 0.8, float(t)) for t in range(33, 73, 3)]
    ids = fake_identities(paper_plan.robots) if mode == "per-robot" else {}
    net = Net(paper_plan, params, keys=(KEY,) if mode != "none" else (), identities=ids,
              cuts=short + long)
    net.run_until(34.0 if cap == 1.0 else 73.0)
    false = [e for e in net.named("takeover") if e["replaced"] == 2]
    if cap == 1.0:
        assert false and 30.0 < false[0]["t"] < 34.0
        return
    assert false == [] and net.named("suspect") == []
    net.crash(2)
    net.run_until(73.0 + params.takeover_bound(patience=params.t_max_bursty))
    assert [e for e in net.named("takeover") if e["function"] == "f2"]
