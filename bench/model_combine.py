"""How a standby should combine three links' silences (DESIGN "Detection"): a model,
not the protocol. Three independent Gilbert-Elliott links (two witnesses' and the
standby's own), frames every 0.1 s; a rule says when the silences add up to a takeover.

    python bench/model_combine.py            # 30 % loss in bursts of 8, ~1 min

For each rule: false takeovers per 600 s of a 4-slot swarm with nobody dead (all three
links silent by the rule for 0.2 s more, the claim hold), and the median and 90th
percentile detection time after a crash (from a stationary channel state). "each >= T"
requires every link silent for T; "sum >= S, each >= F" adds the silences (as summing
independent suspicion levels would) with a floor per link.
"""

from __future__ import annotations

import argparse
import random
import statistics
from collections.abc import Callable

Rule = Callable[[list[int]], bool]
"""Silences in frames -> takeover?"""

FRAMES_PER_S = 10
HOLD = 2  # frames: the claim hold


def each(t: int) -> Rule:
    return lambda s: min(s) >= t


def summed(total: int, floor: int) -> Rule:
    return lambda s: min(s) >= floor and sum(s) >= total


class Links:
    def __init__(self, loss: float, burst: float, rng: random.Random) -> None:
        self.to_good, self.to_bad = 1 / burst, loss / (burst * (1 - loss))
        self.rng = rng
        self.bad = [False, False, False]

    def step(self, silence: list[int]) -> None:
        for i, bad in enumerate(self.bad):
            r = self.rng.random()
            self.bad[i] = r >= self.to_good if bad else r < self.to_bad
            silence[i] = silence[i] + 1 if self.bad[i] else 0


def false_takeovers(rule: Rule, loss: float, burst: float, runs: int, seed: int) -> float:
    links, silence = Links(loss, burst, random.Random(seed)), [0, 0, 0]
    count = held = 0
    for _ in range(runs * 600 * FRAMES_PER_S * 4):
        links.step(silence)
        held = held + 1 if rule(silence) else 0
        count += held == HOLD
    return count / runs


def detection(rule: Rule, loss: float, burst: float, crashes: int,
              seed: int) -> tuple[float, float]:
    rng, times = random.Random(seed), []
    for _ in range(crashes):
        links, silence = Links(loss, burst, rng), [0, 0, 0]
        for _ in range(300):
            links.step(silence)
        t = 0
        while not rule(silence):
            silence = [x + 1 for x in silence]
            t += 1
        times.append(t / FRAMES_PER_S)
    times.sort()
    return statistics.median(times), times[int(0.9 * len(times))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loss", type=float, default=0.3)
    ap.add_argument("--burst", type=float, default=8.0)
    ap.add_argument("--runs", type=int, default=10, help="600-s runs per rule")
    args = ap.parse_args()
    rules = {"each >= 1.7 s": each(17), "each >= 2.0 s": each(20),
             "sum >= 5.1 s, each >= 1.2 s": summed(51, 12),
             "sum >= 5.1 s, each >= 1.5 s": summed(51, 15),
             "sum >= 5.4 s, each >= 1.4 s": summed(54, 14)}
    print(f"{args.loss:.0%} loss in bursts of {args.burst:g}, {args.runs} runs of 600 s")
    for name, rule in rules.items():
        ft = false_takeovers(rule, args.loss, args.burst, args.runs, seed=1)
        med, p90 = detection(rule, args.loss, args.burst, 2000, seed=2)
        print(f"  {name:<28} false takeovers {ft:5.2f} per run, "
              f"detection median {med:.1f} s, p90 {p90:.1f} s", flush=True)


if __name__ == "__main__":
    main()
