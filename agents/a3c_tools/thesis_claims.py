"""The thesis's claims, each with our evidence, an interval and a verdict: docs/claims.md, which
opens with a forest plot of the rows, docs/img/claims_forest.png.

    python -m a3c_tools.thesis_claims                  # print the page (no figure)
    python -m a3c_tools.thesis_claims -o docs/claims.md        # the page and its figure
    python -m a3c_tools.thesis_claims --check docs/claims.md   # exit 1 if either is stale

The claims are in agents/a3c_tools/thesis_claims.toml. A claim compares two lines of the same sweep
design (the same learning rates and run seeds, so runs pair up by run_id): each line's
results.csv, committed under results/, gives one score per run (the mean of its final 5
evaluations). The pairing, the effect with its t interval and the verdict are
a3c_tools.paired's (its docstring gives the rules), which `a3c_tools.compare` uses too. A claim
whose lines have not been run yet gets no interval: the row says what would decide it.

An Atari row compares two lines of one of the thesis's Atari figures on one game (the claim's
`atari`: the figure's folder under results/atari_figures, the game, the steps and seeds of the
campaign's item that runs them): each seed's final evaluation, read from the figure's
results.csv that `a3c_tools.atari_figures --plot-only` writes, paired by seed, with the same t
interval (95%, n - 1 degrees of freedom: at 3 seeds t = 4.30, so only a large, consistent
effect is decided). Until both lines hold every seed at the full steps, the row keeps what it
said before (`ours`, `verdict`) and names the campaign item. Its effect is in the game's score,
so the forest plot, in Catch score, leaves it off (the caption counts it). An Atari row of one
line (no `baseline`, `expect = "random play"`: Figure 6.10's "no learning at all") is judged
seed by seed against random play, with no interval (`atari_line_evidence`).

Looks. A row rests on a fixed set of runs: its first look, runs 0..runs-1 of both lines (the
claim's `runs`, FIRST_LOOK by default), made once both lines hold them all (until then the row
is "not run yet": no verdict from a peek at fewer), whatever else its lines hold (a line shared
with a row that is extended grows, and the rows that are not extended must not gain pairs from
it). A row extended because its first look was inconclusive (the claim's `extend`: N runs, and
the second look's folders where they are new ones) is judged at its second look, runs 0..N-1,
once both lines hold N runs, with a SECOND_LOOK (97.5%) interval, and shows the first look's 95%
interval beside it; until then it keeps the first look's verdict and says the extension is in
progress. Two looks at 95% each would give a row with no effect a directional verdict more often
than 5%; at 95% then 97.5% the chance is at most 5% + 2.5% (the page states the rule, and
tests/test_thesis_claims.py simulates it).

Across the page (`judge`). Every row with an interval has a p-value, that of the two-sided
paired t test its interval inverts (`look_p`; an extended row's two looks made one level-5% test,
`row_p`), and Holm's adjusted p-value over the page's family of tests (`a3c_tools.paired.holm`);
its verdict is taken at the adjusted level (ALPHA), and an inconclusive row gives the runs per
line for 80% power at Holm's first level (`a3c_tools.paired.runs_for_power`). A row keeps its
`history` (required: `check_rows` refuses a row without it), may re-use another row's runs
(`same_runs_as`: not counted again in the tally, and a repeated test counted once in the
family), may be struck (`defect`: no verdict until its runs are made again) or marked
(`mixed_precision`). The page opens with chapter 8's conclusions (`[[conclusion]]`, each
verdict combined from its rows, and each primary claim's verdict once the study is looked at),
then the confirmatory study's primary claims (read from results/confirmatory/plan.toml; after
its one look, their tally, and each claim read as a referee would: its budget, its power planned
and achieved, where its effect lies, what its data show where the plan's rule leaves it open,
a3c_tools.study_reading), then the next study (results/confirmatory_1m/plan.toml, planned until
its look), then every row, exploratory, then the method. A conclusion's answer is its primary
claims' (`conclusions`), or its rows' where the study does not test it.

The forest plot opens, once the confirmatory study's one look is taken, with its Catch claims
(`study_points`), then has one row per claim with an interval (the paired mean effect as a dot, the
interval that gives its verdict as a bar, coloured by verdict, grouped by the page's sections);
the rows without one are left off, and the caption under it counts them. It lives at
img/claims_forest.png beside the page (`-o docs/claims.md` writes docs/img/claims_forest.png),
which the page links. The numbers drawn, each row's section, label, effect, interval, verdict
and colour, are written into the PNG itself (its "Description" text chunk, as JSON), and
`--check` compares those with what would be drawn now: the check is of the data, not of the
pixels, which differ between matplotlib versions.
"""

from __future__ import annotations

import json
import re
import sys
from collections import Counter
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from a3c_tools import read_toml, run_main, tool_parser

if TYPE_CHECKING:  # the functions below import a3c_tools.confirmatory where they use it
    from a3c_tools.confirmatory import Outcome
    from a3c_tools.study_reading import Reading
from a3c_tools.atari_figures import EVAL_EPISODES, SEED
from a3c_tools.paired import (
    MARGIN,
    MAX_POWER_RUNS,
    SECOND_LOOK,
    Paired,
    holm,
    margin_p_value,
    p_value,
    pair,
    random_play,
    read_rows,
    read_scores,
    runs_for_power,
)

ROOT = Path(__file__).resolve().parents[2]  # the repository
CLAIMS = Path(__file__).with_name("thesis_claims.toml")
FIGURE = Path("img/claims_forest.png")  # the forest plot, relative to the page
CONFIRMATORY = ROOT / "results" / "confirmatory" / "plan.toml"  # the pre-registered study
# the next study, planned before any of its runs: the thesis's own budget (1M steps a Catch run)
CONFIRMATORY_NEXT = ROOT / "results" / "confirmatory_1m" / "plan.toml"
ALPHA = 0.05  # the page's family-wise level: a verdict needs its Holm-adjusted p below it
POWER = 0.8  # the power an inconclusive row's "runs per line" is computed for
REQUIRED = ("id", "claim", "where", "form", "thesis", "history")  # every row's fields


def scores(folder: str, column: str = "score") -> dict[str, float]:
    """run_id -> score of the finished runs in the committed folder's results.csv."""
    return read_scores(ROOT / folder / "results.csv", column)


