"""The XBee send window: frame ids, frames waiting for their transmit status, timeouts.

Sans-IO (no clock, no loop, no radio): the transport passes the time in and does what
the answers say. Rules (docs/radios.md):

- a frame goes out with a frame id 1..255 (id 0 would ask the radio for no status;
  ids wrap at 255 and skip those still in flight);
- at most `max_in_flight` frames wait for their status at a time; more wait in a queue
  of `queue_size` whose OLDEST frame is dropped when a new one arrives on a full queue:
  a newer heartbeat supersedes an older one;
- a frame whose status has not come `status_timeout` seconds after it went out is given
  up; a status arriving later is ignored;
- `STALL_AFTER` timeouts in a row, with no status in between, mean the radio stopped
  answering: `stalled` turns true and the transport takes the radio down.
"""

from __future__ import annotations

from collections import deque

STALL_AFTER = 3
"""Status timeouts in a row after which the radio counts as no longer answering."""


class SendWindow:
    """Frames queued and in flight, by frame id, each with its status deadline."""

    def __init__(self, *, max_in_flight: int, queue_size: int, status_timeout: float) -> None:
        if not 1 <= max_in_flight <= 64:
            raise ValueError("max_in_flight must be 1..64 (frame ids wrap at 255)")
        self.max_in_flight = max_in_flight
        self.status_timeout = status_timeout
        self._queue: deque[bytes] = deque(maxlen=queue_size)
        self._deadlines: dict[int, float] = {}
        self._last_id = 0
        self.timeouts_in_row = 0
        """Status timeouts since the last status that came (or the last reset)."""

    @property
    def queued(self) -> int:
        return len(self._queue)

    @property
    def in_flight(self) -> dict[int, float]:
        """Frame id -> status deadline, of the frames sent and not yet answered."""
        return dict(self._deadlines)

    @property
    def stalled(self) -> bool:
        return self.timeouts_in_row >= STALL_AFTER

    def offer(self, frame: bytes) -> bool:
        """Queue a frame. True when the queue was full and its oldest frame was dropped."""
        full = len(self._queue) == self._queue.maxlen
        self._queue.append(frame)  # a full deque drops its oldest
        return full

    def take(self, now: float) -> list[tuple[int, bytes]]:
        """The frames to write now, each with its frame id; their deadlines start now."""
        out = []
        while self._queue and len(self._deadlines) < self.max_in_flight:
            frame_id = self._allocate_id()
            self._deadlines[frame_id] = now + self.status_timeout
            out.append((frame_id, self._queue.popleft()))
        return out

    def status(self, frame_id: int) -> bool:
        """A transmit status came for `frame_id`. False when that frame is not in flight
        (given up already, or an id we did not send): ignore the status."""
        if self._deadlines.pop(frame_id, None) is None:
            return False
        self.timeouts_in_row = 0
        return True

    def expire(self, now: float) -> list[int]:
        """Give up the frames whose deadline has passed, oldest deadline first, and return
        their ids. Stops at the timeout that makes the window `stalled`: the transport
        takes the radio down and the frames still in flight are lost with it (`reset`)."""
        expired = []
        for frame_id, deadline in sorted(self._deadlines.items(), key=lambda kv: kv[1]):
            if deadline > now or self.stalled:
                break
            del self._deadlines[frame_id]
            self.timeouts_in_row += 1
            expired.append(frame_id)
        return expired

    def next_deadline(self) -> float | None:
        """When the next in-flight frame times out; None when nothing is in flight."""
        return min(self._deadlines.values(), default=None)

    def reset(self) -> int:
        """Forget everything (the radio went down or is closing); returns how many frames
        were in flight, now lost."""
        lost = len(self._deadlines)
        self._deadlines.clear()
        self._queue.clear()
        self.timeouts_in_row = 0
        return lost

    def _allocate_id(self) -> int:
        while True:
            self._last_id = self._last_id % 255 + 1
            if self._last_id not in self._deadlines:
                return self._last_id
