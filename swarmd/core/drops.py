"""Why a frame was refused: every refused frame is a counted drop (DESIGN section 2).

A `StrEnum`, so a reason is also its plain name: `Snapshot.drops` maps reasons to counts
and reads and prints as it always did (`drops["auth"]`, `{"auth": 3}` in JSON).
"""

from __future__ import annotations

from enum import StrEnum


class DropReason(StrEnum):
    IRRELEVANT = "irrelevant"
    """No rule of this robot would act on it (DESIGN, "What a robot hears")."""
    SWARM = "swarm"
    """Another swarm's frame."""
    UNKNOWN_SENDER = "unknown_sender"
    """A sender the swarm plan does not name."""
    VERSION = "version"
    """Another wire version (or a fragment reaching a robot that does not reassemble)."""
    MALFORMED = "malformed"
    """Bytes that are no frame."""
    AUTH = "auth"
    """A tag or signature that does not verify, or none where one is needed."""
    REPLAY = "replay"
    """A frame seen already, or older than the sender's window."""
    SEQ_JUMP = "seq_jump"
    """A sequence number further ahead than the time that passed allows."""
    OWN = "own"
    """A frame sent as this robot (multicast loopback, or a second daemon with its id)."""
    BAD_FUNCTION = "bad_function"
    """A slot index the plan does not have."""
    UNCERTIFIED = "uncertified"
    """A new holder or epoch without a certificate this robot verified."""
    UNANCHORED = "unanchored"
    """Per-robot mode: a heartbeat whose chain link this robot cannot tie to its sender
    (it lost the chain, or the frame is forged): no liveness until the next anchor."""
    STALE_EVIDENCE = "stale_evidence"
    """A warning its suspect refuted."""
    NOT_WITNESS = "not_witness"
    """A warning from a robot that does not watch the slot (rule 3)."""
    STALE_CLAIM = "stale_claim"
    """A claim heard again after it stopped being believed (rule 10)."""
    OUTDATED = "outdated"
    """A robot's older frame that its own later heartbeat contradicts: a LEAVE of the
    entry it holds since, a claim or hold it gave up since (a recording of an earlier
    run, or a reordered frame; DESIGN, "Every proof is bound to its run")."""


__all__ = ["DropReason"]
