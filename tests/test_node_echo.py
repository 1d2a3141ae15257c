"""A robot's own frames back from the channel (multicast loopback): dropped as `own`
without a second check of their tag or signature when they are byte for byte what it
sent with the keys in force, and checked like any frame otherwise, in every auth mode
(swarmd.core.node, `Node.receive`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from sim.shared.fakeid import fake_identities
from swarmd.core import wire
from swarmd.core.actions import Broadcast
from swarmd.core.node import ECHO_MEMORY, Node
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan
from swarmd.core.wire import KEY_LEN

MODES = ("per-robot", "shared", "none")
OLD_KEY, NEW_KEY = b"\x01" * KEY_LEN, b"\x02" * KEY_LEN


def make(plan: SwarmPlan, params: Params, mode: str) -> Node:
    identity = fake_identities(plan.robots)[1] if mode == "per-robot" else None
    keys = (OLD_KEY,) if mode == "shared" else ()
    return Node(1, plan, params, 0.0, keys=keys, identity=identity)


def decodes(monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    """The frames `wire.decode` is asked to check from now on."""
    seen: list[bytes] = []
    real: Callable[..., wire.Frame] = wire.decode

    def counting(data: bytes, *args: Any, **kwargs: Any) -> wire.Frame:
        seen.append(data)
        return real(data, *args, **kwargs)

    monkeypatch.setattr(wire, "decode", counting)
    return seen


def own_frames(node: Node, until: float) -> list[bytes]:
    """What `node` sends on its deadlines up to `until` (its heartbeats, first an
    anchor in per-robot mode)."""
    out: list[bytes] = []
    while (d := node.next_deadline()) is not None and d <= until:
        out += [a.frame for a in node.tick(d) if isinstance(a, Broadcast)]
    return out


@pytest.mark.parametrize("mode", MODES)
def test_an_echo_is_own_without_a_second_check(
        paper_plan: SwarmPlan, udp_params: Params, mode: str,
        monkeypatch: pytest.MonkeyPatch) -> None:
    node = make(paper_plan, udp_params, mode)
    frames = own_frames(node, 1.0)
    assert len(frames) >= 5
    checked = decodes(monkeypatch)
    for i, data in enumerate(frames):
        assert node.receive(data, 1.0 + 0.001 * i) == []
    assert checked == []
    assert node.snapshot().drops == {"own": len(frames)}


@pytest.mark.parametrize("mode", MODES)
def test_a_frame_in_our_name_we_did_not_send_is_checked(
        paper_plan: SwarmPlan, udp_params: Params, mode: str,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """One byte off what we sent (another seq, a forger's tag): decoded as any frame,
    so a forgery is `auth` (a valid one stays `own`: the runtime then tells a second
    daemon with our id by frames it did not send)."""
    node = make(paper_plan, udp_params, mode)
    data = own_frames(node, 0.0)[0]
    forged = data[:-1] + bytes((data[-1] ^ 1,))
    checked = decodes(monkeypatch)
    node.receive(forged, 0.01)
    assert checked == [forged]
    unsigned = mode == "none"
    assert node.snapshot().drops == {"own" if unsigned else "auth": 1}


def test_an_echo_tagged_with_a_key_no_longer_listed_is_auth(
        paper_plan: SwarmPlan, udp_params: Params) -> None:
    node = make(paper_plan, udp_params, "shared")
    old = own_frames(node, 0.0)
    node.set_keys([NEW_KEY, OLD_KEY])  # the rotation window: both accepted
    node.receive(old[0], 0.01)
    assert node.snapshot().drops == {"own": 1}
    node.set_keys([NEW_KEY])
    new = own_frames(node, 0.2)
    for i, data in enumerate((*old, *new)):
        node.receive(data, 0.3 + 0.001 * i)
    assert node.snapshot().drops == {"own": 1 + len(new), "auth": len(old)}


def test_a_new_keyring_checks_the_echoes_again(
        paper_plan: SwarmPlan, udp_params: Params, monkeypatch: pytest.MonkeyPatch) -> None:
    """SIGHUP in per-robot mode replaces the keyring and then calls `revoke`: our own
    key may be another now, so what we sent before is checked like any frame."""
    node = make(paper_plan, udp_params, "per-robot")
    frames = own_frames(node, 0.2)
    node.revoke([])
    checked = decodes(monkeypatch)
    for i, data in enumerate(frames):
        node.receive(data, 0.3 + 0.001 * i)
    assert checked == frames
    assert node.snapshot().drops == {"own": len(frames)}


def test_the_echo_memory_is_bounded(paper_plan: SwarmPlan, udp_params: Params,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    node = make(paper_plan, udp_params, "none")
    frames = own_frames(node, (ECHO_MEMORY + 9) * udp_params.heartbeat_interval)
    assert len(frames) > ECHO_MEMORY
    checked = decodes(monkeypatch)
    now = node.next_deadline()
    assert now is not None
    for data in frames:
        node.receive(data, now)
    assert checked == frames[:len(frames) - ECHO_MEMORY]


@pytest.mark.parametrize("mode", MODES)
def test_a_drop_keeps_the_deadline_armed_before(
        paper_plan: SwarmPlan, udp_params: Params, mode: str) -> None:
    """A refused frame moves nothing, so `receive` hands back the deadline worked out
    at the end of the previous call without working it out again; after our own stall
    (`_advance` re-plans everything) a refused frame is the call that arms the new one.
    Checked against the deadline worked out anew after every frame."""
    node = make(paper_plan, udp_params, mode)
    frames = own_frames(node, 1.0)
    garbage = [b"", b"\x11" * 30, frames[0][:-1] + bytes((frames[0][-1] ^ 1,))]
    at = 1.0
    for i, data in enumerate([*frames, *garbage] * 3):
        # Every 7th frame comes after a stall (more than t_max / 2 past the deadline).
        armed = node.next_deadline()
        assert armed is not None
        at = armed + udp_params.t_max if i % 7 == 3 else at + 0.001
        node.receive(data, at)
        assert node.next_deadline() == node._deadline()
        assert node._armed == node._deadline()  # what `_advance` reads
