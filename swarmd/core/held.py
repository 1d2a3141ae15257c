"""Frames a robot holds at start-up until it can judge them (DESIGN section 2, "Who may
say what": "Every proof is bound to its run").

A robot's seqs only rise across its restarts, so its own heartbeat of this run tells a
receiver which of its frames are older words it contradicts (`words.py`, `outdated`).
A receiver that has just started has heard nobody yet: with a shared key or unsigned,
a recording of an earlier run played to it then is believed like any frame, and so is
a recorded word (a standby heartbeat of the earlier run, played just before a recorded
hold numbered above it). So within its start-up grace a robot holds every frame that
would raise a view entry (a fence, a takeover, an epoch change) and is numbered above
its sender's word here, or whose sender has no word here yet: only a later word,
numbered above it, can judge it. It judges the held frames when such a word arrives (a
live sender's frames are numbered above every recording, so its next heartbeat that
raises nothing judges them, and a recording is then `outdated`), or when the grace
ends (a sender not heard above them within it is dead, cut off, or a new holder whose
every frame raises the entry: its frames are taken as they would have been).

While a frame that would fence its own hold is held, the robot does not execute that
slot (`NodeBase._paused`), and executes it again at the same entry if every such frame
is judged `outdated` (DESIGN rule 2: never two executors beyond the takeover bound).

Bad input never grows memory: at most `PER_SENDER` frames a sender and `TOTAL` in all.
Past the bound the lowest-numbered frame of the sender holding the most is pushed out
and counted (`held_over`): a recording is numbered below its sender's live frames, so a
flood of it pushes out itself, never the live word it waits for.
"""

from __future__ import annotations

from typing import NamedTuple

from swarmd.core import wire

PER_SENDER = 8
"""Distinct frames held per sender: more than a robot says between two of its words
that would raise an entry (a LEAVE, a heartbeat of a new holder, a warning or two),
and than a new holder says in one start-up grace (its entry, a reassertion). The same
frame again (a new holder heartbeats its entry ten times a second at `udp()`) takes the
place of the one held, numbered higher, and is not counted."""

TOTAL = 64
"""Frames held in all, whatever the swarm's size: a few kilobytes (a frame is at most a
few hundred bytes, kept once as bytes and once decoded)."""


class HeldFrame(NamedTuple):
    """A frame through every receive filter, not acted on yet."""

    sender: int
    seq: int
    slot: int
    frame: wire.Frame
    data: bytes
    """The bytes as heard (empty when a driver handed the frame decoded)."""


class HeldFrames:
    """The held frames in the order they came, bounded (module docstring)."""

    __slots__ = ("_frames", "_per_sender", "_total")

    def __init__(self, per_sender: int = PER_SENDER, total: int = TOTAL) -> None:
        self._frames: list[HeldFrame] = []
        self._per_sender, self._total = per_sender, total

    def __len__(self) -> int:
        return len(self._frames)

    def hold(self, held: HeldFrame) -> int:
        """Keep `held`; returns how many frames the bound pushed out (0 or 1: `held`
        itself, when it is the lowest-numbered of its sender's). A frame saying what one
        held of its sender says replaces it if numbered higher: judged by its latest
        copy, it stands or falls alike."""
        for i, h in enumerate(self._frames):
            if h.sender == held.sender and h.frame.msg == held.frame.msg:
                if held.seq > h.seq:
                    self._frames[i] = held
                return 0
        self._frames.append(held)
        mine = [h for h in self._frames if h.sender == held.sender]
        if len(mine) > self._per_sender:
            self._frames.remove(min(mine, key=lambda h: h.seq))
            return 1
        if len(self._frames) > self._total:
            self._frames.remove(self._lowest_of_the_most())
            return 1
        return 0

    def _lowest_of_the_most(self) -> HeldFrame:
        """The lowest-numbered frame of the sender that has the most frames held."""
        counts: dict[int, int] = {}
        for h in self._frames:
            counts[h.sender] = counts.get(h.sender, 0) + 1
        most = max(counts, key=lambda s: counts[s])
        return min((h for h in self._frames if h.sender == most), key=lambda h: h.seq)

    def waiting(self, sender: int | None = None, below: int | None = None
                ) -> list[HeldFrame]:
        """The frames held (of `sender`, numbered below `below`: its word can judge
        them), in the order they came; still held until `forget`, so that what judging
        them does sees them as held (a hold paused by them, `NodeBase._paused`)."""
        return [h for h in self._frames if (sender is None or h.sender == sender)
                and (below is None or h.seq < below)]

    def forget(self, judged: list[HeldFrame]) -> None:
        """These frames were judged: no longer held."""
        if judged:
            self._frames = [h for h in self._frames if h not in judged]

    def about(self, slot: int) -> bool:
        """Is a frame about wire slot `slot` held?"""
        return any(h.slot == slot for h in self._frames)


__all__ = ["PER_SENDER", "TOTAL", "HeldFrame", "HeldFrames"]
