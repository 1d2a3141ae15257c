"""Which takeovers the monitor believes: exactly the ones a daemon would (DESIGN section
2, "Takeovers backed by evidence"), in every auth mode: a CLAIM counts only with its
certificate (the suspect's own LEAVE, or unrefuted WARNs of a quorum of distinct
witnesses), judged by the daemons' own `EvidenceStore`, fed the same frames (heard
directly, or relayed in CERTs). A CLAIM alone, from an insider, supersedes nobody on the
monitor either.
"""

from __future__ import annotations

from swarmd.core import wire
from swarmd.core.evidence import EvidenceStore, says
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan


class MonitorClaims:
    """The certified takeovers heard: {(function, epoch, claimant)}."""

    def __init__(self, plan: SwarmPlan, params: Params) -> None:
        self.plan = plan
        self.store = EvidenceStore(0, plan, params)  # robot 0: nobody's own ears
        self.certified: set[tuple[str, int, int]] = set()

    def frame(self, frame: wire.Frame, now: float) -> None:
        """A decoded, verified frame (or CERT) that may be evidence or a claim."""
        msg = frame.msg
        if isinstance(msg, wire.Cert):
            self._relayed(msg, now)
        elif isinstance(msg, wire.Warn):
            self._evidence(msg.function, frame.sender, msg.suspect, msg.epoch, frame.raw, now)
        elif isinstance(msg, wire.Leave):
            self._evidence(msg.function, frame.sender, frame.sender, msg.epoch, frame.raw, now)
        elif isinstance(msg, wire.Refute):
            f = self.plan.function_at(msg.function)
            if f is not None:
                self.store.add_refute(f, frame.sender, msg, frame.raw)
        elif isinstance(msg, wire.Claim):
            self.claim(frame.sender, msg, frame.raw, now)

    def claim(self, claimant: int, c: wire.Claim, raw: bytes, now: float) -> bool:
        """A CLAIM: believed (True) if the evidence here certifies it, else kept
        a while in case its certificate comes later (a channel that reorders)."""
        f = self.plan.function_at(c.function)
        if f is None:
            return False
        if self.store.certify(f, claimant, c, 0):
            self.certified.add((f, c.epoch, claimant))
            return True
        self.store.hold_pending(f, claimant, c, now, raw)
        return False

    def believed(self, function: str, epoch: int, robot: int) -> bool:
        if (function, epoch, robot) not in self.certified:
            return False
        return self.store.is_certified(function, robot, epoch)  # refuted since?

    def _relayed(self, cert: wire.Cert, now: float) -> None:
        inner = cert.inner
        if isinstance(inner.msg, wire.Claim):
            self.claim(inner.sender, inner.msg, cert.raw, now)
            return
        if isinstance(inner.msg, wire.Refute):
            f = self.plan.function_at(cert.function)
            if f is not None:
                self.store.add_refute(f, inner.sender, inner.msg, cert.raw)
            return
        said = says(inner)
        if said is not None:
            self._evidence(cert.function, *said, cert.raw, now)

    def _evidence(self, slot: int, witness: int, suspect: int, epoch: int, raw: bytes,
                  now: float) -> None:
        f = self.plan.function_at(slot)
        if f is None:
            return
        ready = self.store.record(f, witness, suspect, epoch, raw, 0, now)
        for claimant, claim, _signed in ready or ():
            self.certified.add((f, claim.epoch, claimant))
