"""Rebuild the kept evaluations.csv of Atari lines whose run folders were lost (see COMMAND.txt).

    python results/atari_figures/recover_evaluations.py

The runs of these lines had finished, but their run folders (runs/, not committed) did not
survive a new checkout, and with them each seed's evaluation curve. What was committed at FROM
(the last commit before the loss, read with `git show`, so the command gives the same answer
later) determines it: sweep.py's results.csv gives each run's `score` (the mean of its final 5
evaluations after step 0: here every one after step 0, a run having at most 4) and `score_all`
(the mean of all of them), and the figure's results.csv its final evaluation. With evaluations
at 0, 1M and the end (Breakout, 2M steps) that fixes every value: e_end = final,
e_1M = 2 score - e_end, e_0 = 3 score_all - e_1M - e_end. With four (Pong, 3M steps) it fixes
e_0 and e_1M + e_2M per seed; the split is the one assignment of values on the 0.1 grid (10
episodes of whole-point returns) that gives the figure's curves.csv mean and standard error at
1M and at 2M, and the script stops if there is not exactly one.

Every rebuilt value is checked: it lies on the 0.1 grid, and, for a line whose every seed is
rebuilt, each step's mean and standard error over seeds equal FROM's curves.csv (6 significant
digits); GLPQ as run's one finished run, against its step-0 evaluation committed before (FINALS
and STEP_0 below). A line's kept file is written where there is none; where there is one (the
campaign's drawings have kept it since), the script checks that it still holds every rebuilt
row, and exits 1 if not.
"""

from __future__ import annotations

import csv
import itertools
import math
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
FROM = "83bea38"  # the last commit before the run folders were lost
SCORE_LAST = 5  # sweep.py's: a run's score is the mean of its final 5 evaluations after step 0
LINES = {  # line folder -> (the figure whose results.csv and curves.csv hold it, line slug)
    "fig6.9/Breakout/ff": ("fig7.8", "ff"),
    "fig7.8/Breakout/lpq_fig78": ("fig7.8", "lpq_fig78"),
    "fig7.8/Breakout/glpq_fig78": ("fig7.8", "glpq_fig78"),  # run 0 only: 1 and 2 had not ended
    "fig6.10/Pong/vf1.0": ("fig6.10", "vf1.0"),
    "fig6.10/Pong/vf0.5": ("fig6.10", "vf0.5"),
}
# GLPQ as run's seed 1 ended after the figure was last drawn: its final evaluation is in commit
# c59a96f's message and COMMAND.txt's session bullet (38.3), and its step-0 evaluation in the
# figure's results.csv at commit 81b2a9d (1.3), which its rebuilt curve must give again.
FINALS = {("fig7.8/Breakout/glpq_fig78", "1"): 38.3}
STEP_0 = {("fig7.8/Breakout/glpq_fig78", "1"): 1.3}
EPISODES = "10"
GRID = [round(-21.0 + 0.1 * i, 1) for i in range(421)]  # a Pong evaluation's possible means


def rows(path: str) -> list[dict[str, str]]:
    """A committed table of results/atari_figures at FROM."""
    text = subprocess.run(["git", "show", f"{FROM}:results/atari_figures/{path}"], cwd=HERE,
                          capture_output=True, text=True, check=True).stdout  # fmt: skip
    return list(csv.DictReader(text.splitlines()))


def on_grid(value: float) -> float:
    rounded = round(value, 1)
    if abs(rounded - value) > 1e-6:
        sys.exit(f"{value} is not a mean of 10 whole-point returns")
    return rounded


def stats(values: list[float]) -> tuple[str, str]:
    mean = sum(values) / len(values)
    se = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1) / len(values))
    return f"{mean:.6g}", f"{se:.6g}"


