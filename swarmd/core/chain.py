"""A robot's heartbeats only from that robot, per-robot mode: hash chains with signed
anchors (DESIGN section 2, "Who may say what", "Heartbeats").

A heartbeat must stay small (it is almost all of the airtime) and cheap to check (a
robot hears ten of them a second from each neighbour), so it cannot carry a 64-byte
signature every time. Each robot draws a chain of `CHAIN_LEN` secret links, each the
hash of the next (`step`), and reveals them one per heartbeat, last-made first: a
receiver that holds link `x` accepts a heartbeat carrying `y` only if hashing `y` a few
times (`(n_y - n_x) mod 256`, at most `WALK` and what the time since `x` allows)
gives `x`. Nobody but the robot knows the
next link until it sends it, so a dead robot's heartbeats cannot be forged from what
was heard: a forger can only repeat a link already revealed, which is refused. Where
a chain starts — a receiver that just started, one that lost more than `WALK` links,
a new chain — the robot's Ed25519 signature over the whole heartbeat (an *anchor*)
says which link is current. A robot sends an anchor as the first `ANCHOR_RUN`
heartbeats of each chain, after each change of what it heartbeats (slot, epoch, role)
and when it hears a peer again after `resync_after(params)` of silence (a healed
partition), as every extra heartbeat (a refutation, an answer to a stale view: whoever
it answers may have lost the chain), and at least every `anchor_every(params)`.

A link binds liveness, not content: an outsider that hears a fresh link first can
repeat it with other fields to a receiver that has not heard it yet (a race in radio
range, once per link). What a heartbeat says is believed only as far as DESIGN allows
an unsigned heartbeat anyway (never a new epoch or holder without a certificate); the
swarm key's tag, when there is one, binds the content too.

Pure and stdlib-only: the chain's seed is the robot's own signature over its run
(deterministic, unpredictable without its key), so a simulation is reproducible.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Iterable

from swarmd.core.auth import Signer
from swarmd.core.params import Params

LINK_LEN = 8
"""bytes. A 64-bit link: finding a preimage before the next heartbeat is out of reach,
and it costs a heartbeat one byte more than the swarm key's tag."""
CHAIN_LEN = 1024
"""Links per chain: 102 s at 10 Hz, 10 min at `radio()`; drawn in about half a
millisecond, so a simulator with many robots pays little for each."""
WALK = 255
"""The most links a receiver hashes to catch up (the link number is one byte): 25 s of
lost heartbeats at `udp()`, 2.5 min at `radio()`; more, and it waits for an anchor. A
receiver also walks no further than its sender can have sent since the last link
accepted (`PeerChains`), so a forged link of a robot heard lately costs a few hashes."""
SLACK = 8
"""Links allowed beyond what the sender's heartbeat period explains (extra heartbeats:
refutations, answers; at most four a period, `heartbeat.py`)."""
ANCHOR_RUN = 3
"""Anchors in a row where a chain starts, so one lost frame leaves nobody unanchored."""
HEADS = 3
"""Chains a receiver follows per peer (`PeerChains`): the one its links are on, its
next one (a new chain, a new run) and one more, so an anchor of another chain in its
name (a second radio with its key) leaves the chain it links on followed."""
_WRAP = 256
"""The link number on the wire is one byte, counted modulo 256."""
_SEED_DOMAIN = b"swarmd heartbeat chain v1"


def _back(robot: int, link: bytes, steps: int) -> bytes:
    """`link` hashed `steps` times: the link that many before it in its chain."""
    for _ in range(steps):
        link = step(robot, link)
    return link


def step(robot: int, link: bytes) -> bytes:
    """The link before `link` in `robot`'s chain (its hash, personalised per robot so a
    table built for one robot's chains is no use on another's)."""
    h = _hasher(robot).copy()
    h.update(link)
    return h.digest()


def _hasher(robot: int) -> hashlib.blake2b:
    """`robot`'s personalised BLAKE2b, empty, built once: copying it is about a third
    cheaper than building one with its parameters for every link (`step` runs for every
    link heard, and a chain is `CHAIN_LEN` of them)."""
    base = _PERSON.get(robot)
    if base is None:  # robot ids are 16 bits: the table stays small
        person = b"swarmd-hb" + robot.to_bytes(2, "big")
        base = _PERSON[robot] = hashlib.blake2b(digest_size=LINK_LEN, person=person)
    return base


