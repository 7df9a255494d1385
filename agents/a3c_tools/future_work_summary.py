"""The future-work runs on Catch: a table of scores and a figure of learning curves.

    python -m a3c_tools.future_work_summary > results/future_work_catch/summary.txt
    python -m a3c_tools.future_work_summary OTHER_FOLDER   # the same layout elsewhere

Reads each configuration's results.csv (one row per run: its score, the mean of the final 5
evaluations) and, where the per-run folders are still here (runs/, not committed), their
evaluations.csv files, which it gathers into curves.csv (committed) so that the figure can be
drawn again from a clean clone. Writes curves.png: per idea, each configuration's mean
evaluation over its runs against global steps, with +-1 standard error over the runs shaded.
The paired comparisons with their intervals are on docs/claims.md.
"""

from __future__ import annotations

import csv
import statistics
from pathlib import Path

import numpy as np

from a3c_tools import run_main
from a3c_tools.future_work_runs import folder_argument
from a3c_tools.paired import read_scores

# (panel title, [(baseline, variant), ...]): each idea against the thesis's version of its script
PANELS = [
    # the LPQ and GLPQ pairs as the claims page judges them: run with float32 prototype
    # distances (GLPQ with growth's anew, the others by campaign items f1 and f1b)
    ("prototype value head", [("lpq_f32", "lpq_value_f32"), ("glpq_f32", "glpq_value_f32")]),
    ("prototypes from the data", [("lpq_f32", "lpq_data_f32"), ("glpq_f32", "glpq_data_f32")]),
    ("prototype growth", [("lpq_f32", "lpq_growth_f32"), ("glpq_f32", "glpq_growth_f32")]),
    ("online local weight sharing", [("lws", "lws_online")]),
]
# the lines those replace, whose runs computed the distances in bf16 (a known defect): in the
# table and curves.csv, not in the figure
REPLACED = ["lpq", "lpq_value", "glpq", "glpq_value", "lpq_data", "glpq_data", "lpq_growth",
            "glpq_growth"]  # fmt: skip
PANELLED = [name for _, pairs in PANELS for pair in pairs for name in pair]
CONFIGS = list(dict.fromkeys([*PANELLED, *REPLACED]))
# a script's thesis version dashed, its idea solid, in the same colour in every panel
FALL_BACK = 0.1  # print_fall_back: a score this far below the run's best evaluation
COLOURS = {"lpq": ("C0", "C1"), "glpq": ("C2", "C3"), "lws": ("C4", "C5")}