def split(totals: list[float], first: dict[str, str], second: dict[str, str]) -> list[list[float]]:
    """The one (e_1M, e_2M) per seed, on the grid, with e_1M + e_2M = totals and the two steps'
    committed mean and standard error."""
    found = []
    total = round(float(first["mean"]) * len(totals), 1)  # the last seed's e_1M follows
    for head in itertools.product(GRID, repeat=len(totals) - 1):
        lows = [*head, round(total - sum(head), 1)]
        if not -21 <= lows[-1] <= 21 or stats(lows) != (first["mean"], first["se"]):
            continue
        highs = [round(t - low, 1) for t, low in zip(totals, lows, strict=True)]
        if all(-21 <= h <= 21 for h in highs) and stats(highs) == (second["mean"], second["se"]):
            found.append([list(lows), highs])
    if len(found) != 1:
        sys.exit(f"{len(found)} splits of {totals} fit the committed curve")
    return found[0]


def recover(folder: str, figure: str, slug: str) -> None:
    sweep = rows(f"{folder}/results.csv")
    game = folder.split("/")[1]
    ours = lambda r: r["game"] == game and r["line"] == slug  # noqa: E731
    finals = {r["seed"]: float(r["final_score"]) for r in rows(f"{figure}/results.csv") if ours(r)}
    curve = [r for r in rows(f"{figure}/curves.csv") if ours(r)]
    shapes = {(r["evaluations"], r["final_step"]) for r in sweep}
    if len(shapes) != 1 or not 3 <= int(sweep[0]["evaluations"]) <= SCORE_LAST + 1:
        sys.exit(f"{folder}: runs of {shapes} evaluations and final steps; expected one, of 3-6")
    n, final_step = int(sweep[0]["evaluations"]), int(sweep[0]["final_step"])
    steps = [1_000_000 * i for i in range(n - 1)] + [final_step]
    per_seed: dict[str, list[float]] = {}
    for run in sweep:
        score, score_all = float(run["score"]), float(run["score_all"])
        end = (
            FINALS[folder, run["seed"]] if (folder, run["seed"]) in FINALS else finals[run["seed"]]
        )
        middle_sum = on_grid((n - 1) * score - end)  # every evaluation after step 0 but the last
        first = on_grid(n * score_all - (n - 1) * score)
        if STEP_0.get((folder, run["seed"]), first) != first:
            sys.exit(f"{folder}: seed {run['seed']}'s step 0 is not the one committed")
        per_seed[run["seed"]] = [first, middle_sum, end]
    if n == 3:  # 0, 1M, end: the middle is one evaluation
        table = per_seed
    elif n == 4:  # 0, 1M, 2M, end
        seeds = list(per_seed)
        lows, highs = split([per_seed[s][1] for s in seeds], curve[1], curve[2])
        table = {
            s: [per_seed[s][0], lows[i], highs[i], per_seed[s][2]] for i, s in enumerate(seeds)
        }
    else:
        sys.exit(f"{folder}: {n} evaluations a run; this script splits at most two middle ones")
    checked = all(int(point["seeds"]) == len(table) for point in curve)
    if checked and [int(point["step"]) for point in curve] != steps:
        sys.exit(f"{folder}: the committed curve's steps are not {steps}")
    for i, point in enumerate(curve if checked else []):
        if stats([values[i] for values in table.values()]) != (point["mean"], point["se"]):
            sys.exit(f"{folder}: step {point['step']} does not give the committed curve")
    rebuilt = [
        [seed, str(step), f"{v:g}", EPISODES]
        for seed, values in table.items()
        for step, v in zip(steps, values, strict=True)
    ]
    check = "checked against curves.csv" if checked else "its step 0 checked against FROM's"
    kept = HERE / folder / "evaluations.csv"
    if kept.exists():
        with kept.open(newline="") as f:
            held = list(csv.reader(f))
        missing = [row for row in rebuilt if row not in held]
        if missing:
            sys.exit(f"{folder}: its evaluations.csv lacks the rebuilt rows {missing}")
        print(f"{folder}: {len(table)} seeds x {n} evaluations, {check}; all in evaluations.csv")
        return
    with kept.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["seed", "global_step", "mean_return", "episodes"])
        writer.writerows(rebuilt)
    print(f"{folder}: {len(table)} seeds x {n} evaluations, {check}; written")


if __name__ == "__main__":
    for folder, (figure, slug) in LINES.items():
        recover(folder, figure, slug)
