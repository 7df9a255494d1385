"""The confirmatory study read as a referee would: for each primary claim of a plan whose one
look is taken (a3c_tools.confirmatory.outcomes), what its verdict rests on beyond the plan's
rule. The claims page (a3c_tools.thesis_claims) shows these beside the verdicts; nothing here
changes a verdict.

- **Budget.** The steps a run the claim's runs had, against the thesis's (Catch: T_max = 1M;
  Atari: Figure 6.9's 60 epochs of 1M steps).
- **What the data show.** The plan's rule decides a "comparable" claim only when its interval,
  at the Holm-adjusted level, lies inside the band or wholly outside it; a claim left
  inconclusive whose 95% interval lies wholly outside the band is read as *not comparable*, the
  line above (or below) its baseline, with the p-value of a difference from 0: an exploratory
  reading, since that is not the tested hypothesis. Each claim's p-value is labelled with its
  null ("d = 0" for better or worse; for comparable, the band's edge: a small p is evidence of
  being inside the band when the mean is inside it, of being outside when the mean is outside).
- **Power, planned and achieved.** The plan's power; for comparable claims the power of the
  rule the verdict applies (the interval inside the band: two one-sided tests,
  a3c_tools.paired.equivalence_power), which the plan approximated by the two-sided test of the
  nearer edge; the pilot's spread with its 95% interval (chi-square, pairs - 1 degrees of
  freedom); the power at the pilot's own effect. Then, labelled as a sensitivity analysis, the
  power at the study's own spread (the standard deviation of its paired differences), the runs
  per line that spread would have needed, and the smallest effect the study could detect with
  80% power (for comparable claims: the largest true difference at which the verdict still has
  80%).
- **Where the effect lies** (Catch claims): the paired effect by quartile of the learning rate
  (the runs' sampled rates, from the baseline's results.csv), and the pairs at which both lines
  sit at random play (every run within a3c_tools.paired's slack of it) against those where
  either learns, with the 95% interval on the learning pairs alone. Both are exploratory
  splits, chosen after the look.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from a3c_tools.confirmatory import Outcome, catch_pairs, differences, plan_claim
from a3c_tools.paired import (
    CATCH,
    MARGIN,
    equivalence_power,
    equivalence_reach,
    equivalence_runs,
    interval,
    p_value,
    power,
    random_play,
    runs_for_power,
    smallest_effect,
    spread_interval,
)

# the thesis's steps a run: Catch's T_max (its figures' "1 million frames"); an Atari game's,
# Figure 6.9's 60 epochs of 1M steps (the thesis notes read Beam Rider at 60M off it)
THESIS_STEPS = {CATCH: 1_000_000, "Atari": 60_000_000}
FRACTIONS = {1: "the thesis's own", 2: "half the thesis's", 4: "a quarter of the thesis's",
             30: "a thirtieth of the thesis's"}  # fmt: skip


@dataclass(frozen=True)
class Reading:
    """A primary claim at the look, read beyond its verdict (the module docstring)."""

    id: str
    budget: str
    verdict: str  # the plan's rule's
    answer: str  # the verdict, or what the data show where the plan's rule leaves it open
    null: str  # what its p-value tests
    p_zero: float  # the two-sided paired t p-value of a difference of 0
    planned_power: float  # as the plan states it
    rule_power: float  # the plan's spread and effect, under the verdict's own rule
    pilot_pairs: int
    pilot_spread: float
    pilot_spread_interval: tuple[float, float]
    pilot_effect: float
    pilot_power: float  # the plan's spread, at the pilot's own effect
    study_spread: float
    study_power: float  # sensitivity: the planned effect at the study's spread
    study_runs: int | None  # runs per line for the plan's power at the study's spread
    reach: float | None  # smallest effect with 80% (better/worse); comparable: the largest
    # true difference at which the verdict keeps 80%, None where even 0 has less
    testable: bool  # whether the study's spread needed no more runs than the claim's cap
    notes: tuple[str, ...]


def steps_of(claim: dict, plan: dict) -> tuple[str, int]:
    """(game, steps a run) of a claim's test: Catch and its items' total_timesteps, or the
    Atari game and its test's steps."""
    if "atari" in claim["test"]:
        return claim["test"]["game"], int(claim["test"]["steps"])
    items = {item["id"]: item for item in plan.get("item", [])}
    steps = {int(items[i]["total_timesteps"]) for i in claim["items"] if i in items}
    if len(steps) != 1:
        raise ValueError(f"{claim['id']}: its items run {sorted(steps)} steps, not one budget")
    return "Catch", steps.pop()


