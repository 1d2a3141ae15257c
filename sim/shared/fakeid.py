"""Throwaway per-robot identities for the simulators and tests, stdlib only.

A stand-in for `swarmd.base.identity`'s Ed25519 keys with the same interface
(`swarmd.core.auth.Signer` / `Verifier`): each robot's "signature" is an HMAC-SHA512
(64 bytes, the size of an Ed25519 signature, so frame sizes are the real ones) under a
secret of that robot's own. Robot R's key signs only as R, which is all the protocol
relies on; the verifier here holds the secrets, so it is no public-key scheme: fine
for one process simulating a swarm, never for a real one.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Iterable

from swarmd.core.auth import SIGNATURE_LEN, Identity


class FakeSigner:
    __slots__ = ("_secret", "robot")

    def __init__(self, robot: int, secret: bytes) -> None:
        self.robot = robot
        self._secret = secret

    def sign(self, data: bytes) -> bytes:
        return hmac.new(self._secret, data, hashlib.sha512).digest()[:SIGNATURE_LEN]


class FakeVerifier:
    __slots__ = ("_revoked", "_secrets")

    def __init__(self, secrets: dict[int, bytes], revoked: Iterable[int] = ()) -> None:
        self._secrets = dict(secrets)
        self._revoked = frozenset(revoked)

    def revoke(self, robots: Iterable[int]) -> None:
        """Revoke these robots from now on (a SIGHUP with a longer `revoked` list): what
        they signed before still verifies as history (`Verifier.verify`)."""
        self._revoked = self._revoked | frozenset(robots)

    def verify(self, robot: int, data: bytes, signature: bytes, *,
               history: bool = False) -> bool:
        secret = self._secrets.get(robot)
        if secret is None or (robot in self._revoked and not history) \
                or len(signature) != SIGNATURE_LEN:
            return False
        good = hmac.new(secret, data, hashlib.sha512).digest()[:SIGNATURE_LEN]
        return hmac.compare_digest(good, signature)


def fake_identities(robots: Iterable[int], seed: int = 0) -> dict[int, Identity]:
    """One identity per robot; all share one verifier that knows every robot."""
    secrets = {r: hashlib.sha256(f"swarmd-fake-{seed}-{r}".encode()).digest()
               for r in robots}
    verifier = FakeVerifier(secrets)
    return {r: Identity(FakeSigner(r, s), verifier) for r, s in secrets.items()}