_PERSON: dict[int, hashlib.blake2b] = {}
"""robot -> its personalised BLAKE2b, not fed yet (`_hasher`)."""


def resync_after(params: Params) -> float:
    """Seconds of silence after which a peer may have lost our chain (half of `WALK`
    heartbeat periods): hearing it again, we anchor (`OwnChain.reanchor`)."""
    return WALK * params.heartbeat_interval / 2


def anchor_every(params: Params) -> float:
    """Seconds between two scheduled anchors at most: a receiver that starts (its
    watchdogs wait `startup_grace`) or lost a standby's chain (it waits
    `standby_timeout`) is anchored again well before it would suspect anyone."""
    return min(params.startup_grace, params.standby_timeout) / 2


class OwnChain:
    """This robot's links, revealed one per heartbeat (`next`)."""

    __slots__ = ("_anchor_due", "_count", "_last_anchor", "_links", "_n", "_reanchored",
                 "_robot", "_run", "_signer", "_what")

    def __init__(self, robot: int, signer: Signer, run: int) -> None:
        self._robot, self._signer, self._run = robot, signer, run
        self._links: list[bytes] = []
        self._count = 0  # chains drawn
        self._n = 0
        self._anchor_due = 0
        self._last_anchor = float("-inf")
        self._what: tuple[int, int, int] | None = None
        self._reanchored = float("-inf")

    def next(self, now: float, what: tuple[int, int, int], every: float, *,
             extra: bool = False) -> tuple[int, bytes, bool]:
        """(link number, link, anchor?) for the heartbeat sent at `now` saying `what`
        (slot, epoch, role)."""
        if not self._links:
            self._draw()
        if what != self._what:
            self._what = what
            self._anchor_due = ANCHOR_RUN
        self._n = (self._n + 1) % _WRAP
        link = self._links.pop()
        anchor = extra or self._anchor_due > 0 or now - self._last_anchor >= every
        if anchor:
            self._anchor_due = max(0, self._anchor_due - 1)
            self._last_anchor = now
        return self._n, link, anchor

    def anchor_next(self) -> None:
        """Our next heartbeat is an anchor: one we answer with could not go out as an
        extra one (`heartbeat.py`'s limit), and whoever we answer may have lost our
        chain. The caller bounds how often (`Hearing._digest_heard`)."""
        self._anchor_due = max(self._anchor_due, 1)

    def reanchor(self, now: float, every: float) -> None:
        """A peer is back after a silence long enough to have lost our chain (a
        partition that healed cut it off from us too): our next `ANCHOR_RUN` heartbeats
        are anchors, at most once every `every` seconds (a forged frame in a dead
        robot's name must not make us sign at will)."""
        if now - self._reanchored >= every:
            self._reanchored = now
            self._anchor_due = ANCHOR_RUN

    def _draw(self) -> None:
        self._count += 1
        stamp = self._run.to_bytes(6, "big") + self._count.to_bytes(4, "big")
        seed = hashlib.blake2b(
            self._signer.sign(_SEED_DOMAIN + self._robot.to_bytes(2, "big") + stamp),
            digest_size=LINK_LEN).digest()
        base = _hasher(self._robot)
        links = [seed]
        for _ in range(CHAIN_LEN - 1):
            h = base.copy()  # `step`, inlined: drawing is most of a short run's hashing
            h.update(links[-1])
            links.append(h.digest())
        self._links = links  # popped from the end: the last one made goes out first
        self._anchor_due = ANCHOR_RUN


class _Head:
    """Where one chain of a peer stands: the last link accepted, its number, and when."""

    __slots__ = ("link", "n", "when")

    def __init__(self, n: int, link: bytes, when: float) -> None:
        self.n, self.link, self.when = n, link, when