def budget_text(game: str, steps: int) -> str:
    """ "250,000 steps a run on Catch, a quarter of the thesis's 1M"."""
    thesis = THESIS_STEPS[CATCH if game in (CATCH, "Catch") else "Atari"]
    ratio = thesis / steps
    share = FRACTIONS.get(round(ratio)) if abs(ratio - round(ratio)) < 1e-9 else None
    share = share or f"{steps / thesis:.2g} of the thesis's"
    return f"{steps:,} steps a run on {game.removesuffix('-v0')}, {share} {thesis / 1e6:g}M"


def budget(claim: dict, plan: dict) -> str:
    return budget_text(*steps_of(claim, plan))


def null_of(claim: dict, effect: float) -> str:
    """What a claim's p-value tests, in words."""
    if claim["expect"] != "comparable":
        return "of d = 0"
    edge = f"{MARGIN:+g}" if effect >= 0 else f"{-MARGIN:+g}"
    if abs(effect) < MARGIN:
        return f"of d = {edge} (small: inside the band)"
    return f"of d = {edge} (small: outside the band)"


def answer_of(
    claim: dict,
    outcome: Outcome,
    p_zero: float,
    names: tuple[str, str] = ("its baseline", "the line"),
) -> str:
    """The verdict, or, for a comparable claim the rule leaves inconclusive with its whole 95%
    interval outside the band, what the data show (exploratory); `names`: (baseline, line)."""
    if outcome.verdict != "inconclusive" or claim["expect"] != "comparable":
        return outcome.verdict
    if outcome.low > MARGIN or outcome.high < -MARGIN:
        side = "above" if outcome.effect > 0 else "below"
        return (f"not comparable: {names[1]} scores {side} {names[0]}; its 95% interval lies "
                f"wholly outside the band, p of d = 0: {p_zero:.1g}; an exploratory reading, not "
                "the tested hypothesis")  # fmt: skip
    return outcome.verdict


def by_learning_rate(rates: np.ndarray, d: np.ndarray) -> list[tuple[float, float, int, float]]:
    """The paired effect in each quartile of the learning rate: (lowest rate, highest rate,
    pairs, mean difference), from the lowest rates up."""
    order = np.argsort(rates, kind="stable")
    return [(float(rates[q].min()), float(rates[q].max()), int(q.size), float(d[q].mean()))
            for q in np.array_split(order, 4) if q.size]  # fmt: skip


def floor_split(
    b: np.ndarray, x: np.ndarray, d: np.ndarray, level: float | None = None
) -> tuple[np.ndarray, str] | None:
    """The pairs at which every run of both lines is at random play (a3c_tools.paired's rule),
    and a sentence on them and on the others (with `level`, a comparable claim's, also their
    interval at that level against the band); None where there are none."""
    score, slack = random_play(CATCH)
    floor = (b <= score + slack) & (x.max(axis=0) <= score + slack)
    if not floor.any():
        return None
    learning = d[~floor]
    text = (f"{int(floor.sum())} of its {d.size} pairs have both lines at random play (every "
            f"run at most {score + slack:g}), where the differences' spread is "
            f"{d[floor].std(ddof=1) if floor.sum() > 1 else 0:.3f} against {d.std(ddof=1):.3f} "
            "over all, which narrows the interval")  # fmt: skip
    if learning.size >= 3:
        low, high = interval(learning)
        text += (f"; on the {learning.size} pairs where either line learns: "
                 f"{learning.mean():+.3f} [{low:+.3f}, {high:+.3f}] (95% t)")  # fmt: skip
        if level is not None:
            low, high = interval(learning, 1 - level)
            inside = "inside" if low >= -MARGIN and high <= MARGIN else "not inside"
            text += (f", and at the claim's level ({1 - level:.1%}) [{low:+.3f}, {high:+.3f}], "
                     f"{inside} the band")  # fmt: skip
    return floor, text


def catch_notes(claim: dict, level: float) -> list[str]:
    """Where a Catch claim's effect lies: by learning-rate quartile, and off the floor."""
    rates, b, x, d = catch_pairs({**claim["test"], "runs": claim["runs"]})
    notes = []
    if not np.isnan(rates).any():  # (a line swept over no learning rate has none)
        quartiles = ", ".join(f"{mean:+.3f} ({low:.0e}-{high:.0e}, n = {n})"
                              for low, high, n, mean in by_learning_rate(rates, d))  # fmt: skip
        notes.append(f"the effect by learning-rate quartile, lowest first: {quartiles}")
    split = floor_split(b, x, d, level if claim["expect"] == "comparable" else None)
    if split is not None:
        notes.append(split[1])
    return notes


