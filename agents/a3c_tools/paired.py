"""Paired comparisons of two lines: the one implementation of pairing, the interval and the
verdict, used by the claims page (`thesis_claims`) and by `compare`.

Two sweeps with the same --seed and samples give run i the same sampled values and run seed
(a3c_tools.sweep), so their runs pair up by run_id. The effect is the mean over the paired runs
of d = other - base, with a Student-t interval on the paired differences: mean(d) +-
t(n - 1) sd(d) / sqrt(n) at 95% (`scipy.stats.t`). Its coverage is exact at every n for normal
differences, and held at 93% or more from 3 pairs up in simulation when the two lines' runs
come from one skewed, bimodal or heavy-tailed distribution (the differences of exchangeable
runs are symmetric; the t interval is conservative for symmetric heavy tails):
tests/test_compare.py simulates Catch-like bimodal, lognormal and t(2) scores at n = 2, 3, 5,
8, 20. A bootstrap interval
does not hold its level at these n: over 2 or 3 runs it is about the spread of the points.
No method holds a mean's coverage for differences that are skewed at so few runs (Bahadur and
Savage 1956); such differences would mean the lines differ, if not in their mean.

Below MIN_PAIRS pairs no interval is given and no verdict: at 2 pairs the t interval is +-12.7
standard errors (and for bimodal scores, such as Catch's learned or not, below its level).
Verdicts, from the interval and the expected direction:

- "better" / "worse": reproduced when the interval lies wholly on the expected side of 0,
  contradicted when it lies wholly on the other side, inconclusive otherwise;
- "comparable": reproduced when the interval lies within +-margin, contradicted when it lies
  wholly outside it, inconclusive otherwise;
- no verdict when every run of both lines is at random play (its score at most RANDOM_SLACK
  above the game's random score, RANDOM_SCORES): neither line learned, so the comparison says
  nothing about learning, whatever the interval.

An inconclusive verdict states the runs per line at which its test would have 80% power
(POWER) if the effect and the spread of the paired differences were as measured, at the level
the verdict is judged at (1 - confidence: 0.05 at 95%, 0.025 at a second look's 97.5%):
`runs_for_power`, from the noncentral t. (`runs_to_decide`, the smallest n whose t(n - 1) sd /
sqrt(n) would just put the interval off 0, is only about 50% power: the campaign's extensions
were sized by it.) `p_value` / `margin_p_value` give the p-value of the test an interval
inverts, and `holm` the adjustment of a family of them (the claims page uses these three).
"""

from __future__ import annotations

import csv
import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3c_tools import ATARI_REPORT_CONFIG, read_toml

EXPECTS = ("better", "worse", "comparable")
MARGIN = 0.05  # a Catch score difference (success rate) below which two lines are "comparable"
MAX_RUNS = 400  # beyond this many runs per line, more runs at the budget would not decide it
CONFIDENCE = 0.95
SECOND_LOOK = 0.975  # a second look at lines extended after an inconclusive first one
MIN_PAIRS = 3  # fewer pairs: no interval, no verdict
POWER = 0.8  # the power an inconclusive verdict's "runs per line" is computed for
CATCH = "Catch-v0"
RANDOM_SCORES = {CATCH: 0.2}  # a uniformly random policy's score; Atari games: atari_report.toml
RANDOM_SLACK = {CATCH: 0.1}  # a run within this of random play has not learned (Atari: 5% of
# the game's human - random range)


def read_rows(out: Path, table: str = "results.csv") -> list[dict]:
    """The rows of a sweep folder's results.csv (or `table`), every status ([] before any)."""
    path = out / table
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def read_scores(table: Path, column: str = "score") -> dict[str, float]:
    """run_id -> score of the finished (ok) runs of a sweep's results.csv ({} if there is none):
    the mean of the final 5 evaluations, or with column "score_all" the mean of all of them."""
    rows = read_rows(table.parent, table.name)
    return {row["run_id"]: float(row[column]) for row in rows if row["status"] == "ok"}


