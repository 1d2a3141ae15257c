"""XBee API frames on a UART: framing, checksum, API-mode-2 escaping (docs/radios.md).

    7E | length (2 B, big-endian) | frame data | checksum = 0xFF - (sum(data) & 0xFF)

In API mode 2 every byte after the start delimiter that is 0x7E, 0x7D, 0x11 or 0x13 is
sent as 0x7D followed by the byte XOR 0x20 (0x11/0x13 are XON/XOFF). The parser is
incremental and resynchronises on the next 0x7E after garbage between frames (in API
mode 2 also inside a frame, since an escaped stream has no raw 0x7E in a frame).
"""

from __future__ import annotations

from collections import Counter

START = 0x7E
ESC = 0x7D
_SPECIAL = frozenset((0x7E, 0x7D, 0x11, 0x13))


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
    """Feed UART bytes, get frame data (type byte first) of frames with a good checksum."""

    def __init__(self, api_mode: int) -> None:
        self.api_mode = api_mode
        self._buf = bytearray()  # unescaped bytes after the start delimiter
        self._in_frame = False
        self._escaped = False
        self.drops: Counter[str] = Counter()

    def feed(self, data: bytes) -> list[bytes]:
        frames: list[bytes] = []
        for b in data:
            # API mode 1 does not escape, so 0x7E inside a frame is data: only the length
            # ends a frame. In mode 2 a raw 0x7E is always a start (resynchronise).
            if b == START and (self.api_mode == 2 or not self._in_frame):
                if self._in_frame and self._buf:
                    self.drops["truncated"] += 1
                self._in_frame, self._escaped = True, False
                self._buf.clear()
                continue
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
            if len(self._buf) >= 2:
                length = int.from_bytes(self._buf[:2], "big")
                if len(self._buf) == length + 3:
                    data_part = bytes(self._buf[2:-1])
                    if checksum(data_part) == self._buf[-1] and length > 0:
                        frames.append(data_part)
                    else:
                        self.drops["checksum"] += 1
                    self._in_frame = False
                    self._buf.clear()
        return frames