def read(
    claim: dict,
    outcome: Outcome,
    plan: dict,
    extra: tuple[str, ...] = (),
    names: tuple[str, str] = ("its baseline", "the line"),
) -> Reading:
    """One primary claim, read (the module docstring); `extra` notes are appended, `names` are
    its (baseline, line) in words."""
    claims, study = plan["claim"], plan["study"]
    planned = plan_claim(claim, len(claims), study)
    d = differences({**claim["test"], "runs": claim["runs"]})
    pilot = differences(claim["spread_from"])
    comparable = claim["expect"] == "comparable"
    effect, level, runs = float(claim["effect"]), planned.level, int(claim["runs"])
    study_spread = float(d.std(ddof=1))
    p_zero = p_value(d)
    if comparable:
        rule = equivalence_power(effect, planned.spread, runs, level)
        at_pilot = equivalence_power(float(pilot.mean()), planned.spread, runs, level)
        at_study = equivalence_power(effect, study_spread, runs, level)
        reach = equivalence_reach(study_spread, runs, level)
        needed = equivalence_runs(effect, study_spread, level, study["power"])
    else:
        rule = power(abs(effect), planned.spread, runs, level)
        at_pilot = power(abs(float(pilot.mean())), planned.spread, runs, level)
        at_study = power(abs(effect), study_spread, runs, level)
        reach = smallest_effect(study_spread, runs, level)
        needed = runs_for_power(abs(effect), study_spread, level, study["power"])
    notes = [] if "atari" in claim["test"] else catch_notes(claim, level)
    cap = int(claim.get("max_runs", study["max_runs"]))
    testable = needed is not None and needed <= cap
    if not testable and outcome.verdict in ("reproduced", "contradicted"):
        times = abs(outcome.effect / effect) if effect else math.inf
        notes.insert(0, (
            f"at the study's own spread ({study_spread:.3g}, against the plan's "
            f"{planned.spread:.3g}) "
            f"its test had {shown_fraction(at_study)} power and would have needed "
            f"{'more than 5,000' if needed is None else f'{needed:,}'} runs per line, past its "
            f"cap of {cap}: by the rule that left the not-testable claims out, it was not "
            f"testable; it is decided only because its effect ({outcome.effect:+.3g}) is "
            f"{times:.0f} times the planned one ({effect:+g})"
        ))  # fmt: skip
    return Reading(
        id=claim["id"], budget=budget(claim, plan), verdict=outcome.verdict,
        answer=answer_of(claim, outcome, p_zero, names),
        null=null_of(claim, outcome.effect), p_zero=p_zero,
        planned_power=float(claim["power"]), rule_power=rule, pilot_pairs=int(pilot.size),
        pilot_spread=planned.spread,
        pilot_spread_interval=spread_interval(planned.spread, int(pilot.size)),
        pilot_effect=float(pilot.mean()), pilot_power=at_pilot, study_spread=study_spread,
        study_power=at_study, study_runs=needed, reach=reach, testable=testable,
        notes=(*notes, *extra),
    )  # fmt: skip


def readings(
    plan: dict,
    found: list[Outcome],
    notes: dict[str, str] | None = None,
    names: dict[str, list[str]] | None = None,
) -> list[Reading]:
    """Every primary claim of a looked-at plan, read; `notes` (claim id -> text) are added to
    their claims' notes (the claims file's caveats: hosts, pilots' precision), `names` (claim
    id -> [baseline, line]) name their lines."""
    notes, names = notes or {}, names or {}
    return [
        read(claim, outcome, plan, tuple(n for n in [notes.get(claim["id"])] if n),
             tuple(names.get(claim["id"], ("its baseline", "the line"))))
        for claim, outcome in zip(plan["claim"], found, strict=True)
    ]  # fmt: skip


def power_table(found: list[Reading], plan: dict) -> list[str]:
    """The page's table of each claim's power, planned and achieved (Markdown rows)."""
    target = f"{plan['study']['power']:.0%}"
    out = ["| id | p tests | pilot: pairs, spread [95%], effect | planned power "
           "(plan; under the verdict's rule) | at the pilot's effect | *sensitivity*: power at "
           f"the study's spread (its runs for {target}) | *sensitivity*: smallest effect with "
           f"{target} (comparable: largest difference kept) |",
           "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in found:
        f = ".3f" if "Catch" in r.budget else ".2f"
        low, high = r.pilot_spread_interval
        needed = "more than 5,000" if r.study_runs is None else f"{r.study_runs:,}"
        reach = "none: even a true 0 has less" if r.reach is None else f"{r.reach:{f}}"
        cells = [r.id, r.null,
                 f"{r.pilot_pairs}, {r.pilot_spread:{f}} [{low:{f}}, {high:{f}}], "
                 f"{r.pilot_effect:+{f}}",
                 f"{shown_fraction(r.planned_power)}; {shown_fraction(r.rule_power)}",
                 shown_fraction(r.pilot_power),
                 f"{shown_fraction(r.study_power)} at {r.study_spread:{f}} ({needed})",
                 reach]  # fmt: skip
        out.append("| " + " | ".join(cells) + " |")
    return out


def shown_fraction(value: float) -> str:
    return f"{value:.0%}" if value >= 0.01 or value == 0 else f"{value:.1%}"
