"""Per-robot signatures as the sans-IO core sees them (DESIGN section 1: the core never
imports a crypto library). The edge (`swarmd.identity`) implements these with Ed25519.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

SIGNATURE_LEN = 64          # Ed25519
PUBLIC_KEY_LEN = 32


class Signer(Protocol):
    robot: int

    def sign(self, data: bytes) -> bytes: ...          # SIGNATURE_LEN bytes, this robot's key


class Verifier(Protocol):
    def verify(self, robot: int, data: bytes, signature: bytes) -> bool: ...
    # False (never raises) for an unknown or revoked robot, a bad signature, wrong lengths


class Identity(NamedTuple):            # what a Node is given in per-robot mode
    signer: Signer
    verifier: Verifier