FIRST_LOOK = 8  # a Catch row's runs per line where its claim names no `runs`


def run_ids(runs: int) -> list[str]:
    """The run ids of a sweep's runs 0..runs-1."""
    return [f"run-{i:04d}" for i in range(runs)]


def finished(folder: str, runs: int) -> bool:
    """Whether the committed folder's results.csv holds runs 0..runs-1 (ok or failed)."""
    return set(run_ids(runs)) <= {row["run_id"] for row in read_rows(ROOT / folder)}


@dataclass(frozen=True)
class Looks:
    """A pair row's evidence: its first look (runs 0..first-1 of both lines, 95%) and, for a row
    extended after it, the second look (runs 0..N-1, at SECOND_LOOK) once both lines hold N
    runs. `decisive` is the look whose verdict the row takes."""

    first: Paired | None
    second: Paired | None
    extension: int | None  # the second look's N, for an extended row

    @property
    def decisive(self) -> Paired | None:
        return self.second if self.second is not None else self.first

    def verdict(self, expect: str) -> str:
        if self.decisive is None:
            return "not run yet"
        call = self.decisive.verdict(expect)
        if self.extension is not None and self.second is None:
            call += f"; extension to {self.extension} runs (the plan's N) in progress (campaign)"
        return call

    def shown(self) -> str:
        """The effect with its interval; for a row with a second look, both looks."""
        if self.second is None:
            return self.first.shown() if self.first is not None else "-"
        first = (
            f"; first look (n = {self.first.runs}, {self.first.level}): {self.first.shown()}"
            if self.first is not None
            else ""
        )
        return f"{self.second.shown()} (n = {self.second.runs}, {self.second.level}){first}"


def atari_scores(atari: dict, line: str) -> dict[str, float]:
    """run_id -> the final evaluation of an Atari line's runs that reached the row's steps, from
    its figure's results.csv (`a3c_tools.atari_figures ... --plot-only` writes it; run i has seed
    SEED + 1000 i); a run still in progress is left out ({} before any is drawn)."""
    return {
        f"run-{(int(row['seed']) - SEED) // 1000:04d}": float(row["final_score"])
        for row in read_rows(ROOT / atari["figure"])
        if row["game"] == atari["game"]
        and row["line"] == line
        and int(row["final_step"]) >= atari["steps"]
    }


def compared(claim: dict) -> Looks | None:
    """The claim's two lines paired by run_id, each look with its effect and interval; None for
    a claim judged without a pair of lines. A row rests on exactly its first look's runs (runs
    0..runs-1) until its extension's lines both hold `extend.runs`, whatever else its lines
    (shared with other rows) hold. An Atari row rests on its `seeds` seeds, paired by seed."""
    if "baseline" not in claim:
        return None
    if "atari" in claim:
        atari = claim["atari"]
        if claim["expect"] not in ("better", "worse"):
            raise ValueError(f"an Atari row is better or worse, not {claim['expect']!r}")
        first = pair(
            atari_scores(atari, claim["baseline"]), atari_scores(atari, claim["line"]),
            env_id=f"{atari['game']}NoFrameskip-v4", run_ids=run_ids(atari["seeds"]),
        )  # fmt: skip
        if first is not None and first.runs < atari["seeds"]:  # judged on every seed or none
            first = None
        return Looks(first, None, None)
    column = claim.get("score", "score")
    first_runs = claim.get("runs", FIRST_LOOK)
    first = None
    # the one look at the runs the row names, once both lines hold them all: no look before
    if all(finished(folder, first_runs) for folder in (claim["baseline"], claim["line"])):
        first = pair(
            scores(claim["baseline"], column), scores(claim["line"], column),
            run_ids=run_ids(first_runs),
        )  # fmt: skip
    extend = claim.get("extend")
    if extend is None:
        return Looks(first, None, None)
    n = extend["runs"]
    folders = (extend.get("baseline", claim["baseline"]), extend.get("line", claim["line"]))
    second = None
    if all(finished(folder, n) for folder in folders):
        second = pair(
            *(scores(folder, column) for folder in folders),
            confidence=SECOND_LOOK, run_ids=run_ids(n),
        )  # fmt: skip
    return Looks(first, second, n)


def evidence(claim: dict) -> tuple[str, str, str]:
    """(our numbers, the effect with its interval, the verdict) of one claim."""
    if "atari" in claim and "baseline" not in claim:
        return atari_line_evidence(claim)
    if "baseline" not in claim:
        return claim["ours"], "-", claim["verdict"]
    column = claim.get("score", "score")
    looks = compared(claim)
    paired = looks.decisive
    if "atari" in claim:
        return atari_evidence(claim, paired)
    if paired is None:  # the command goes to the page's list of what is missing
        return "not run yet (the command is in the last section)", "-", "not run yet"
    names = claim.get("names", ["baseline", "line"])
    extend = claim.get("extend", {})
    folders = (extend.get("baseline", claim["baseline"]), extend.get("line", claim["line"]))
    if looks.second is None:
        folders = (claim["baseline"], claim["line"])
    ours = (
        f"{names[1]} {paired.other.mean():.3f} vs {names[0]} {paired.base.mean():.3f}"
        + (" (the mean over all evaluations)" if column == "score_all" else "")
        + f" (n = {paired.runs} paired "
        f"runs; [{folders[1]}]({link(folders[1])}), [{folders[0]}]"
        f"({link(folders[0])}))"
    )
    return ours, looks.shown(), looks.verdict(claim["expect"])


def atari_evidence(claim: dict, paired: Paired | None) -> tuple[str, str, str]:
    """(our numbers, the effect with its interval, the verdict) of an Atari row: its seeds'
    final evaluations paired by seed, or, until every seed of both lines is done, what the row
    said before (`ours`, `verdict`) or "not run yet", and the campaign item that runs it."""
    atari = claim["atari"]
    if paired is None:
        return atari_unfinished(claim)
    names = claim["names"]
    seeds = ", ".join(
        f"{other:.1f} vs {base:.1f}" for other, base in zip(paired.other, paired.base, strict=True)
    )
    ours = (
        f"{names[1]} {paired.other.mean():.1f} vs {names[0]} {paired.base.mean():.1f}: the "
        f"final evaluation at {atari['steps'] / 1e6:g}M steps ({EVAL_EPISODES} episodes), the "
        f"mean of {paired.runs} seeds paired by seed (seeds {SEED}, {SEED + 1000}, ...: {seeds}; "
        f"[{atari['figure']}]({link(atari['figure'])}))"
    )
    return ours, paired.shown(), paired.verdict(claim["expect"])


