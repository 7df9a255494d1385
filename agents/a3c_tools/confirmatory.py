"""The confirmatory study's numbers: for each primary claim of results/confirmatory/plan.toml,
the spread of its committed paired differences, the runs per line for the plan's power at the
family's Holm-corrected level, and the power those runs give; and the check that the plan holds
these numbers and that its run seeds are new.

    python -m a3c_tools.confirmatory results/confirmatory/plan.toml          # the table
    python -m a3c_tools.confirmatory results/confirmatory/plan.toml --check  # exit 1 if stale

A claim's `spread_from` names the committed runs whose paired differences give the spread:
`baseline` and `line` (Catch results folders, runs 0..runs-1 paired by run_id), or `lines` for a
composite claim (the mean over those lines, run by run, against the baseline), or `atari` (a
figure's folder, `game`, `baseline` and `line`: each line's results.csv, paired by seed). The
runs per line are the fewest for which the two-sided paired t test at the level alpha / (the
number of primary claims), Holm's first and strictest step, has at least the plan's power at
the claim's `effect` (a3c_tools.paired.runs_for_power; for "comparable", the distance of
`effect` from the band's edge), capped at the plan's `max_runs` (the power at the cap is then
stated). A run seed is new when no committed results.csv under results/ has it in its `seed` column.

The analysis is fixed here too (`outcomes`): one look, once every claim's `test` runs are in,
the same paired t test as the claims page's, Holm over the family, a verdict where the adjusted
p is below alpha; the claims page shows it (until then, how many of each claim's runs are in:
`runs_in`, which counts run ids and reads no score).

With `spread_upper` in the plan's [study] (a confidence, as 0.8), a claim is sized for the one-sided
upper confidence limit of its pilot's spread rather than the spread itself (`planning_spread`):
for a study whose pilot ran at another budget, or over few pairs. An item's own
`device_steps_per_s` replaces the study's for its device-minute estimate (a measured rate of its
script).

A `[[not_testable]]` entry is a claim left out of the family because no affordable number of
runs gives it power: the plan states, and `--check` holds, the runs per line its test would
need for the plan's power at the level it would have had in the family (alpha / (claims +
not testable), uncapped up to a3c_tools.paired.MAX_POWER_RUNS), the power at its `max_runs`,
and the CPU-hours those runs would take (`steps`, `num_workers` and `rate_from` as an item's).
"""

from __future__ import annotations

import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3c_tools import ROOT, read_toml, results_folder, run_main, tool_parser
from a3c_tools import atari_figures as af
from a3c_tools.paired import (
    MARGIN,
    MAX_POWER_RUNS,
    holm,
    interval,
    margin_p_value,
    p_value,
    power,
    read_rows,
    runs_for_power,
)

PLAN = ROOT / "results" / "confirmatory" / "plan.toml"
STRIDE = 1000  # sweep.py's and atari_figures' run seeds: seed + 1000 i


