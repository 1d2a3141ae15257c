"""Why a transport threw bytes away before the core saw a frame (DESIGN section 2: every
refused frame is a counted drop).

`StrEnum`s, like the core's `swarmd.core.drops.DropReason`, so a reason is also its
plain name: counters keyed by them print and serialise as before (`fragment_drop:short`).
"""

from __future__ import annotations

from enum import StrEnum


class FragmentDrop(StrEnum):
    """A fragment the reassembler (`swarmd.transport.fragment`) did not keep."""

    SHORT = "short"
    """No payload after the fragment header."""
    BAD_COUNT = "bad_count"
    """A fragment count outside 2..MAX_FRAGMENTS."""
    BAD_INDEX = "bad_index"
    """An index not below the count."""
    DUPLICATE = "duplicate"
    """A piece already held, or one of a message completed within the expiry."""
    EVICTED_SENDER = "evicted_sender"
    """A sender's oldest partial message, pushed out by its newest."""
    EVICTED = "evicted"
    """The oldest partial message, pushed out when the reassembler is full."""
    INCONSISTENT = "inconsistent"
    """A piece whose count differs from the message's first piece."""
    TOO_LARGE = "too_large"
    """Pieces adding up to more than any frame."""
    SENDER_MISMATCH = "sender_mismatch"
    """A whole message whose frame names another sender than its fragments."""
    EXPIRED = "expired"
    """A message not complete within the expiry after its first piece."""


class FramingDrop(StrEnum):
    """A chunk of a serial stream (`swarmd.transport.framing`) that is no frame."""

    COBS = "cobs"
    """Bytes that are no COBS encoding."""
    CRC = "crc"
    """A checksum that does not match."""
    SHORT = "short"
    """Shorter than its checksum."""
    OVERLONG = "overlong"
    """No delimiter for longer than any frame can be (noise or a lost 0x00)."""


__all__ = ["FragmentDrop", "FramingDrop"]