def atari_unfinished(claim: dict) -> tuple[str, str, str]:
    """An Atari row whose runs are not all done: what it said before (`ours`, `verdict`) or "not
    run yet", and the campaign item that runs it."""
    atari = claim["atari"]
    todo = (
        f"{atari['seeds']} seeds x {atari['steps'] / 1e6:g}M steps per line: campaign item "
        f"{atari['item']}, not finished"
    )
    if "ours" in claim:
        return claim["ours"], "-", f"{claim['verdict']}; {todo}"
    return f"not run yet ({todo}; the command is in the last section)", "-", "not run yet"


def atari_line_evidence(claim: dict) -> tuple[str, str, str]:
    """(our numbers, "-", the verdict) of an Atari row about one line alone, that none of its
    runs leaves random play (`expect = "random play"`): each seed's final evaluation against the
    game's random play, a run more than the slack above it (5% of the human - random range,
    a3c_tools.paired's rule) having learned. Reproduced when no seed learned, contradicted when
    any did; no interval, the claim being of every run and not of a mean."""
    atari, line = claim["atari"], claim["line"]
    if claim["expect"] != "random play":
        raise ValueError(f"an Atari row of one line expects random play, not {claim['expect']!r}")
    found = atari_scores(atari, line)
    ids = run_ids(atari["seeds"])
    if not set(ids) <= set(found):  # judged on every seed or none
        return atari_unfinished(claim)
    at_random = random_play(f"{atari['game']}NoFrameskip-v4")
    if at_random is None:
        raise ValueError(f"no random and human scores for {atari['game']} in atari_report.toml")
    random, slack = at_random
    finals = [found[run_id] for run_id in ids]
    learned = sum(final > random + slack for final in finals)
    ours = (
        f"{claim['names'][0]}: the final evaluation at {atari['steps'] / 1e6:g}M steps "
        f"({EVAL_EPISODES} episodes) of seeds {SEED}, {SEED + 1000}, ...: "
        f"{', '.join(f'{final:.1f}' for final in finals)}; a run above {random + slack:.2f} "
        f"(random play, {random:g}, plus 5% of the human - random range) has left random play "
        f"([{atari['figure']}]({link(atari['figure'])}))"
    )
    if learned == 0:
        return ours, "-", f"reproduced: none of the {len(finals)} seeds left random play"
    return ours, "-", f"contradicted: {learned} of {len(finals)} seeds left random play"


def look_p(paired: Paired, expect: str) -> float:
    """One look's p-value: the two-sided paired t test that its interval inverts (of 0 for
    "better" / "worse", of |effect| = MARGIN for "comparable")."""
    differences = paired.other - paired.base
    if expect == "comparable":
        return margin_p_value(differences)
    return p_value(differences)


def row_p(looks: Looks, expect: str) -> float | None:
    """A row's p-value. One look: its look's. An extended row's two looks (95%, then 97.5%: at
    most 7.5% together) scaled to one level-5% test by Bonferroni over its looks, 1.5 min(p1,
    2 p2): rejecting below alpha means p1 < alpha / 1.5 or p2 < alpha / 3."""
    if looks.decisive is None:
        return None
    first = look_p(looks.first, expect) if looks.first is not None else 1.0
    if looks.extension is None:
        return first
    second = look_p(looks.second, expect) if looks.second is not None else 0.5
    return min(1.0, 1.5 * min(first, 2 * second))


@dataclass(frozen=True)
class Judged:
    """One row of the page as judged across the page: its evidence, its p-value and Holm's
    adjusted one (None without an interval), the verdict at the adjusted level, and what its
    interval alone (at its own level) would have said."""

    claim: dict
    section: str
    ours: str
    effect: str
    p: float | None
    adjusted: float | None
    verdict: str
    alone: str  # the verdict's head at the row's own level, before the adjustment


def ids_of(claim: dict) -> list[str]:
    """The rows whose runs a row re-uses (its `same_runs_as`: one id or a list)."""
    same = claim.get("same_runs_as", [])
    return [same] if isinstance(same, str) else list(same)


def same_test(claim: dict, other: dict) -> bool:
    """Whether a row re-uses another's runs for the very same test (same lines, same score)."""
    keys = ("baseline", "line", "score", "atari", "expect")
    return all(claim.get(key) == other.get(key) for key in keys)


def check_rows(claims: dict) -> dict[str, dict]:
    """id -> claim, after checking that every row has its required fields (its history
    included: a row's history cannot be dropped in an edit) and that the ids it names exist."""
    rows: dict[str, dict] = {}
    for section in claims["section"]:
        for claim in section["claim"]:
            missing = [field for field in REQUIRED if not str(claim.get(field, "")).strip()]
            if missing:
                where = claim.get("id") or claim.get("where") or "a row"
                raise ValueError(f"{where} in {CLAIMS.name} has no {', '.join(missing)}")
            if claim["id"] in rows:
                raise ValueError(f"row id {claim['id']!r} repeats in {CLAIMS.name}")
            rows[claim["id"]] = claim
    for claim in rows.values():
        for other in ids_of(claim):
            if other not in rows:
                raise ValueError(f"{claim['id']}: same_runs_as names no row {other!r}")
    return rows


def distance(paired: Paired, expect: str) -> float:
    """How far a row's effect is from deciding it: from 0, or for "comparable" from the band's
    edge."""
    return abs(abs(paired.effect) - MARGIN) if expect == "comparable" else abs(paired.effect)


def power_note(paired: Paired, expect: str, level: float) -> str:
    """The runs per line at which the row's test has 80% power at the page's level, if its
    effect and spread stayed as measured."""
    spread = float((paired.other - paired.base).std(ddof=1))
    needed = runs_for_power(distance(paired, expect), spread, level, POWER)
    if needed is None:
        return f"no number of runs per line gives {POWER:.0%} power at {level:.2g} at this effect"
    return f"about {needed} runs per line for {POWER:.0%} power at {level:.2g}"