@functools.lru_cache(maxsize=8)
def t_quantiles(confidence: float = CONFIDENCE) -> np.ndarray:
    """The two-sided t quantile at `confidence` for n = 0..MAX_RUNS + 1 pairs (df = n - 1;
    nan below 2 pairs)."""
    from scipy import stats

    n = np.arange(MAX_RUNS + 2)
    q = np.full(n.shape, np.nan)
    q[2:] = stats.t.ppf(0.5 + confidence / 2, n[2:] - 1)
    return q


def t_quantile(runs: int, confidence: float = CONFIDENCE) -> float:
    """The two-sided t quantile at `confidence` for `runs` pairs (df = runs - 1)."""
    if runs <= MAX_RUNS + 1:
        return float(t_quantiles(confidence)[runs])
    from scipy import stats

    return float(stats.t.ppf(0.5 + confidence / 2, runs - 1))


def t_intervals(
    differences: np.ndarray, confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, low, high) of the t interval of the mean of each row of paired differences
    (shape (..., n), n >= 2): vectorised, for one comparison or many."""
    d = np.asarray(differences, dtype=float)
    n = d.shape[-1]
    if n < 2:
        raise ValueError(f"a t interval needs 2 or more differences, got {n}")
    mean = d.mean(axis=-1)
    half = t_quantile(n, confidence) * d.std(axis=-1, ddof=1) / math.sqrt(n)
    return mean, mean - half, mean + half


def interval(differences: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The t interval (95% by default) of the mean of paired differences, over runs."""
    _, low, high = t_intervals(differences, confidence)
    return float(low), float(high)


def runs_to_decide(
    distance: float, half_width: float, runs: int, confidence: float = CONFIDENCE
) -> int | None:
    """The fewest runs per line (more than `runs`) whose interval's half-width, t(n - 1) s /
    sqrt(n) with the spread s measured at `runs`, is below `distance`; None beyond MAX_RUNS.
    About 50% power (the estimate would fall on either side of the edge): the campaign's rule
    sized its extensions by it (results/campaign/plan.toml); `verdict` states `runs_for_power`."""
    if distance <= 0 or runs < 2:
        return None
    spread = half_width * math.sqrt(runs) / t_quantile(runs, confidence)
    n = np.arange(MAX_RUNS + 1)  # up to MAX_RUNS: beyond, "would not decide it"
    with np.errstate(invalid="ignore"):
        fits = (n > runs) & (t_quantiles(confidence)[: MAX_RUNS + 1] * spread
                             / np.sqrt(np.maximum(n, 1)) < distance)  # fmt: skip
    return int(np.argmax(fits)) if fits.any() else None


def decision(expect: str, low: float, high: float, runs: int, margin: float = MARGIN) -> str:
    """The verdict's word of an interval: "reproduced", "contradicted", "inconclusive", or
    "no verdict" below MIN_PAIRS pairs (`verdict` says why, and what would decide it)."""
    if runs < MIN_PAIRS:
        return "no verdict"
    if expect in ("better", "worse"):
        sign = 1 if expect == "better" else -1
        side_low, side_high = sorted((sign * low, sign * high))
        if side_low > 0:
            return "reproduced"
        return "contradicted" if side_high < 0 else "inconclusive"
    if low >= -margin and high <= margin:
        return "reproduced"
    return "contradicted" if low > margin or high < -margin else "inconclusive"


def verdict(
    expect: str,
    effect: float,
    low: float,
    high: float,
    runs: int,
    margin: float = MARGIN,
    confidence: float = CONFIDENCE,
) -> str:
    """The verdict of an interval (`decision`), and for an inconclusive one the runs per line
    for POWER at the interval's level (1 - confidence) if the effect and the spread stayed as
    measured (the spread read back from the interval's half-width); no verdict below MIN_PAIRS
    pairs."""
    word = decision(expect, low, high, runs, margin)
    if word == "no verdict":
        return f"no verdict: {runs} paired runs, fewer than {MIN_PAIRS} give no useful interval"
    if word != "inconclusive":
        return word
    # how far the interval's centre is from 0 (better, worse) or from the margin (comparable)
    directional = expect in ("better", "worse")
    distance = abs(effect) if directional else abs(abs(effect) - margin)
    spread = (high - low) / 2 * math.sqrt(runs) / t_quantile(runs, confidence)
    level = round(1 - confidence, 10)
    needed = runs_for_power(distance, spread, level, POWER)
    if needed is None:
        return (f"inconclusive: no number of runs per line up to {MAX_POWER_RUNS} gives "
                f"{POWER:.0%} power at {level:g} at this effect")  # fmt: skip
    return f"inconclusive: about {needed} runs per line for {POWER:.0%} power at {level:g}"