class PeerChains:
    """Where each peer's chains stand, as this robot verified them. `check` is pure (a
    frame the replay filter then refuses moves nothing); `commit` records an accepted
    heartbeat. `rate`: the most heartbeats a second a robot sends on schedule (the
    active period's), which bounds how far a link may be ahead.

    Up to `HEADS` chains per peer, each of which only moves forward. An anchor moves the
    chain it continues; one that continues none (the robot's next chain, its new run, or
    an anchor another radio signs with its key) is another head beside the ones its
    links still follow, so no anchor in a robot's name takes its own chain from the
    receivers (DESIGN "Heartbeats, per robot")."""

    __slots__ = ("_at", "_hit", "_rate")

    def __init__(self, rate: float) -> None:
        self._rate = 2 * rate  # margin: a late sender catching up, clocks that differ
        self._at: dict[int, list[_Head]] = {}
        """robot -> its chains' heads, the one a link or anchor moved last first."""
        self._hit: tuple[int, int, bytes, _Head] | None = None
        """The head `check` tied the last link to, so `commit` hashes nothing again."""

    def _reach(self, head: _Head, n: int, now: float) -> int:
        """How many links `n` is ahead of `head`, 0 where a link there cannot be its
        chain's next: revealed already, or further than `WALK` and the time since allow."""
        gap = (n - head.n) % _WRAP
        return gap if 0 < gap <= min(WALK, SLACK + int((now - head.when) * self._rate)) \
            else 0

    def _continues(self, robot: int, head: _Head, n: int, link: bytes, now: float) -> bool:
        """Is link `n` of `robot`'s the next one of `head`'s chain?"""
        gap = self._reach(head, n, now)
        return bool(gap) and hmac.compare_digest(_back(robot, link, gap), head.link)

    def _open(self, head: _Head, now: float) -> bool:
        """Can a link still be tied to `head` without an anchor (its walk is not yet
        `WALK` long)? A head past that is kept only while no other chain needs room."""
        return SLACK + (now - head.when) * self._rate < WALK

    def check(self, robot: int, n: int, link: bytes, now: float, *, anchor: bool) -> bool:
        """Is this heartbeat `robot`'s own? An anchor is (its signature was verified);
        a link is if it hashes to the last one accepted of one of its chains within as
        many steps as the time since allows (at most `WALK`)."""
        if anchor:
            return True
        if len(link) != LINK_LEN:
            return False
        for head in self._at.get(robot, ()):
            if self._continues(robot, head, n, link, now):
                self._hit = (robot, n, link, head)
                return True
        return False

    def commit(self, robot: int, n: int, link: bytes, now: float, *, anchor: bool) -> None:
        """Record an accepted heartbeat: a link moves the head `check` tied it to; an
        anchor moves the head it continues, moves nothing if it is behind one (at most
        `WALK` links: it came late), else starts a head."""
        heads = self._at.setdefault(robot, [])
        hit = self._hit
        if hit is not None and hit[:3] == (robot, n, link) and hit[3] in heads:
            head: _Head | None = hit[3]
        else:  # an anchor, or a link judged later (held within the start-up grace)
            head = next((h for h in heads if (h.n == n and h.link == link)
                         or self._continues(robot, h, n, link, now)), None)
        if head is None and anchor:
            if any(0 < (h.n - n) % _WRAP <= WALK
                   and hmac.compare_digest(_back(robot, h.link, (h.n - n) % _WRAP), link)
                   for h in heads):
                # Behind a head of its chain (a reordering channel, or a frame held in
                # our start-up grace, brought it late): keep the newer. As a head of its
                # own it would take links already revealed after it.
                return
            # A chain none of the heads continues: first among them; heads no link can
            # reach any more without an anchor make room first, then the oldest.
            heads.sort(key=lambda h: not self._open(h, now))
            del heads[HEADS - 1:]
            heads.insert(0, _Head(n, link, now))
            return
        if head is None:
            return  # `check` said no: nothing to record
        head.n, head.link, head.when = n, link, now
        if heads[0] is not head:
            heads.remove(head)
            heads.insert(0, head)

    def forget(self, robots: Iterable[int]) -> None:
        """Revoked robots: only an anchor (which their revoked key cannot sign any more)
        makes them heard again."""
        for r in robots:
            self._at.pop(r, None)

    def __contains__(self, robot: object) -> bool:
        return isinstance(robot, int) and bool(self._at.get(robot))


__all__ = ["ANCHOR_RUN", "CHAIN_LEN", "HEADS", "LINK_LEN", "SLACK", "WALK", "OwnChain",
           "PeerChains", "anchor_every", "resync_after", "step"]