def combine(heads: list[str]) -> str:
    """A conclusion's verdict from its rows' verdicts (their first words)."""
    if not heads:
        return "untested"
    decided = {head for head in heads if head in ("reproduced", "contradicted")}
    if decided == {"reproduced", "contradicted"}:
        return "mixed"
    if decided:
        [head] = decided
        return head if all(h == head for h in heads) else f"partly {head}"
    return "no verdict" if all(h == "no verdict" for h in heads) else "inconclusive"


def judge(claims: dict) -> list[Judged]:
    """Every row of the page, judged across the page: each row with an interval gets its
    p-value and Holm's adjusted p-value over the family of the page's tests (every row with an
    interval, a row that repeats another's very test counted once), and its verdict at the
    adjusted level (ALPHA); a row whose runs had a known defect (`defect`) gets none."""
    rows = check_rows(claims)
    entries = []
    for section in claims["section"]:
        for claim in section["claim"]:
            looks = compared(claim)
            paired = looks.decisive if looks is not None else None
            p = row_p(looks, claim["expect"]) if paired is not None else None
            entries.append((section["title"], claim, looks, paired, p, evidence(claim)))
    family = [i for i, (_, claim, _, _, p, _) in enumerate(entries) if p is not None
              and not any(same_test(claim, rows[other]) for other in ids_of(claim))]  # fmt: skip
    adjusted = dict(zip(family, holm([entries[i][4] for i in family]), strict=True))
    index = {claim["id"]: i for i, (_, claim, *_) in enumerate(entries)}
    level = ALPHA / max(len(family), 1)  # Holm's first step: the level a new look must meet
    judged: list[Judged] = []
    for i, (title, claim, looks, paired, p, (ours, effect, own)) in enumerate(entries):
        twin = next((index[o] for o in ids_of(claim) if same_test(claim, rows[o])), None)
        adj = adjusted.get(i, adjusted.get(twin) if twin is not None else None)
        alone, verdict = head_of(own), own
        if "defect" in claim:
            verdict = f"no verdict: runs had a known defect ({claim['defect']})"
        elif adj is not None and not alone.startswith("no verdict"):
            expect = claim["expect"]
            if adj < ALPHA:
                if expect == "comparable":
                    verdict = "reproduced" if abs(paired.effect) < MARGIN else "contradicted"
                else:
                    sign = 1 if expect == "better" else -1
                    verdict = "reproduced" if sign * paired.effect > 0 else "contradicted"
            else:
                verdict = "inconclusive: "
                if alone in ("reproduced", "contradicted"):
                    verdict += f"{alone} by its interval alone, not after Holm; "
                verdict += power_note(paired, expect, level)
            if looks.extension is not None and looks.second is None:
                verdict += f"; extension to {looks.extension} runs in progress (campaign)"
        judged.append(Judged(claim, title, ours, effect, p, adj, verdict, alone))
    for i, row in enumerate(judged):  # a judgement over other rows, once they are judged
        if "baseline" not in row.claim and ids_of(row.claim):
            heads = [head_of(judged[index[o]].verdict) for o in ids_of(row.claim)]
            verdict = f"{combine(heads)}: from rows {', '.join(ids_of(row.claim))}"
            judged[i] = replace(row, verdict=verdict)
    return judged


def repeats(j: Judged, judged: list[Judged]) -> bool:
    """Whether the row re-uses the runs of a row it names for the very same test (same_test)."""
    return any(same_test(j.claim, o.claim) for o in judged if o.claim["id"] in ids_of(j.claim))


def family_size(judged: list[Judged]) -> int:
    """The number of tests Holm's adjustment runs over."""
    return sum(j.p is not None and not repeats(j, judged) for j in judged)


def chance_verdicts(judged: list[Judged]) -> float:
    """The directional verdicts expected by chance alone, were no line different from its
    baseline: each directional test's level (5%; 7.5% for an extended row's two looks)."""
    return sum((0.075 if "extend" in j.claim else 0.05 for j in judged if j.p is not None
                and j.claim["expect"] != "comparable" and not repeats(j, judged)), 0.0)  # fmt: skip


def shown_p(p: float | None) -> str:
    """A p-value as the page shows it: 2 significant digits, '< 0.0001' below."""
    if p is None:
        return "-"
    return "< 0.0001" if p < 0.0001 else f"{p:.2g}"


def link(folder: str) -> str:
    """A docs-relative link to a results folder's results.csv."""
    return f"../{folder}/results.csv"


# the tally's order
VERDICTS = ("reproduced", "contradicted", "inconclusive", "no verdict", "not run yet")


def head_of(call: str) -> str:
    """A verdict's first word(s): "inconclusive" of "inconclusive: about 11 runs ...", "reproduced"
    of "reproduced; extension to 11 runs (the plan's N) in progress (campaign)"."""
    return re.split(r"[:;]", call, maxsplit=1)[0]


def tally(judged: list[Judged]) -> str:
    """How many experiments have each verdict (a row that re-uses another row's runs is not
    counted again): "**At a glance**: 3 experiments: 2 reproduced, 1 ..., in 4 rows (...)"."""
    counted = [j for j in judged if not ids_of(j.claim)]
    counts = Counter(head_of(j.verdict) for j in counted)
    heads = [*VERDICTS, *sorted(set(counts) - set(VERDICTS))]
    parts = ", ".join(f"{counts[head]} {head}" for head in heads if counts[head])
    again = [j.claim["id"] for j in judged if ids_of(j.claim)]
    text = f"**At a glance**: {len(counted)} experiments: {parts}, in {len(judged)} rows"
    if again:
        text += f" ({len(again)} re-use another row's runs and are not counted again: "
        text += ", ".join(again) + ")"
    budgets = Counter(row_steps(j.claim) for j in judged)
    shown = [f"{steps:,} on {game} ({count})" for (game, steps), count in
             sorted(budgets.items(), key=lambda b: (b[0][0] != "Catch", b[0][1]))
             if game]  # fmt: skip
    if shown:
        text += (f"; steps a run (rows): {', '.join(shown)}, where the thesis's runs were 1M "
                 "on Catch and 60M on Atari")  # fmt: skip
    return text + "."