def p_value(differences: np.ndarray, null: float = 0.0) -> float:
    """The two-sided paired t test's p-value of mean(d) = null over the paired differences: the
    test whose confidence interval `interval` is (p < 1 - confidence exactly when the interval
    excludes `null`). A row of identical differences gives 0 or 1."""
    from scipy import stats

    d = np.asarray(differences, dtype=float)
    n = d.size
    if n < 2:
        raise ValueError(f"a t test needs 2 or more differences, got {n}")
    se = d.std(ddof=1) / math.sqrt(n)
    gap = abs(d.mean() - null)
    if se == 0:
        return 0.0 if gap > 0 else 1.0
    return float(2 * stats.t.sf(gap / se, n - 1))


def margin_p_value(differences: np.ndarray, margin: float = MARGIN) -> float:
    """A "comparable" claim's p-value: the two-sided paired t test of |mean(d)| = margin, dual to
    its verdict rule (the interval at 1 - p just touches the band's edge: p < 1 - confidence
    exactly when the interval lies wholly inside +-margin or wholly outside it)."""
    d = np.asarray(differences, dtype=float)
    edge = margin if d.mean() >= 0 else -margin  # the band's edge nearest the mean
    return p_value(d, edge)


def holm(p_values: list[float]) -> list[float]:
    """Holm's step-down adjusted p-values, in the order given: the k-th smallest of m is
    max over j <= k of min(1, (m - j + 1) p_(j)). Rejecting where adjusted p < alpha keeps the
    chance of any false rejection in the family at most alpha under any dependence between the
    tests (Holm 1979)."""
    m = len(p_values)
    order = sorted(range(m), key=lambda i: p_values[i])
    adjusted, running = [0.0] * m, 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p_values[i]))
        adjusted[i] = running
    return adjusted


MAX_POWER_RUNS = 5000  # beyond this many runs per line, "more than" is said instead


SQRT2 = math.sqrt(2)


def chi_integral(given_w, df: int, points: list[float]) -> float:
    """E[given_w(W)] for W ~ chi(df), the sample spread's law (s = sigma W / sqrt(df)),
    integrated where its density is not negligible, `points` marked for the quadrature."""
    from scipy import integrate, stats

    log_norm = (df / 2 - 1) * math.log(2) + math.lgamma(df / 2)  # chi(df)'s density's

    def weighted(w: float) -> float:
        if w <= 0:
            return 0.0
        return given_w(w) * math.exp((df - 1) * math.log(w) - w * w / 2 - log_norm)

    low, high = stats.chi.ppf(1e-15, df), stats.chi.isf(1e-15, df)
    inside = [min(max(x, low), high) for x in points]
    found = integrate.quad(weighted, low, high, points=inside, limit=200)[0]
    return float(min(max(found, 0.0), 1.0))


def power(effect: float, spread: float, runs: int, alpha: float) -> float:
    """The power of the two-sided paired t test at level `alpha` over `runs` pairs, when the
    differences have mean `effect` and standard deviation `spread`: P(|T| > t(1 - alpha/2,
    n - 1)) with T noncentral t (n - 1 degrees of freedom, noncentrality effect sqrt(n) /
    spread; `scipy.stats.nct`)."""
    from scipy import stats

    if runs < 2:
        return 0.0
    df, shift = runs - 1, effect * math.sqrt(runs) / spread
    q = stats.t.ppf(1 - alpha / 2, df)

    # T = (Z + shift) / (W / sqrt(df)), Z normal, W chi(df): P(|T| > q) given W, with the
    # point where |T| = q at Z = 0 marked for the quadrature. Not scipy's nct, which gives nan
    # or ~0 far out (a large shift at few degrees of freedom, or hundreds of them).
    def given_w(w: float) -> float:  # plain math: scipy's per-call cost, times quad's points
        scale = q * w / math.sqrt(df)
        return 0.5 * (math.erfc((scale - shift) / SQRT2) + math.erfc((scale + shift) / SQRT2))

    return chi_integral(given_w, df, [shift * math.sqrt(df) / q, math.sqrt(df)])


