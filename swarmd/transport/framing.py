"""Frame delimiting for byte-stream radios: COBS + CRC-32, zero-byte delimited.

A transparent-mode XBee (AP=0) or a SiK telemetry radio hands us a byte stream, not
frames: the radio packetises at its own timeout, merges writes, splits long ones, and
noise on the air or the UART adds bytes. So every swarmd frame goes
out as::

    00 | COBS(frame + CRC32_LE(frame)) | 00

- COBS (Cheshire & Baker 1999) removes every 0x00 from the body, so 0x00 is a pure
  delimiter: after any garbage the decoder is back in sync at the next 0x00.
- The leading 0x00 costs one byte and cuts off noise that arrived before the frame, so
  garbage never fuses with the following good frame.
- CRC-32 (zlib's, run in C) rejects corrupted or fused chunks; a 16-bit check would let
  about one random chunk in 65 536 through, too many for a noisy link running for days.

`FrameDecoder.feed(bytes)` returns the good frames in order and counts the rest by
reason; it never raises on input (DESIGN: bad input never takes the daemon down).
"""

from __future__ import annotations

import zlib
from collections import Counter

from swarmd.transport.drops import FramingDrop

DELIMITER = b"\x00"
CRC_LEN = 4
MAX_FRAME = 1024
"""Largest frame (before COBS) accepted; a longer run without a delimiter is noise."""


class CobsError(ValueError):
    """Bytes that are not a valid COBS encoding."""


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode `data`: the result contains no 0x00 byte."""
    out = bytearray()
    for chunk in data.split(b"\x00"):
        # A code byte 0xFF means "254 data bytes, no zero follows" (the COBS rule).
        while len(chunk) >= 0xFE:
            out.append(0xFF)
            out += chunk[:0xFE]
            chunk = chunk[0xFE:]
        out.append(len(chunk) + 1)
        out += chunk
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Invert `cobs_encode`. Raises `CobsError` on anything it could not have made."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise CobsError("zero byte inside a COBS block")
        i += 1
        end = i + code - 1
        if end > n:
            raise CobsError("COBS block runs past the end")
        block = data[i:end]
        if 0 in block:
            raise CobsError("zero byte inside a COBS block")
        out += block
        i = end
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


def encode(frame: bytes) -> bytes:
    """The bytes to write for one frame (delimiters included)."""
    crc = zlib.crc32(frame).to_bytes(CRC_LEN, "little")
    return DELIMITER + cobs_encode(frame + crc) + DELIMITER


def overhead(frame_len: int) -> int:
    """Bytes `encode` adds to a frame of `frame_len` bytes (for the channel budget)."""
    return 2 + CRC_LEN + 1 + (frame_len + CRC_LEN) // 0xFE


class FrameDecoder:
    """Incremental decoder: feed it stream bytes cut anywhere, get the good frames."""

    def __init__(self, max_frame: int = MAX_FRAME) -> None:
        self._buf = bytearray()
        self._max_encoded = max_frame + CRC_LEN + 2 + (max_frame + CRC_LEN) // 0xFE
        self._skipping = False
        self.drops: Counter[str] = Counter()
        """Rejected chunks by reason: cobs, crc, short, overlong."""
        self.frames = 0

    def feed(self, data: bytes) -> list[bytes]:
        """Add stream bytes; return the complete, checked frames they finish."""
        good: list[bytes] = []
        start = 0
        while True:
            stop = data.find(0, start)
            if stop < 0:
                self._append(data[start:])
                return good
            self._append(data[start:stop])
            chunk = bytes(self._buf)
            skipped = self._skipping
            self._buf.clear()
            self._skipping = False
            start = stop + 1
            if skipped:
                continue  # the tail of an over-long run; already counted
            if chunk:
                frame = self._check(chunk)
                if frame is not None:
                    good.append(frame)

    def _append(self, part: bytes) -> None:
        if self._skipping or not part:
            return
        self._buf += part
        if len(self._buf) > self._max_encoded:
            # No delimiter for longer than any frame can be: noise (or a lost 0x00).
            # Drop what we hold and ignore bytes up to the next delimiter.
            self.drops[FramingDrop.OVERLONG] += 1
            self._buf.clear()
            self._skipping = True

    def _check(self, chunk: bytes) -> bytes | None:
        try:
            raw = cobs_decode(chunk)
        except CobsError:
            self.drops[FramingDrop.COBS] += 1
            return None
        if len(raw) <= CRC_LEN:
            self.drops[FramingDrop.SHORT] += 1
            return None
        frame, crc = raw[:-CRC_LEN], raw[-CRC_LEN:]
        if zlib.crc32(frame).to_bytes(CRC_LEN, "little") != crc:
            self.drops[FramingDrop.CRC] += 1
            return None
        self.frames += 1
        return frame