def row_steps(claim: dict) -> tuple[str, int]:
    """(game, steps a run) of a row's runs: an Atari row's steps; a Catch row's, its lines'
    longest finished run (to the 1,000); ("", 0) for a row with no lines of its own."""
    if "atari" in claim:
        return claim["atari"]["game"], int(claim["atari"]["steps"])
    steps = [int(row["final_step"]) for key in ("baseline", "line") if key in claim
             for row in read_rows(ROOT / claim[key])
             if row.get("status") == "ok" and row.get("final_step")]  # fmt: skip
    return ("Catch", round(max(steps), -3)) if steps else ("", 0)


def multiplicity(judged: list[Judged]) -> str:
    """The lead's sentence on multiplicity: the tests, what chance alone would give, and which
    verdicts survive Holm's adjustment."""
    size = family_size(judged)
    decided = [j for j in judged if j.adjusted is not None
               and head_of(j.verdict) in ("reproduced", "contradicted")]  # fmt: skip
    alone = [j for j in judged if j.adjusted is not None and not repeats(j, judged)
             and j.alone in ("reproduced", "contradicted")]  # fmt: skip
    survive = (", ".join(f"{j.claim['id']} ({head_of(j.verdict)})" for j in decided)
               if decided else "none")  # fmt: skip
    struck = [j.claim["id"] for j in judged if "defect" in j.claim and j.adjusted is not None
              and j.adjusted < ALPHA]  # fmt: skip
    if struck:
        survive += (
            f"; {len(struck)} more would ({', '.join(struck)}) but "
            f"{'is' if len(struck) == 1 else 'are'} struck for a known defect"
        )
    survives = "verdict survives" if len(decided) == 1 else "verdicts survive"
    return (
        f"**Multiplicity.** The page makes {size} tests (one per row with an interval, a row "
        f"that repeats another's very test counted once). Were no line different from its "
        f"baseline anywhere, chance alone would give about {chance_verdicts(judged):.1f} "
        f"directional verdicts among them at each row's own level. {len(alone)} rows are "
        f"decided by their own interval; adjusted across the page by Holm's method (family-wise "
        f"error at most {ALPHA:g}), {len(decided)} {survives}: {survive}. The verdicts "
        "below are the adjusted ones; each row still shows its unadjusted 95% interval."
    )


def conclusions(claims: dict, judged: list[Judged], plan_path: Path | None = None) -> list[str]:
    """The page's opening table: one answer per conclusion of chapter 8, at its budget: the
    confirmatory study's where it tests the conclusion (its primary claims' answers combined),
    the exploratory rows' where it does not (and, until the study's look, everywhere); the
    rows, weaker evidence, beside it."""
    from a3c_tools.study_reading import budget_text

    by_id = {j.claim["id"]: j for j in judged}
    found = study_readings(claims, plan_path)  # {} until the study's one look
    out = ["| the thesis concludes (chapter 8) | our answer | at (steps a run) | confirmatory "
           "test | exploratory rows (weaker evidence) |", "|---|---|---|---|---|"]  # fmt: skip
    for conclusion in claims.get("conclusion", []):
        rows = conclusion.get("rows", [])
        unknown = [row for row in rows if row not in by_id]
        if unknown:
            raise ValueError(f"conclusion {conclusion['claim']!r} names no row {unknown}")
        word = combine([head_of(by_id[row].verdict) for row in rows])
        rests = ", ".join(f"{row} ({head_of(by_id[row].verdict)})" for row in rows)
        exploratory = f"{word}: {rests}" if rests else conclusion.get("none", "no row")
        primary = conclusion.get("primary", "-")
        names = [] if primary.startswith("-") else primary.split(", ")
        read = [found[name] for name in names if name in found]
        if names and len(read) == len(names):
            answer = f"**{combine([head_of(r.answer) for r in read])}**"
            at = "; ".join(dict.fromkeys(r.budget for r in read))
            test = ", ".join(
                f"{r.id} (**{r.verdict}**)" if r.answer == r.verdict
                else f"{r.id} (**{r.verdict}** by the plan's rule; the data: {r.answer})"
                for r in read
            )  # fmt: skip
        else:
            waiting = "the study's look waits" if names else "exploratory only"
            answer = f"**{word}** ({waiting})"
            games: dict[int, list[str]] = {}
            for game, steps in dict.fromkeys(row_steps(by_id[row].claim) for row in rows):
                if game:
                    games.setdefault(steps, []).append(game)
            at = "; ".join(budget_text(" and ".join(g), steps) for steps, g in games.items())
            at = at or "-"
            test = primary
        cells = [conclusion["claim"], answer, at, test, exploratory]
        out.append("| " + " | ".join(" ".join(c.split()) for c in cells) + " |")
    return out


def study_readings(claims: dict, plan_path: Path | None = None) -> dict[str, Reading]:
    """Each primary claim of the confirmatory study read as a referee would (its budget, its
    power planned and achieved, what the data show: a3c_tools.study_reading), with the claims
    file's notes and line names; {} until its one look."""
    plan_path = plan_path or CONFIRMATORY
    found = study_outcomes(plan_path)
    if not found:
        return {}
    from a3c_tools.study_reading import readings

    plan = read_toml(plan_path)
    notes, names = claims.get("study_notes", {}), claims.get("study_lines", {})
    return {r.id: r for r in readings(plan, [o for _, o in found], notes, names)}


def study_outcomes(plan_path: Path | None = None) -> list[tuple[dict, Outcome]]:
    """The confirmatory study's primary claims with their results at its one look ([] until
    then, or without a plan)."""
    plan_path = plan_path or CONFIRMATORY
    if not plan_path.is_file():
        return []
    from a3c_tools.confirmatory import outcomes

    plan = read_toml(plan_path)
    found = outcomes(plan)
    return [] if found is None else list(zip(plan["claim"], found, strict=True))


def study_verdicts(plan_path: Path | None = None) -> dict[str, str]:
    """Each primary claim's verdict at the confirmatory study's one look ({} until then)."""
    return {o.id: o.verdict for _, o in study_outcomes(plan_path)}


