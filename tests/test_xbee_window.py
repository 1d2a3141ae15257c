"""The XBee send window (swarmd/transport/window.py), table-driven on virtual time.

Each row: a window (max_in_flight, queue_size; status_timeout 2 s), a list of events and
what the last event returns plus the state after it. Events:

    ("offer", frame)        -> True when the oldest queued frame was dropped
    ("take", now)           -> [(frame_id, frame), ...] to write
    ("status", frame_id)    -> False when that frame is not in flight
    ("expire", now)         -> [frame_id, ...] given up
    ("reset",)              -> frames in flight that were lost
"""

from __future__ import annotations

from typing import Any

import pytest

from swarmd.transport.window import STALL_AFTER, SendWindow

Event = tuple[Any, ...]


def run(window: SendWindow, events: list[Event]) -> list[Any]:
    out: list[Any] = []
    for name, *args in events:
        if name == "offer":
            out.append(window.offer(args[0]))
        elif name == "take":
            out.append(window.take(args[0]))
        elif name == "status":
            out.append(window.status(args[0]))
        elif name == "expire":
            out.append(window.expire(args[0]))
        elif name == "reset":
            out.append(window.reset())
        else:
            raise AssertionError(f"unknown event {name}")
    return out


def offers(*frames: bytes) -> list[Event]:
    return [("offer", f) for f in frames]


A, B, C, D = b"a", b"b", b"c", b"d"

# (name, max_in_flight, queue_size, events, last output, in flight {id: deadline},
#  queued, timeouts in row, stalled)
ROWS: list[tuple[str, int, int, list[Event], Any, dict[int, float], int, int, bool]] = [
    ("ids start at 1, deadline = now + timeout",
     2, 4, [*offers(A), ("take", 10.0)], [(1, A)], {1: 12.0}, 0, 0, False),
    ("at most max_in_flight go out, the rest wait in order",
     2, 4, [*offers(A, B, C), ("take", 0.0)], [(1, A), (2, B)], {1: 2.0, 2: 2.0}, 1, 0,
     False),
    ("a status frees a slot for the next queued frame",
     2, 4, [*offers(A, B, C), ("take", 0.0), ("status", 1), ("take", 1.0)], [(3, C)],
     {2: 2.0, 3: 3.0}, 0, 0, False),
    ("a full queue drops its oldest frame (True)",
     1, 2, [*offers(A, B, C)], True, {}, 2, 0, False),
    ("after the drop the newest frames remain",
     1, 2, [*offers(A, B, C), ("take", 0.0)], [(1, B)], {1: 2.0}, 1, 0, False),
    ("not full: nothing dropped",
     1, 2, [*offers(A, B)], False, {}, 2, 0, False),
    ("a status for an unknown id is ignored",
     2, 4, [*offers(A), ("take", 0.0), ("status", 7)], False, {1: 2.0}, 0, 0, False),
    ("nothing expires before its deadline",
     2, 4, [*offers(A), ("take", 0.0), ("expire", 1.99)], [], {1: 2.0}, 0, 0, False),
    ("a frame expires at its deadline and counts a timeout",
     2, 4, [*offers(A), ("take", 0.0), ("expire", 2.0)], [1], {}, 0, 1, False),
    ("a status after the timeout is late: ignored",
     2, 4, [*offers(A), ("take", 0.0), ("expire", 2.0), ("status", 1)], False, {}, 0, 1,
     False),
    ("expiry goes oldest deadline first",
     2, 4, [*offers(A), ("take", 0.0), *offers(B), ("take", 1.0), ("expire", 5.0)], [1, 2],
     {}, 0, 2, False),
    ("a status in between resets the timeouts in a row",
     1, 4, [*offers(A), ("take", 0.0), ("expire", 2.0), *offers(B), ("take", 2.0),
            ("status", 2)], True, {}, 0, 0, False),
    (f"{STALL_AFTER} timeouts in a row stall the window; expiry stops there",
     4, 4, [*offers(A, B, C, D), ("take", 0.0), ("expire", 9.0)], [1, 2, 3], {4: 2.0}, 0,
     3, True),
    ("reset loses what is in flight, clears the queue and the stall",
     4, 4, [*offers(A, B, C, D), ("take", 0.0), ("expire", 9.0), *offers(A), ("reset",)],
     1, {}, 0, 0, False),
    ("ids wrap after 255 to 1, skipping those still in flight",
     2, 4, [*offers(A), ("take", 0.0),  # id 1 stays in flight
            *[e for i in range(2, 256) for e in (("offer", B), ("take", 0.0), ("status", i))],
            *offers(C), ("take", 0.0)], [(2, C)], {1: 2.0, 2: 2.0}, 0, 0, False),
]


@pytest.mark.parametrize(
    ("max_in_flight", "queue_size", "events", "last", "in_flight", "queued", "in_row",
     "stalled"),
    [row[1:] for row in ROWS], ids=[row[0] for row in ROWS])
def test_window(max_in_flight: int, queue_size: int, events: list[Event], last: Any,
                in_flight: dict[int, float], queued: int, in_row: int,
                stalled: bool) -> None:
    window = SendWindow(max_in_flight=max_in_flight, queue_size=queue_size, status_timeout=2.0)
    out = run(window, events)
    assert out[-1] == last
    assert window.in_flight == in_flight
    assert window.queued == queued
    assert window.timeouts_in_row == in_row
    assert window.stalled is stalled


def test_next_deadline_is_the_earliest_in_flight() -> None:
    window = SendWindow(max_in_flight=4, queue_size=4, status_timeout=2.0)
    assert window.next_deadline() is None
    window.offer(A)
    window.take(5.0)
    window.offer(B)
    window.take(6.0)
    assert window.next_deadline() == 7.0
    window.status(1)
    assert window.next_deadline() == 8.0


def test_max_in_flight_is_bounded_by_the_frame_id_space() -> None:
    with pytest.raises(ValueError, match=r"1\.\.64"):
        SendWindow(max_in_flight=65, queue_size=4, status_timeout=2.0)
