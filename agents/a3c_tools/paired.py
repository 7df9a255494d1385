"""Paired comparisons of two lines: the one implementation of pairing, the bootstrap interval and
the verdict, used by the claims page (`thesis_claims`) and by `compare`.

Two sweeps with the same --seed and samples give run i the same sampled values and run seed
(a3c_tools.sweep), so their runs pair up by run_id. The effect is the mean over the paired runs
of (other - base), with a 95% BCa interval from `scipy.stats.bootstrap` (paired resampling of
runs, 10,000 resamples, seed 0). Verdicts, from the interval and the expected direction:

- "better" / "worse": reproduced when the interval lies wholly on the expected side of 0,
  contradicted when it lies wholly on the other side, inconclusive otherwise;
- "comparable": reproduced when the interval lies within +-margin, contradicted when it lies
  wholly outside it, inconclusive otherwise.

An inconclusive verdict states the runs per line that would decide it if the effect and the
spread stayed as measured (the interval narrows as 1 / sqrt(runs)).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import bootstrap

EXPECTS = ("better", "worse", "comparable")
MARGIN = 0.05  # a Catch score difference (success rate) below which two lines are "comparable"
MAX_RUNS = 400  # beyond this many runs per line, more runs at the budget would not decide it
RESAMPLES = 10_000


def read_scores(table: Path, column: str = "score") -> dict[str, float]:
    """run_id -> score of the finished (ok) runs of a sweep's results.csv ({} if there is none):
    the mean of the final 5 evaluations, or with column "score_all" the mean of all of them."""
    if not table.is_file():
        return {}
    with open(table, newline="") as f:
        return {
            row["run_id"]: float(row[column]) for row in csv.DictReader(f) if row["status"] == "ok"
        }


def interval(differences: np.ndarray) -> tuple[float, float]:
    """95% BCa interval of the mean of paired differences, over runs."""
    if np.ptp(differences) == 0:
        return float(differences[0]), float(differences[0])
    result = bootstrap(
        (differences,), np.mean, confidence_level=0.95, n_resamples=RESAMPLES, method="BCa",
        random_state=np.random.default_rng(0),
    )  # fmt: skip
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def verdict(
    expect: str, effect: float, low: float, high: float, runs: int, margin: float = MARGIN
) -> str:
    """The verdict of an interval, and for an inconclusive one the runs that would decide it."""
    if expect in ("better", "worse"):
        sign = 1 if expect == "better" else -1
        side_low, side_high = sorted((sign * low, sign * high))
        if side_low > 0:
            return "reproduced"
        if side_high < 0:
            return "contradicted"
        distance = abs(effect)  # how far the interval's centre is from 0
    else:
        if low >= -margin and high <= margin:
            return "reproduced"
        if low > margin or high < -margin:
            return "contradicted"
        distance = abs(abs(effect) - margin)  # how far the centre is from the margin
    half_width = (high - low) / 2
    if distance == 0 or runs * (half_width / distance) ** 2 > MAX_RUNS:
        return f"inconclusive: more runs at this budget would not decide it (> {MAX_RUNS} per line)"
    needed = math.ceil(runs * (half_width / distance) ** 2)
    return f"inconclusive: about {max(needed, runs + 1)} runs per line would decide it"


@dataclass(frozen=True)
class Paired:
    """Two lines' scores on their paired runs, and the effect of other - base."""

    run_ids: list[str]
    base: np.ndarray
    other: np.ndarray
    effect: float
    low: float
    high: float

    @property
    def runs(self) -> int:
        return len(self.run_ids)

    def shown(self) -> str:
        """The effect with its interval, as the claims page shows it: +0.063 [-0.070, +0.240]."""
        return f"{self.effect:+.3f} [{self.low:+.3f}, {self.high:+.3f}]"

    def verdict(self, expect: str, margin: float = MARGIN) -> str:
        return verdict(expect, self.effect, self.low, self.high, self.runs, margin)


def pair(base: dict[str, float], other: dict[str, float]) -> Paired | None:
    """The runs both lines finished, by run_id (a run missing or failed in either is left out),
    with the effect and its interval; None with fewer than 2 pairs (no interval)."""
    run_ids = sorted(set(base) & set(other))
    if len(run_ids) < 2:
        return None
    b = np.array([base[r] for r in run_ids])
    x = np.array([other[r] for r in run_ids])
    low, high = interval(x - b)
    return Paired(run_ids, b, x, float(np.mean(x - b)), low, high)