def study_tally(claims: dict | None = None, plan_path: Path | None = None) -> str | None:
    """The confirmatory study's verdicts counted, once its one look is taken, with the budgets
    they hold at and the claims whose data the rule leaves open: "**The confirmatory study at a
    glance**: 7 primary claims: 2 reproduced, ... (at ...)" (None until then)."""
    found = study_readings(claims or {}, plan_path)
    if not found:
        return None
    counts = Counter(r.verdict for r in found.values())
    parts = ", ".join(f"{counts[head]} {head}" for head in VERDICTS if counts[head])
    beyond = [f"{r.id}'s data read {head_of(r.answer)}" for r in found.values()
              if r.answer != r.verdict]  # fmt: skip
    if beyond:  # (only an inconclusive claim is read beyond the plan's rule)
        parts += f", of which {', '.join(beyond)}"
    budgets = Counter(r.budget for r in found.values())
    at = " and ".join(f"{count} at {budget}" for budget, count in budgets.items())
    name = "primary claim" if len(found) == 1 else "primary claims"
    return f"**The confirmatory study at a glance**: {len(found)} {name}: {parts}; {at}."


def confirmatory(plan_path: Path = CONFIRMATORY, claims: dict | None = None) -> list[str]:
    """The confirmatory section's table, from the pre-registered plan: each primary claim, its
    experiment, the effect it must detect, its runs per line and power, and its status; then
    the claims the plan left out as not testable, with the runs and CPU-hours they would need."""
    if not plan_path.is_file():
        return []
    from a3c_tools.confirmatory import outcomes, runs_in

    plan = read_toml(plan_path)
    found = outcomes(plan)  # None until every claim's runs are in: one look
    read = study_readings(claims or {}, plan_path) if found is not None else {}
    progress = [runs_in(claim["test"], claim["runs"]) for claim in plan.get("claim", [])]
    out = ["| id | primary claim | experiment | effect to detect | runs per line (power) | "
           "effect [95% t interval], p and its null (Holm) | verdict, at its budget |",
           "|---|---|---|---|---|---|---|"]  # fmt: skip
    for i, claim in enumerate(plan.get("claim", [])):
        result, verdict = "-", "**planned, not yet run**"
        done, needed = sum(progress[i].values()), claim["runs"] * len(progress[i])
        # counted from run ids, no score read: the one look waits for every claim's runs
        if done and done >= needed:
            verdict = f"**all {needed} runs in; waits for the one look**"
        elif done:
            verdict = f"**under way: {done} of {needed} runs in**"
        if found is not None:
            o, r = found[i], read[claim["id"]]
            f = ".3f" if "atari" not in claim["test"] else ".1f"
            result = (f"{o.effect:+{f}} [{o.low:+{f}}, {o.high:+{f}}] (n = {o.pairs}), "
                      f"p {r.null}: {shown_p(o.p)} ({shown_p(o.adjusted)})")  # fmt: skip
            verdict = f"**{o.verdict}** at {r.budget}"
            if r.answer != o.verdict:  # the plan's rule leaves open what the data show
                verdict += f"; the data: {r.answer}"
        cells = [claim["id"], claim["claim"], claim["experiment"],
                 f"{claim['effect']:+g} ({claim['effect_basis']})".replace("+0 (", "0 ("),
                 f"{claim['runs']} ({claim['power']:.0%} at {claim['level']:.4f})",
                 result, verdict]  # fmt: skip
        out.append("| " + " | ".join(" ".join(str(c).split()) for c in cells) + " |")
    left = plan.get("not_testable", [])
    if left:  # left out of the family before any run: what a test of them would need
        out += ["", "**Not testable at our budget**, so outside the family and never tested by "
                "the study (`results/confirmatory/PLAN.md` says why):", ""]  # fmt: skip
        for entry in left:
            need = (f"more than {MAX_POWER_RUNS}" if entry.get("runs") is None
                    else f"{entry['runs']:,}")  # fmt: skip
            out.append(
                f"- {entry['id']}: {' '.join(entry['claim'].split())} {POWER:.0%} power at "
                f"{abs(entry['effect']):g} ({entry['effect_basis']}) would need {need} runs per "
                f"line at the committed spread ({entry.get('cpu_hours', 0):,} CPU-hours); the "
                f"{entry['max_runs']} runs a line we can afford give {entry['power']:.0%}."
            )
    return out


def study_reading_sections(claims: dict, plan_path: Path = CONFIRMATORY) -> list[str]:
    """After the study's look: each claim's power, planned and achieved, and what each verdict
    rests on (a3c_tools.study_reading); [] until the look."""
    found = study_readings(claims, plan_path)
    if not found:
        return []
    from a3c_tools.study_reading import power_table

    plan = read_toml(plan_path)
    out = ["### Power, planned and achieved", "", claims.get("study_power", "").strip(), ""]
    out += [*power_table(list(found.values()), plan), ""]
    out += ["### What each verdict rests on", "", claims.get("study_rests", "").strip(), ""]
    for r in found.values():
        call = r.verdict if r.answer == r.verdict else f"{r.verdict}; the data: {r.answer}"
        notes = "; ".join(r.notes)
        out.append(f"- **{r.id}** ({call}; {r.budget}){': ' + notes if notes else ''}.")
    return [*out, ""]


def confirmatory_status(plan_path: Path = CONFIRMATORY) -> str:
    """The confirmatory section's status: planned, under way (how many of the study's runs are
    in, each line's counted once however many claims read it; run ids only), or done. Not in its
    heading, so that the section's anchor stays the same while the runs come in."""
    from a3c_tools.confirmatory import outcomes, runs_in

    plan = read_toml(plan_path)
    if outcomes(plan) is not None:
        return "done: every run is in and the one look is taken"
    lines: dict[tuple[str, ...], tuple[int, int]] = {}  # line -> (runs needed, runs in)
    for claim in plan.get("claim", []):
        for line, done in runs_in(claim["test"], claim["runs"]).items():
            needed, before = lines.get(line, (0, 0))
            lines[line] = (max(needed, claim["runs"]), max(before, done))
    done, needed = sum(d for _, d in lines.values()), sum(n for n, _ in lines.values())
    if not done:
        return "planned, not yet run"
    return f"under way, {done} of its {needed} runs in"


# The forest plot. Colours by the verdict's first word; the checks compare them with the page.
COLOURS = {
    "reproduced": "#2e7d32",
    "contradicted": "#c62828",
    "inconclusive": "#8a8a8a",
    "no verdict": "#b0b0b0",
}
SYMBOLS = {"better": ">", "worse": "<", "comparable": "\u2248"}  # line against baseline