def gather_curves(folder: Path) -> list[dict[str, str]]:
    """Rows (config, run_id, global_step, mean_return), from runs/ or else from curves.csv."""
    saved: list[dict[str, str]] = []
    if (folder / "curves.csv").is_file():
        with open(folder / "curves.csv", newline="") as f:
            saved = list(csv.DictReader(f))
    rows = []
    for config in CONFIGS:
        for run_id in sorted(read_scores(folder / config / "results.csv")):
            path = folder / config / "runs" / run_id / "evaluations.csv"
            if path.is_file():
                with open(path, newline="") as f:
                    rows += [
                        {"config": config, "run_id": run_id, "global_step": r["global_step"],
                         "mean_return": r["mean_return"]}
                        for r in csv.DictReader(f)
                    ]  # fmt: skip
            else:
                rows += [r for r in saved if r["config"] == config and r["run_id"] == run_id]
    with open(folder / "curves.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, ["config", "run_id", "global_step", "mean_return"])
        writer.writeheader()
        writer.writerows(rows)
    return rows


def plot(rows: list[dict[str, str]], path: Path, finished: dict[str, int]) -> dict[str, list]:
    """The figure; `finished`: each configuration's finished runs, so that a legend says where
    fewer runs' curves were kept (a run folder lost before its curve was gathered). Returns
    each panel's legend labels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True, sharey=True)
    legends = {}
    for ax, (title, pairs) in zip(axes.flat, PANELS, strict=True):
        for config in dict.fromkeys(name for pair in pairs for name in pair):
            runs: dict[str, list[tuple[int, float]]] = {}
            for r in rows:
                if r["config"] == config:
                    runs.setdefault(r["run_id"], []).append(
                        (int(r["global_step"]), float(r["mean_return"]))
                    )
            dashed = config in {pair[0] for pair in pairs}
            colour = COLOURS[config.split("_")[0]][0 if dashed else 1]
            style = "--" if dashed else "-"
            total = finished.get(config, 0)
            if not runs:
                if total:  # in the legend only: scored, its curves not kept
                    ax.plot([], [], style, color=colour, label=f"{config} ({total} runs: curves "
                            "not kept)")  # fmt: skip
                continue
            # evaluations fall within a few hundred steps of each 50,000: align them by index
            length = min(len(points) for points in runs.values())
            steps = np.array([p[0] for p in next(iter(runs.values()))[:length]])
            values = np.array([[p[1] for p in points[:length]] for points in runs.values()])
            mean = values.mean(axis=0)
            se = values.std(axis=0, ddof=1) / np.sqrt(len(runs)) if len(runs) > 1 else 0 * mean
            label = f"{config} (n={len(runs)}" + (f" of {total} runs" if total > len(runs) else "")
            ax.plot(steps, mean, style, color=colour, label=label + ")")
            ax.fill_between(steps, mean - se, mean + se, alpha=0.15, color=colour)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        legends[title] = ax.get_legend_handles_labels()[1]
        if legends[title]:
            ax.legend(fontsize=8, loc="upper left")
    for ax in axes[1]:
        ax.set_xlabel("global steps")
    for ax in axes[:, 0]:
        ax.set_ylabel("mean evaluation return (50 episodes)")
    fig.suptitle("Catch-v0, the thesis's future work: 1M steps, 2 workers x 16 envs (n: runs)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return legends


def main(argv: list[str] | None = None) -> int:
    about = "The future-work runs' scores (stdout), curves.csv and curves.png."
    folder = folder_argument("future_work_summary", about, argv)
    print("| configuration | runs | score (final 5), mean +- s.e. over runs | runs' scores |")
    print("|---|---:|---|---|")
    finished = {}
    for config in CONFIGS:
        scores = read_scores(folder / config / "results.csv")
        finished[config] = len(scores)
        if not scores:
            print(f"| {config} | 0 | not run yet | |")
            continue
        values = [scores[r] for r in sorted(scores)]
        se = statistics.stdev(values) / len(values) ** 0.5 if len(values) > 1 else float("nan")
        listed = ", ".join(f"{v:.3f}" for v in values)
        mean = statistics.mean(values)
        print(f"| {config} | {len(values)} | {mean:.3f} +- {se:.3f} | {listed} |")
    rows = gather_curves(folder)
    print_fall_back(rows)
    plot(rows, folder / "curves.png", finished)
    return 0


def print_fall_back(rows: list[dict[str, str]]) -> None:
    """Per configuration, how far its runs fall back from their best evaluation: a run's best
    (after step 0) against its score (the mean of its final 5 evaluations)."""
    print()
    print(f"| configuration | runs | best evaluation, mean over runs | runs whose score is more "
          f"than {FALL_BACK} below their best |")  # fmt: skip
    print("|---|---:|---:|---:|")
    for config in CONFIGS:
        runs: dict[str, list[float]] = {}
        for r in rows:
            if r["config"] == config and r["global_step"] != "0":
                runs.setdefault(r["run_id"], []).append(float(r["mean_return"]))
        if not runs:
            continue
        best = [max(v) for v in runs.values()]
        fell = sum(max(v) - statistics.mean(v[-5:]) > FALL_BACK for v in runs.values())
        print(f"| {config} | {len(runs)} | {statistics.mean(best):.3f} | {fell} |")


if __name__ == "__main__":
    run_main(main)