def runs_for_power(effect: float, spread: float, alpha: float, target: float = 0.8) -> int | None:
    """The fewest runs per line (pairs, >= 2) at which the two-sided paired t test at level
    `alpha` has at least `target` power for differences of mean `effect` and standard deviation
    `spread`; None beyond MAX_POWER_RUNS (or for no effect)."""
    if effect == 0 or spread <= 0:
        return None if effect == 0 else 2
    effect = abs(effect)

    def enough(n: int) -> bool:
        return power(effect, spread, n, alpha) >= target

    # Start at the normal approximation's n, ((z(1 - alpha/2) + z(target)) spread / effect)^2,
    # then step: power grows with n, and the t test's n is within a few of it, so a handful of
    # noncentral t evaluations instead of a search's twenty (verdict calls this per row).
    from scipy import stats

    z = stats.norm.ppf(1 - alpha / 2) + stats.norm.ppf(target)
    n = min(max(2, math.ceil((z * spread / effect) ** 2)), MAX_POWER_RUNS)
    while n > 2 and enough(n - 1):
        n -= 1
    while not enough(n):
        if n >= MAX_POWER_RUNS:
            return None
        n += 1
    return n


def equivalence_power(
    effect: float, spread: float, runs: int, alpha: float, margin: float = MARGIN
) -> float:
    """The power of a "comparable" verdict as the page and the study take it: the chance that
    the two-sided (1 - alpha) t interval of the mean over `runs` pairs lies wholly inside
    +-margin (two one-sided tests at alpha / 2 each), when the differences have mean `effect`
    and standard deviation `spread`. `power` of |mean| = margin is not this: at a true 0 it
    counts a rejection at either edge, and the interval must clear both."""
    from scipy import stats

    if runs < 2:
        return 0.0
    df, se = runs - 1, spread / math.sqrt(runs)
    edge = stats.t.ppf(1 - alpha / 2, df)  # the interval's t quantile

    def given_w(w: float) -> float:  # the interval's half-width is edge se w / sqrt(df)
        half = edge * se * w / math.sqrt(df)
        if half >= margin:
            return 0.0
        upper, lower = (margin - half - effect) / se, (-margin + half - effect) / se
        return 0.5 * (math.erfc(-upper / SQRT2) - math.erfc(-lower / SQRT2))

    return chi_integral(given_w, df, [math.sqrt(df), margin * math.sqrt(df) / (edge * se)])


def smallest_effect(spread: float, runs: int, alpha: float, target: float = POWER) -> float:
    """The smallest |effect| that the two-sided paired t test at `alpha` over `runs` pairs
    detects with `target` power at this spread (the power `power` gives grows with it)."""
    from scipy import optimize

    high = spread
    while power(high, spread, runs, alpha) < target:
        high *= 2
    return float(optimize.brentq(lambda e: power(e, spread, runs, alpha) - target, 0, high))


def equivalence_reach(
    spread: float, runs: int, alpha: float, margin: float = MARGIN, target: float = POWER
) -> float | None:
    """The largest true |difference| at which a "comparable" verdict (`equivalence_power`) still
    has `target` power, or None where even a true 0 has less."""
    from scipy import optimize

    if equivalence_power(0.0, spread, runs, alpha, margin) < target:
        return None
    return float(optimize.brentq(
        lambda e: equivalence_power(e, spread, runs, alpha, margin) - target, 0, margin
    ))  # fmt: skip