@dataclass(frozen=True)
class Point:
    """One row of the forest plot: a claim with an interval, its numbers as the page rounds
    them (to 3 decimals, so that the plot and the table agree digit for digit)."""

    section: str
    label: str
    effect: float
    low: float
    high: float
    verdict: str  # the verdict's first word
    colour: str


def label(claim: dict) -> str:
    """A row's short name on the plot: its figure, the claim as "line > baseline" (< for worse,
    an approximately-equal sign for comparable) and its form, as in
    "Fig. 6.5: WW < FF (as written, --conv-layout final)"."""
    found = re.search(r"Figures? ((?:[A-Z]|\d+)\.\d+)", claim["where"])
    # a script's path (chapter 8's ideas) by its stem; "as run" is said once, by the form
    base, line = (
        Path(name).stem.removeprefix("a3c_")
        if name.endswith(".py")
        else name.removesuffix(" as run")
        for name in claim["names"]
    )
    form = claim["form"] + (", all evaluations" if claim.get("score") == "score_all" else "")
    head = f"Fig. {found[1]}: " if found else ""
    return f"{head}{line} {SYMBOLS[claim['expect']]} {base} ({form})"


STUDY_SECTION = "The confirmatory study (primary claims)"  # the plot's first, once looked at


def study_points(claims: dict, plan_path: Path | None = None) -> list[Point]:
    """The confirmatory study's Catch claims as forest-plot rows, once its one look is taken:
    each claim's effect and 95% interval, coloured by its verdict at the study's Holm level and
    labelled from the claims file's `[study_labels]` (an Atari claim's effect is in game score,
    so it is left off, as the page's Atari rows are)."""
    labels = claims.get("study_labels", {})
    points = []
    for claim, o in study_outcomes(plan_path):
        if "atari" in claim["test"]:
            continue
        effect, low, high = (round(x, 3) for x in (o.effect, o.low, o.high))
        name = f"{o.id}: {labels.get(o.id, ' '.join(claim['claim'].split()[:6]))}"
        points.append(Point(STUDY_SECTION, name, effect, low, high, o.verdict,
                            COLOURS[o.verdict]))  # fmt: skip
    return points


def forest_points(claims: dict) -> list[Point]:
    """The forest plot's rows: the confirmatory study's Catch claims once its one look is taken
    (study_points), then, in the page's order, every Catch row with an interval, coloured by its
    verdict at the page's adjusted level."""
    points = study_points(claims)
    for judged in judge(claims):
        claim = judged.claim
        looks = compared(claim)
        paired = looks.decisive if looks is not None else None
        if paired is None or "atari" in claim:  # an Atari row's effect is in game score
            continue
        verdict = head_of(judged.verdict)
        effect, low, high = (round(x, 3) for x in (paired.effect, paired.low, paired.high))
        points.append(Point(judged.section, label(claim), effect, low, high, verdict,
                            COLOURS[verdict]))  # fmt: skip
    return points