def catch_pairs(spec: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A Catch spec's committed pairs, over the runs 0..runs-1 that its baseline and every line
    finished: (learning rates, nan where the baseline's table has none; baseline scores; the
    lines' scores (lines, n); the differences, line - baseline or the lines' mean - baseline)."""
    base, *lines = (
        {row["run_id"]: row for row in read_rows(ROOT / results_folder(f, ROOT))
         if row["status"] == "ok"}
        for f in [spec["baseline"], *spec.get("lines", [spec.get("line")])]
    )  # fmt: skip
    ids = [f"run-{i:04d}" for i in range(int(spec["runs"]))]
    ids = [i for i in ids if i in base and all(i in line for line in lines)]
    rates = np.array([float(base[i].get("learning-rate") or "nan") for i in ids])
    b = np.array([float(base[i]["score"]) for i in ids])
    x = np.array([[float(line[i]["score"]) for i in ids] for line in lines])
    return rates, b, x, x.mean(axis=0) - b


def complete(spec: dict, runs: int) -> bool:
    """Whether every run a claim's test needs is in (ok or failed): Catch lines hold runs
    0..runs-1, an Atari figure's lines every seed (a failed run, or an ok one at the steps), and
    its table, which the one look reads, every seed that is ok in both lines."""
    if not all(n == runs for n in runs_in(spec, runs).values()):
        return False
    if "atari" in spec:
        both = set.intersection(*(atari_seeds(spec, runs, line)[0] for line in atari_lines(spec)))
        return atari_differences({**spec, "runs": runs}).size == len(both)
    return True


def atari_lines(spec: dict) -> tuple[str, str]:
    return spec["baseline"], spec["line"]


def atari_line_folder(spec: dict, line: str) -> Path:
    """An Atari claim's line's folder, FIGURE/GAME/LINE, or that of the figure whose runs it is
    (atari_figures' same_as: Figure 7.8's A3C FF is Figure 6.9's)."""
    folder = Path(spec["atari"])
    figure = next((each for each in af.data().figures if each.id == folder.name), None)
    shared = next((each for each in figure.lines if each.slug == line), None) if figure else None
    if shared is not None:
        folder = af.line_folder(folder.parent, figure, spec["game"], shared)
    else:
        folder = folder / spec["game"] / line
    return ROOT / results_folder(str(folder), ROOT)


def atari_seeds(spec: dict, runs: int, line: str) -> tuple[set[int], set[int]]:
    """The seeds of an Atari claim's runs (seed + 1000 i, i < runs) in one line's results.csv,
    read from its seed, status and final_step columns alone (no score): (ok and at the claim's
    steps, failed). An ok run short of the steps is not in (a run of another budget)."""
    wanted = {int(spec["seed"]) + STRIDE * i for i in range(runs)}
    ok, failed = set(), set()
    for row in read_rows(atari_line_folder(spec, line)):
        seed = int(row["seed"])
        if seed not in wanted:
            continue
        if row.get("status") == "failed":
            failed.add(seed)
        elif int(row.get("final_step") or 0) >= int(spec["steps"]):
            ok.add(seed)
    return ok, failed


def runs_in(spec: dict, runs: int) -> dict[tuple[str, ...], int]:
    """How many of the runs a claim's test needs are in, line by line (the line's folder, or its
    figure, game and name), counted from the run ids, seeds, statuses and steps alone: no score
    is read, so the count can be shown while the study runs without looking at its data."""
    if "atari" in spec:  # each line's own folder
        return {
            (spec["atari"], spec["game"], line): len(set.union(*atari_seeds(spec, runs, line)))
            for line in atari_lines(spec)
        }
    ids = {f"run-{i:04d}" for i in range(runs)}
    return {
        (folder,): len(
            ids & {row["run_id"] for row in read_rows(ROOT / results_folder(folder, ROOT))}
        )
        for folder in [spec["baseline"], *spec.get("lines", [spec.get("line")])]
    }


@dataclass(frozen=True)
class Outcome:
    """A primary claim's result at the study's one look."""

    id: str
    pairs: int
    effect: float
    low: float
    high: float
    p: float
    adjusted: float
    verdict: str


def outcomes(plan: dict) -> list[Outcome] | None:
    """The study's one look: None until every claim's runs are all in; then per claim the
    paired mean difference with its 95% t interval, its two-sided paired t p-value (for
    "comparable", of |difference| = 0.05), Holm's adjusted p over the family, and the verdict
    at the family's level (`alpha`)."""
    claims, alpha = plan["claim"], plan["study"]["alpha"]
    if not all(complete(c["test"], c["runs"]) for c in claims):
        return None
    found = []
    for claim in claims:
        d = differences({**claim["test"], "runs": claim["runs"]})
        test = margin_p_value if claim["expect"] == "comparable" else p_value
        low, high = interval(d)
        found.append((claim, d, test(d), low, high))
    adjusted = holm([p for _, _, p, _, _ in found])
    result = []
    for (claim, d, p, low, high), adj in zip(found, adjusted, strict=True):
        effect = float(d.mean())
        verdict = "inconclusive"
        if adj < alpha and claim["expect"] == "comparable":
            verdict = "reproduced" if abs(effect) < MARGIN else "contradicted"
        elif adj < alpha:
            sign = 1 if claim["expect"] == "better" else -1
            verdict = "reproduced" if sign * effect > 0 else "contradicted"
        result.append(Outcome(claim["id"], d.size, effect, low, high, p, adj, verdict))
    return result


def atari_scores(spec: dict, line: str) -> dict[int, float]:
    """seed -> score of one line's runs of an Atari claim, from the line's own results.csv: the
    sweep's score, the mean of a run's evaluations after step 0 (at 1M and 2M steps), as every
    Catch claim scores a run (PLAN.md, amendment 5). Only ok runs; with `steps` in the spec only
    those that reached them, with `seed` (and `runs`) only the study's, seed + 1000 i."""
    wanted = None
    if "seed" in spec:
        wanted = {int(spec["seed"]) + STRIDE * i for i in range(int(spec["runs"]))}
    scores = {}
    for row in read_rows(atari_line_folder(spec, line)):
        seed = int(row["seed"])
        if row.get("status") != "ok" or (wanted is not None and seed not in wanted):
            continue
        if int(row.get("final_step") or 0) >= int(spec.get("steps", 0)):
            scores[seed] = float(row["score"])
    return scores


def atari_differences(spec: dict) -> np.ndarray:
    """The paired differences of two lines of an Atari figure on one game, by seed: the line's
    score minus the baseline's, over the seeds that both have (atari_scores)."""
    base, line = (atari_scores(spec, name) for name in atari_lines(spec))
    return np.array([line[s] - base[s] for s in sorted(set(base) & set(line))])


def differences(spec: dict) -> np.ndarray:
    return atari_differences(spec) if "atari" in spec else catch_pairs(spec)[3]


@dataclass(frozen=True)
class Planned:
    """A primary claim's computed plan: the committed spread (and its pairs), the level, the
    runs per line and the power they give."""

    id: str
    pairs: int
    spread: float
    level: float
    runs: int
    power: float


def planning_spread(spread: float, pairs: int, study: dict) -> float:
    """The spread a claim is sized for: the pilot's standard deviation, or, with the study's
    `spread_upper` (a confidence, such as 0.8), its one-sided upper confidence limit at that
    confidence (chi-square with pairs - 1 degrees of freedom), so that a pilot that happened to
    spread narrowly does not leave the study underpowered (Browne 1995)."""
    confidence = study.get("spread_upper")
    if confidence is None:
        return spread
    from scipy import stats

    df = pairs - 1
    return spread * math.sqrt(df / stats.chi2.ppf(1 - float(confidence), df))


def plan_claim(claim: dict, size: int, study: dict) -> Planned:
    """The runs per line for a primary claim, in a family of `size` claims."""
    d = differences(claim["spread_from"])
    if d.size < 3:
        raise ValueError(f"{claim['id']}: {d.size} committed pairs, fewer than 3 give no spread")
    spread = planning_spread(float(d.std(ddof=1)), int(d.size), study)
    level = study["alpha"] / size
    effect = float(claim["effect"])
    gap = abs(MARGIN - abs(effect)) if claim["expect"] == "comparable" else abs(effect)
    most = int(claim.get("max_runs", study["max_runs"]))
    needed = runs_for_power(gap, spread, level, study["power"])
    runs = most if needed is None or needed > most else max(needed, 3)
    return Planned(claim["id"], int(d.size), spread, level, runs, power(gap, spread, runs, level))


@dataclass(frozen=True)
class Untestable:
    """A claim outside the family: the runs per line it would need for the plan's power at the
    level it would have had in the family, the power at its cap, and those runs' CPU-hours."""

    id: str
    pairs: int
    spread: float
    level: float
    runs: int | None  # None: more than MAX_POWER_RUNS
    power: float  # at max_runs
    cpu_hours: float | None


def plan_untestable(entry: dict, plan: dict) -> Untestable:
    """What a `[[not_testable]]` entry's test would need, had it stayed in the family."""
    d = differences(entry["spread_from"])
    if d.size < 3:
        raise ValueError(f"{entry['id']}: {d.size} committed pairs, fewer than 3 give no spread")
    study = plan["study"]
    spread = float(d.std(ddof=1))
    level = study["alpha"] / (len(plan["claim"]) + len(plan.get("not_testable", [])))
    effect = abs(float(entry["effect"]))
    runs = runs_for_power(effect, spread, level, study["power"])
    cap = power(effect, spread, int(entry["max_runs"]), level)
    hours = None if runs is None else cpu_hours({**entry, "runs": runs})
    return Untestable(entry["id"], int(d.size), spread, level, runs, cap, hours)


def committed_seeds(root: Path = ROOT / "results", own: tuple[Path, ...] = ()) -> set[int]:
    """Every run seed in a committed results.csv under `root` (its `seed` column), but for the
    tables under `own` (the study's output folders: its own runs use its seeds)."""
    seeds: set[int] = set()
    for table in root.rglob("results.csv"):
        if any(table.is_relative_to(folder) for folder in own):
            continue
        for row in read_rows(table.parent):
            value = (row.get("seed") or "").strip()
            if value.lstrip("-").isdigit():
                seeds.add(int(value))
    return seeds


def output_folders(plan: dict) -> tuple[Path, ...]:
    """The folders the plan's items write their runs into."""
    folders = []
    for item in plan.get("item", []):
        if "out" in item:  # an atari item: its figure's folder
            folders.append(ROOT / item["out"])
        folders += [ROOT / line["out"] for line in item.get("lines", []) if isinstance(line, dict)]
    return tuple(folders)


def plan_seeds(plan: dict) -> set[int]:
    """The run seeds the plan's items will use."""
    seeds = set()
    for item in plan.get("item", []):
        runs = int(item.get("runs", item.get("seeds", 0)))
        seeds |= {int(item["seed"]) + STRIDE * i for i in range(runs)}
    return seeds


def problems(plan: dict, plan_path: Path) -> list[str]:
    """What in the plan disagrees with the committed runs: a claim's runs, power or level
    other than computed, an item with fewer runs than its claims need or more than any needs
    (or named by none), a not-testable entry's numbers other than computed, or a seed already
    used."""
    out = []
    claims, study = plan["claim"], plan["study"]
    for claim in claims:
        done = plan_claim(claim, len(claims), study)
        stated = (claim["runs"], round(claim["power"], 2), round(claim["level"], 5))
        if stated != (done.runs, round(done.power, 2), round(done.level, 5)):
            computed = f"{done.runs}, {done.power:.2f}, {done.level:.5f}"
            out.append(f"{claim['id']}: the plan says runs, power, level {stated}, the "
                       f"committed runs give {computed}")  # fmt: skip
        items = {item["id"]: item for item in plan.get("item", [])}
        made = {line["out"] for i in claim["items"] if i in items
                for line in items[i].get("lines", []) if isinstance(line, dict)}  # fmt: skip
        atari = [items[i] for i in claim["items"] if i in items and items[i]["kind"] == "atari"]
        made |= {f"{a['out']}/{a['figure']}:{line}" for a in atari for line in a["lines"]}
        test = claim["test"]
        if "atari" in test:
            needed = {f"{test['atari']}:{line}" for line in (test["baseline"], test["line"])}
            needed -= {f"{test['atari']}:ff"} if any(m.endswith(":ff") for m in made) else set()
        else:
            needed = {test["baseline"], *test.get("lines", [test.get("line")])}
        if not needed <= made:
            out.append(
                f"{claim['id']}: its test reads {sorted(needed - made)}, which no item makes"
            )
        for item_id in claim["items"]:
            item = items.get(item_id)
            if item is None:
                out.append(f"{claim['id']}: no item {item_id} in {plan_path}")
            elif int(item.get("runs", item.get("seeds", 0))) < claim["runs"]:
                out.append(f"{claim['id']}: item {item_id} has fewer runs than {claim['runs']}")
    for item in plan.get("item", []):  # no run that no claim's test reads
        wanted = [c["runs"] for c in claims if item["id"] in c["items"]]
        runs = int(item.get("runs", item.get("seeds", 0)))
        if not wanted:
            out.append(f"item {item['id']}: no primary claim names it")
        elif runs > max(wanted):
            out.append(f"item {item['id']}: {runs} runs per line, its claims need {max(wanted)}")
    ids = {claim["id"] for claim in claims}
    for entry in plan.get("not_testable", []):
        if entry["id"] in ids:
            out.append(f"{entry['id']}: both a primary claim and not testable")
        done = plan_untestable(entry, plan)
        hours = None if done.cpu_hours is None else round(done.cpu_hours)
        stated = (entry.get("runs"), round(entry["power"], 2), round(entry["level"], 5),
                  entry.get("cpu_hours"))  # fmt: skip
        if stated != (done.runs, round(done.power, 2), round(done.level, 5), hours):
            computed = f"{done.runs}, {done.power:.2f}, {done.level:.5f}, {hours}"
            out.append(f"{entry['id']} (not testable): the plan says runs, power, level, "
                       f"CPU-hours {stated}, the committed runs give {computed}")  # fmt: skip
    used = sorted(plan_seeds(plan) & committed_seeds(own=output_folders(plan)))
    if used:
        out.append(f"run seeds already used by committed runs: {used[:10]}")
    return out


def cpu_hours(item: dict) -> float:
    """An item's estimated CPU-hours: its runs (per line) x its steps at the steps/s its
    `rate_from` lines' committed runs had (final_step / wall_time_s, times their workers), one
    rate per line, in order."""
    runs = int(item.get("runs", item.get("seeds", 0)))
    steps = int(item.get("total_timesteps", item.get("steps", 0)))
    total = 0.0
    for folder in item["rate_from"]:
        with open(ROOT / results_folder(folder, ROOT) / "results.csv", newline="") as f:
            rows = [row for row in csv.DictReader(f) if row.get("status", "ok") == "ok"]
        workers = int(item.get("num_workers", 1))
        seconds = [float(r["wall_time_s"]) / float(r["final_step"]) for r in rows]
        total += runs * steps * workers * sum(seconds) / len(seconds) / 3600
    return total


def compute(plan: dict) -> str:
    """The study's compute: CPU-hours per item from this machine's committed runs, and device
    minutes at the plan's stated rate (an estimate until the batched backend is measured)."""
    rates = plan["study"]["device_steps_per_s"]
    lines = ["| item | runs per line x lines | steps a run | CPU-hours | device minutes (est.) |",
             "|---|---|---|---|---|"]  # fmt: skip
    hours = minutes = 0.0
    for item in plan.get("item", []):
        runs = int(item.get("runs", item.get("seeds", 0)))
        steps = int(item.get("total_timesteps", item.get("steps", 0)))
        count = len(item["rate_from"])
        h = cpu_hours(item)
        rate = float(item.get("device_steps_per_s", rates[item["kind"]]))  # an item's own
        m = runs * steps * count / rate / 60
        hours, minutes = hours + h, minutes + m
        lines.append(f"| {item['id']} | {runs} x {count} | {steps:,} | {h:.1f} | {m:.0f} |")
    lines.append(f"| **all** | | | **{hours:.1f}** | **{minutes:.0f}** |")
    return "\n".join(lines) + "\n"


def table(plan: dict) -> str:
    claims, study = plan["claim"], plan["study"]
    lines = ["| claim | committed pairs | spread (sd of differences) | level | runs per line "
             "| power |", "|---|---|---|---|---|---|"]  # fmt: skip
    for claim in claims:
        done = plan_claim(claim, len(claims), study)
        lines.append(f"| {done.id} | {done.pairs} | {done.spread:.4g} | {done.level:.5f} | "
                     f"{done.runs} | {done.power:.2f} |")  # fmt: skip
    left = plan.get("not_testable", [])
    if left:
        lines += ["", "| not testable | committed pairs | spread | level had it stayed | runs per "
                  f"line for {study['power']:.0%} power | power at its cap | their CPU-hours |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
        for entry in left:
            done = plan_untestable(entry, plan)
            runs = f"> {MAX_POWER_RUNS}" if done.runs is None else f"{done.runs}"
            hours = "-" if done.cpu_hours is None else f"{done.cpu_hours:,.0f}"
            cap = f"{done.power:.2f} at {entry['max_runs']}"
            lines.append(f"| {done.id} | {done.pairs} | {done.spread:.4g} | {done.level:.5f} | "
                         f"{runs} | {cap} | {hours} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser("confirmatory", __doc__.split("\n")[0])
    parser.add_argument("plan", type=Path, nargs="?", default=PLAN, help="the plan (TOML)")
    parser.add_argument(
        "--check", action="store_true",
        help="exit 1 if the plan's numbers or seeds disagree with the committed runs",
    )  # fmt: skip
    opts = parser.parse_args(argv)
    try:
        plan = read_toml(opts.plan)
    except ValueError as error:
        print(error, file=sys.stderr)
        return 2
    try:
        return report(plan, opts.plan, opts.check)
    except (KeyError, ValueError, OSError) as error:  # a plan short of a field or a folder
        what = f"no {error}" if isinstance(error, KeyError) else str(error)
        print(f"{opts.plan}: {what}", file=sys.stderr)
        return 2


def report(plan: dict, path: Path, check: bool) -> int:
    """Print the plan's numbers, or with `check` what disagrees; the exit code."""
    if check:
        found = problems(plan, path)
        for problem in found:
            print(problem)
        if not found:
            print(f"{path} holds what the committed runs give, and its seeds are new")
        return 1 if found else 0
    sys.stdout.write(table(plan) + "\n" + compute(plan))
    return 0


if __name__ == "__main__":
    run_main(main)