def equivalence_runs(
    effect: float, spread: float, alpha: float, target: float = POWER, margin: float = MARGIN
) -> int | None:
    """The fewest runs per line at which a "comparable" verdict (`equivalence_power`) has
    `target` power at a true difference `effect`; None beyond MAX_POWER_RUNS."""
    if abs(effect) >= margin:
        return None

    def enough(n: int) -> bool:
        return equivalence_power(effect, spread, n, alpha, margin) >= target

    # from the two-sided test's runs (equivalence needs as many or more), up in steps of 5%,
    # then down to the fewest
    n = max(2, runs_for_power(margin - abs(effect), spread, alpha, target) or MAX_POWER_RUNS)
    while not enough(n):
        if n >= MAX_POWER_RUNS:
            return None
        n = min(MAX_POWER_RUNS, n + max(1, n // 20))
    while n > 2 and enough(n - 1):
        n -= 1
    return n


def spread_interval(
    spread: float, pairs: int, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """The interval of a standard deviation estimated from `pairs` differences (chi-square with
    pairs - 1 degrees of freedom, normal differences): how loosely a pilot's spread holds."""
    from scipy import stats

    df = pairs - 1
    tail = (1 - confidence) / 2
    return (spread * math.sqrt(df / stats.chi2.isf(tail, df)),
            spread * math.sqrt(df / stats.chi2.ppf(tail, df)))  # fmt: skip


def game_of(env_id: str) -> str:
    """The game of an Atari id: "BreakoutNoFrameskip-v4" and "ALE/Breakout-v5" -> "Breakout"."""
    name = env_id.removeprefix("ALE/")
    return re.sub(r"(NoFrameskip|Deterministic)?-v\d+$", "", name)


def random_play(env_id: str) -> tuple[float, float] | None:
    """(random play's score, the slack within which a run has not learned) of an env id: Catch's,
    or an Atari game's from atari_report.toml; None for a game the project has no score for."""
    if env_id in RANDOM_SCORES:
        return RANDOM_SCORES[env_id], RANDOM_SLACK[env_id]
    games = read_toml(ATARI_REPORT_CONFIG)["games"]
    game = games.get(game_of(env_id))
    if game is None:
        return None
    return float(game["random"]), 0.05 * (float(game["human"]) - float(game["random"]))


@dataclass(frozen=True)
class Paired:
    """Two lines' scores on their paired runs, and the effect of other - base with its
    interval at `confidence`."""

    run_ids: list[str]
    base: np.ndarray
    other: np.ndarray
    effect: float
    low: float
    high: float
    confidence: float = CONFIDENCE
    env_id: str = CATCH

    @property
    def runs(self) -> int:
        return len(self.run_ids)

    @property
    def level(self) -> str:
        """The interval's level and method, as "95% t"."""
        return f"{100 * self.confidence:g}% t"

    def shown(self) -> str:
        """The effect with its interval, as the claims page shows it: +0.063 [-0.070, +0.240]
        in Catch score, one decimal in an Atari game's (+12.4 [-3.1, +27.9])."""
        f = ".3f" if self.env_id == CATCH else ".1f"
        return f"{self.effect:+{f}} [{self.low:+{f}}, {self.high:+{f}}]"

    def at_random_play(self) -> str | None:
        """Why neither line learned, when every run of both is at random play; else None."""
        found = random_play(self.env_id)
        if found is None:
            return None
        score, slack = found
        top = max(self.base.max(), self.other.max())
        if top > score + slack:
            return None
        f = ".3f" if self.env_id == CATCH else ".1f"  # as shown() gives the game's scores
        return (
            f"both lines at random play ({self.env_id}: about {score:g}; every run at most "
            f"{top:{f}}, within {slack:{f}} of it), so this says nothing about learning"
        )

    def verdict(self, expect: str, margin: float = MARGIN) -> str:
        why = self.at_random_play()
        if why is not None:
            return f"no verdict: {why}"
        return verdict(expect, self.effect, self.low, self.high, self.runs, margin, self.confidence)


def pair(
    base: dict[str, float],
    other: dict[str, float],
    confidence: float = CONFIDENCE,
    env_id: str = CATCH,
    run_ids: list[str] | None = None,
) -> Paired | None:
    """The runs both lines finished, by run_id (a run missing or failed in either is left out;
    with `run_ids`, only those), with the effect and its interval; None with fewer than
    MIN_PAIRS pairs (no interval)."""
    shared = sorted(set(base) & set(other) & (set(run_ids) if run_ids is not None else set(base)))
    if len(shared) < MIN_PAIRS:
        return None
    b = np.array([base[r] for r in shared])
    x = np.array([other[r] for r in shared])
    low, high = interval(x - b, confidence)
    return Paired(shared, b, x, float(np.mean(x - b)), low, high, confidence, env_id)