def draw(points: list[Point], path: Path) -> None:
    """The forest plot of the points, as a PNG whose "Description" holds the points (JSON)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.transforms import blended_transform_factory

    sections = list(dict.fromkeys(point.section for point in points))
    rows = len(points) + len(sections)  # a heading row above each section's points
    fig, ax = plt.subplots(figsize=(8, 0.28 * rows + 1.5), layout="constrained")
    left = blended_transform_factory(ax.transAxes, ax.transData)  # x in axes, y in rows
    ticks, names, y = [], [], 0
    for section in sections:
        # a heading bar over the grid, the band and the line at 0, under no point
        ax.axhspan(y - 0.5, y + 0.5, color="#eeeeee", zorder=2.5)
        ax.text(0.005, y, section, transform=left, va="center", fontsize=8.5, weight="bold",
                zorder=5)  # fmt: skip
        for point in (point for point in points if point.section == section):
            y += 1
            ax.plot([point.low, point.high], [y, y], color=point.colour, lw=1.8, zorder=3)
            ax.plot(point.effect, y, "o", color=point.colour, ms=4.5, zorder=4)
            ticks.append(y)
            names.append(point.label)
        y += 1
    ax.axvspan(-MARGIN, MARGIN, color="#dde6f3", zorder=1)
    ax.axvline(0, color="black", lw=0.8, zorder=2)
    ax.set_yticks(ticks, names, fontsize=7.5)
    ax.set_ylim(y - 0.5, -0.5)  # the first section on top
    ax.tick_params(axis="y", length=0)
    ax.tick_params(axis="x", labelsize=8, top=True, labeltop=True)
    ax.grid(axis="x", color="#dddddd", lw=0.6, zorder=0)
    ax.set_xlabel(
        "paired mean effect: line - baseline in Catch score (the fraction of balls caught)",
        fontsize=8,
    )
    handles = [Line2D([], [], color=colour, marker="o", ms=4.5, lw=1.8, label=verdict)
               for verdict, colour in COLOURS.items()]  # fmt: skip
    handles.append(Patch(color="#dde6f3", label=f"\u00b1{MARGIN} (comparable)"))
    fig.legend(handles=handles, loc="outside upper center", ncol=4, fontsize=8, frameon=False)
    description = json.dumps([asdict(point) for point in points])
    fig.savefig(path, dpi=130, metadata={"Software": None, "Description": description})
    plt.close(fig)


def plotted(path: Path) -> list[Point] | None:
    """The points a forest plot was drawn from, read back from the PNG; None if there is no
    such file or it carries none."""
    if not path.is_file():
        return None
    from PIL import Image, UnidentifiedImageError  # matplotlib's own dependency

    try:
        with Image.open(path) as image:
            description = getattr(image, "text", {}).get("Description")
    except UnidentifiedImageError:
        return None
    if description is None:
        return None
    return [Point(**point) for point in json.loads(description)]


def caption(claims: dict, rows: list[tuple[str, str, str]]) -> str:
    """The forest plot's caption: what it draws, and which rows it leaves off (those without an
    interval), by reason and section."""
    left_off: dict[str, Counter] = {}
    rows_of = [
        (section["title"], claim) for section in claims["section"] for claim in section["claim"]
    ]
    for (title, claim), (_, effect, call) in zip(rows_of, rows, strict=True):
        if "atari" in claim and "baseline" in claim:
            why = "with an effect in a game's score, not Catch's"
        elif "atari" in claim and call != "not run yet":
            why = "judged seed by seed against random play"
        elif effect == "-":
            why = "not run yet" if call == "not run yet" else "judged without a pair of lines"
        else:
            continue
        left_off.setdefault(why, Counter())[title] += 1
    drawn = len(rows) - sum(sum(counts.values()) for counts in left_off.values())
    text = (
        f"*The {drawn} Catch rows with an interval: the paired mean effect (line - baseline, "
        f"in Catch score) with its unadjusted t interval (95%; {100 * SECOND_LOOK:g}% at an "
        "extended row's second look), coloured by its verdict at the page's Holm-adjusted "
        "level; a label reads as the claim (line > "
        f"baseline for better, < for worse, \u2248 for comparable: within the band of "
        f"\u00b1{MARGIN})."
    )
    study = study_points(claims)
    if study:
        text += (
            f" Above them, the confirmatory study's {len(study)} primary claims on Catch, each "
            "with its 95% t interval and coloured by its verdict at the study's own Holm-"
            "adjusted level (its Atari claim, in game score, is in the table)."
        )
    if left_off:
        text += " Left off: " + "; ".join(
            f"{sum(counts.values())} {why} ("
            + ", ".join(f"{count} in {title}" for title, count in counts.items()) + ")"
            for why, counts in left_off.items()
        ) + "."  # fmt: skip
    return text + "*"


def render(claims: dict) -> str:
    """The whole page, in Markdown: the answer (the thesis's conclusions and our verdicts), the
    confirmatory study, the exploratory rows with their forest plot, then the method."""
    judged = judge(claims)
    rows = [(j.ours, j.effect, j.verdict) for j in judged]
    out = [claims["intro"].strip(), "", "## The answer: the thesis's conclusions", ""]
    looked = bool(study_verdicts())
    answer = claims.get("answer", "").strip()
    status = claims.get("answer_looked" if looked else "answer_waiting", "").strip()
    out += ["\n".join([answer, status]).strip(), "", *conclusions(claims, judged), ""]
    out += [tally(judged), "", multiplicity(judged), ""]
    table = confirmatory(CONFIRMATORY, claims)
    if table:
        out += ["## The confirmatory study", "", f"**Status**: {confirmatory_status()}.", ""]
        glance = study_tally(claims)
        if glance is not None:  # the answer first, then how it was reached
            out += [glance, "", claims.get("confirmatory_looked", "").strip(), ""]
        out += [claims.get("confirmatory", "").strip(), "", *table, ""]
        out += study_reading_sections(claims)
    following = confirmatory(CONFIRMATORY_NEXT, claims)
    if following:
        out += ["## The next study: the thesis's budget", "",
                f"**Status**: {confirmatory_status(CONFIRMATORY_NEXT)}.", "",
                claims.get("next_study", "").strip(), "", *following, ""]  # fmt: skip
    out += ["## Exploratory rows", "", claims.get("exploratory", "").strip(), ""]
    if any(effect != "-" for _, effect, _ in rows):  # the figure main writes beside the page
        out += [f"![The claims' effects with their intervals]({FIGURE.as_posix()})", ""]
        out += [caption(claims, rows), ""]
    missing: dict[str, list[str]] = {}
    next_row = iter(judged)
    for section in claims["section"]:
        out += [f"### {section['title']}", ""]
        if "text" in section:
            out += [section["text"].strip(), ""]
        out += [
            "| id | claim | where | form | thesis's evidence | ours | effect [t interval] | "
            "p (Holm) | verdict | history |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for claim in section["claim"]:
            row = next(next_row)
            call = row.verdict
            if head_of(call) == "not run yet" and "command" in claim:
                game = f" ({claim['atari']['game']})" if "atari" in claim else ""
                missing.setdefault(claim["command"], []).append(claim["where"] + game)
            head = head_of(call)
            verdict_cell = f"**{head}**{call[len(head) :]}"
            if "mixed_precision" in claim:
                verdict_cell += f"; *precision mixed*: {claim['mixed_precision']}"
            p_cell = "-" if row.p is None else f"{shown_p(row.p)} ({shown_p(row.adjusted)})"
            history = claim["history"]
            if ids_of(claim):
                history = f"re-uses the runs of {', '.join(ids_of(claim))}; {history}"
            cells = [claim["id"], claim["claim"], claim["where"], claim.get("form", "-"),
                     claim["thesis"], row.ours, row.effect, p_cell, verdict_cell,
                     history]  # fmt: skip
            out.append("| " + " | ".join(" ".join(cell.split()) for cell in cells) + " |")
        out.append("")
    out += ["## Method", "", claims.get("method", "").strip(), ""]
    out.append(claims["outro"].strip())
    if missing:  # the sentence that introduces the list only with a list to introduce
        out += ["", claims.get("missing", "The rows *not run yet*, and their commands:").strip()]
        out += [""] + [f"- {'; '.join(dict.fromkeys(wheres))}: `{command}`"
                       for command, wheres in missing.items()]  # fmt: skip
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser("thesis_claims", __doc__.split("\n")[0])
    parser.add_argument(
        "-o",
        "--out",
        type=Path,
        help="write the page here and its figure in img/ beside it (default: the page to stdout)",
    )
    parser.add_argument(
        "--check", type=Path, help="exit 1 if this page or its figure differs from the data"
    )
    opts = parser.parse_args(argv)
    claims = read_toml(CLAIMS)
    page, points = render(claims), forest_points(claims)
    if opts.check is not None:
        figure = opts.check.parent / FIGURE
        stale = (
            [str(opts.check)] if not opts.check.is_file() or opts.check.read_text() != page else []
        )
        if points and plotted(figure) != points:  # the data drawn, not the pixels
            stale.append(str(figure))
        if stale:
            are = "is" if len(stale) == 1 else "are"
            command = f"python -m a3c_tools.thesis_claims -o {opts.check}"
            print(f"{' and '.join(stale)} {are} stale: {command}")
            return 1
        print(f"{opts.check} and its figure hold what the committed results give")
    elif opts.out is not None:
        opts.out.write_text(page)
        print(f"wrote {opts.out}")
        if points:
            figure = opts.out.parent / FIGURE
            figure.parent.mkdir(parents=True, exist_ok=True)
            draw(points, figure)
            print(f"wrote {figure}")
    else:
        sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    run_main(main)
