"""Per-robot signatures, injected (DESIGN section 2, "Who may say what").

The core stays stdlib-only and sans-IO: it never imports a crypto library. In per-robot
mode a `Node` is given an `Identity`: a `Signer` holding this robot's own key and a
`Verifier` holding every robot's public key. `swarmd.base.identity` implements both with
Ed25519; tests and simulators may use any object with the same shape.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

SIGNATURE_LEN = 64
"""bytes. An Ed25519 signature."""
PUBLIC_KEY_LEN = 32
"""bytes. An Ed25519 public key."""


class Signer(Protocol):
    robot: int

    def sign(self, data: bytes) -> bytes:
        """`SIGNATURE_LEN` bytes over `data`, with this robot's own key."""
        ...


class Verifier(Protocol):
    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        """Is `signature` robot `robot`'s over `data`? False, never an exception, for an
        unknown or revoked robot, a bad signature, or wrong lengths.

        `history`: `data` is a warning or a LEAVE backing a takeover's certificate
        (`wire.BACKERS`, relayed or restored), not a frame heard first-hand: a key no
        longer in force — a revoked robot's, or one retired by a rotation — verifies it
        still, so that a takeover accepted before the key changed keeps its proof
        (DESIGN, "Key changes never rewrite history"). Only keys in force verify
        anything else."""
        ...


class Identity(NamedTuple):
    """What a `Node` is given in per-robot mode."""

    signer: Signer
    verifier: Verifier


__all__ = ["PUBLIC_KEY_LEN", "SIGNATURE_LEN", "Identity", "Signer", "Verifier"]
