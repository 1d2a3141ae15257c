"""Link models both simulators share: one-way cuts and bursty loss.

- `LinkCut`: a one-way link fault (`fade`, `deaf`, a one-way partition) while it lasts:
  frames from its senders do not reach its receivers (sim/shared/faults.py `Fault.cut`).
- `GilbertElliott`: the bursty radio channel (`--loss-model burst`): each directed link
  is in a good state (every frame passes) or a bad one (every frame is lost), and
  switches per frame so that the mean loss is `loss` and a bad spell lasts `burst_len`
  frames on average (P(bad -> good) = 1/L, P(good -> bad) = p / (L (1 - p)), whose
  stationary share of bad is p). Losses one way, in bursts, as a radio fades.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

LOSS_MODELS = ("bernoulli", "burst")
"""`--loss-model`: independent losses per frame, or Gilbert-Elliott bursts."""


@dataclass(frozen=True, slots=True)
class LinkCut:
    start: float
    end: float
    senders: frozenset[int] | None
    """None: every robot."""
    receivers: frozenset[int] | None

    def cuts(self, sender: int, receiver: int, t: float) -> bool:
        return self.start <= t < self.end and sender != receiver \
            and (self.senders is None or sender in self.senders) \
            and (self.receivers is None or receiver in self.receivers)


@dataclass(slots=True)
class GilbertElliott:
    """Per directed link (sender, receiver) two-state loss, drawn from `rng`."""

    loss: float
    burst_len: float
    rng: random.Random
    _bad: set[tuple[int, int]] = field(default_factory=set)
    _to_bad: float = field(init=False)
    _to_good: float = field(init=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"loss must be in [0, 1), got {self.loss}")
        if not self.burst_len >= 1.0:
            raise ValueError(f"burst length must be at least 1 frame, got {self.burst_len}")
        self._to_good = 1.0 / self.burst_len
        self._to_bad = self.loss / (self.burst_len * (1.0 - self.loss)) if self.loss else 0.0

    def lost(self, sender: int, receiver: int) -> bool:
        """Advance the link one frame; True if this frame is lost."""
        link = (sender, receiver)
        if link in self._bad:
            if self.rng.random() < self._to_good:
                self._bad.discard(link)
                return False
            return True
        if self._to_bad and self.rng.random() < self._to_bad:
            self._bad.add(link)
            return True
        return False


__all__ = ["LOSS_MODELS", "GilbertElliott", "LinkCut"]
