"""XBee API frames on a UART: framing, checksum, API-mode-2 escaping (docs/radios.md).

    7E | length (2 B, big-endian) | frame data | checksum = 0xFF - (sum(data) & 0xFF)

In API mode 2 every byte after the start delimiter that is 0x7E, 0x7D, 0x11 or 0x13 is
sent as 0x7D followed by the byte XOR 0x20 (0x11/0x13 are XON/XOFF). The parser is
incremental and resynchronises on the next 0x7E after garbage between frames (in API
mode 2 also inside a frame, since an escaped stream has no raw 0x7E in a frame).

API mode 1 has no escapes, so inside a frame only the length says where it ends: one
corrupt length (`7E FF FF`) would otherwise swallow the next 64 KiB. Two bounds, as the
Digi guides leave the radio's own rule unstated (docs/radios.md, "What the emulator
answers"): a length longer than any frame the radio takes (`MAX_FRAME_DATA`) drops the
frame at once, and a 0x7E that arrives after the line was quiet for `INTER_CHAR_TIMEOUT`
inside a frame starts a new one (the partial frame is dropped).
"""

from __future__ import annotations

from collections import Counter

START = 0x7E
ESC = 0x7D
_SPECIAL = frozenset((0x7E, 0x7D, 0x11, 0x13))

MAX_FRAME_DATA = 512
"""B. Longest frame data taken from the UART: the largest request an emulated firmware
knows is a Zigbee Transmit Request with 255 B of payload (269 B of frame data)."""
INTER_CHAR_TIMEOUT = 0.1
"""s. A silence this long inside a frame, then a 0x7E: a new frame starts."""


def checksum(data: bytes) -> int:
    return 0xFF - (sum(data) & 0xFF)


def escape(data: bytes) -> bytes:
    out = bytearray()
    for b in data:
        if b in _SPECIAL:
            out += bytes((ESC, b ^ 0x20))
        else:
            out.append(b)
    return bytes(out)


def encode(data: bytes, api_mode: int) -> bytes:
    """One API frame around `data` (frame type first) in API mode 1 or 2."""
    body = len(data).to_bytes(2, "big") + data + bytes((checksum(data),))
    return bytes((START,)) + (escape(body) if api_mode == 2 else body)


class FrameParser:
    """Feed UART bytes, get frame data (type byte first) of frames with a good checksum.

    `drops` counts what was thrown away: `checksum`, `truncated` (a new start inside a
    frame), `length` (zero or over `max_length`), `timeout` (a start after a silence)."""

    def __init__(self, api_mode: int, *, max_length: int = MAX_FRAME_DATA,
                 gap: float = INTER_CHAR_TIMEOUT) -> None:
        self.api_mode = api_mode
        self.max_length = max_length
        self.gap = gap
        self._buf = bytearray()  # unescaped bytes after the start delimiter
        self._in_frame = False
        self._escaped = False
        self._last: float | None = None  # when the previous bytes arrived
        self.drops: Counter[str] = Counter()

    def feed(self, data: bytes, now: float | None = None) -> list[bytes]:
        """`now` (s, monotonic) is when `data` arrived; None disables the timeout."""
        quiet = (now is not None and self._last is not None
                 and now - self._last > self.gap)
        if now is not None:
            self._last = now
        frames: list[bytes] = []
        for b in data:
            # API mode 1 does not escape, so 0x7E inside a frame is data: only the length
            # ends a frame, unless the line was quiet first. In mode 2 a raw 0x7E is
            # always a start (resynchronise).
            if b == START and (self.api_mode == 2 or not self._in_frame or quiet):
                if self._in_frame and self._buf:
                    self.drops["timeout" if self.api_mode == 1 else "truncated"] += 1
                self._in_frame = True
                self._escaped = False
                self._buf.clear()
                quiet = False
                continue
            quiet = False
            if not self._in_frame:
                continue  # garbage between frames
            if self.api_mode == 2:
                if self._escaped:
                    b ^= 0x20
                    self._escaped = False
                elif b == ESC:
                    self._escaped = True
                    continue
            self._buf.append(b)
            self._check_length(frames)
        return frames

    def _check_length(self, frames: list[bytes]) -> None:
        """After each byte of a frame: drop it once its length field is impossible;
        once it is complete, append its data to `frames` if the checksum agrees."""
        if len(self._buf) < 2:
            return
        length = int.from_bytes(self._buf[:2], "big")
        if len(self._buf) == 2 and not 0 < length <= self.max_length:
            self.drops["length"] += 1  # hunt for the next start delimiter
            self._in_frame = False
            self._buf.clear()
        elif len(self._buf) == length + 3:
            data_part = bytes(self._buf[2:-1])
            if checksum(data_part) == self._buf[-1]:
                frames.append(data_part)
            else:
                self.drops["checksum"] += 1
            self._in_frame = False
            self._buf.clear()
