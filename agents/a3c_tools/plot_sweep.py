"""Plot learning-rate sweeps the way the thesis does (Figures 6.3, 6.5-6.8, 7.1-7.7).

    python -m a3c_tools.plot_sweep sweeps/a3c_ff/results.csv sweeps/glpq/results.csv \\
        --labels "A3C FF" "A3C GLPQ" --out sweep.png

Each results table written by `a3c_tools.sweep` is one configuration and one line. The figure,
as in the thesis:
- upper left: each run's mean score over all of its evaluations (the thesis's "mean score on 20
  evaluations"), against log10 of the learning rate;
- upper right: each run's score, the mean of its final 5 evaluations;
- below: a bar per configuration, the mean score of the final 5 evaluations over the runs whose
  learning rate lies in the range the sweeps sampled (from each table's sweep.json, else the
  runs' own range; [1e-5, 1e-2] in the thesis's sweeps) or in --bar-range, with the standard
  error of that mean and the number of runs; its title gives that range.

The curves follow the thesis's plotting code: the runs are sorted by log10(learning rate),
linearly interpolated onto 50 evenly spaced points of the x range, and smoothed with a
Savitzky-Golay filter of window 5 and polynomial order 3 (each point replaced by the value at it
of the cubic least-squares fit to the 5 points around it; at both ends, the cubic fit to the
first or last 5 points). Two deliberate differences: runs with the same learning rate are
averaged before interpolating, and the curve is drawn only between the lowest and the highest
learning rate sampled, rather than extrapolated to the ends of the axis. The runs themselves are
drawn as faint dots in the line's colour, since a first reproduction has far fewer of them than
the thesis's 50-100. Failed runs are left out of the curves and the bars, and counted in the
table printed on stdout.

The table printed on stdout (markdown) gives, per configuration, the runs (ok/all), the bar's
value and the mean over all evaluations, ready for a README.

Reference values (`--reference LABEL=VALUE`, repeatable), e.g. the thesis's bar values
(`--reference "A3C FF=0.73"`), are drawn as a hatched bar beside that configuration's bar and
added to the table as a column "reference".

A sweep that samples a second flag jointly with the first (`--y grad-clip`, the thesis's
Figure A.1) is drawn as a map instead: one panel per table, each run a point at
(log10 x, log10 y) coloured by its score (final 5), and the table printed lists the runs.
"""

from __future__ import annotations

import csv
import math
import sys
import textwrap
from pathlib import Path

import numpy as np

from a3c_tools import run_main, sweep, tool_parser

GRID_POINTS = 50  # the thesis interpolated onto np.linspace(lo, hi), 50 points
SAVGOL_WINDOW = 5
SAVGOL_ORDER = 3


def savgol(y: np.ndarray, window: int = SAVGOL_WINDOW, order: int = SAVGOL_ORDER) -> np.ndarray:
    """Savitzky-Golay smoothing: each point becomes the value at it of the least-squares
    polynomial of degree `order` through the `window` points centred on it; the first and last
    window // 2 points take the values of the polynomial fitted to the first or last `window`
    points (scipy.signal.savgol_filter's mode="interp"). Fewer points than `window`: unchanged."""
    from scipy.signal import savgol_filter

    y = np.asarray(y, dtype=float)
    return y.copy() if len(y) < window else savgol_filter(y, window, order, mode="interp")


def smooth_curve(
    x: np.ndarray, y: np.ndarray, x_range: tuple[float, float], points: int = GRID_POINTS
) -> tuple[np.ndarray, np.ndarray]:
    """The thesis's sweep curve: average runs with equal x, sort by x, interpolate linearly onto
    `points` evenly spaced points of x_range (keeping those within the data), Savitzky-Golay
    smooth (window 5, order 3). Returns the grid points and the curve on them."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if len(x) == 0:
        return np.empty(0), np.empty(0)
    unique_x, inverse = np.unique(x, return_inverse=True)
    mean_y = np.bincount(inverse, weights=y) / np.bincount(inverse)
    grid = np.linspace(x_range[0], x_range[1], points)
    grid = grid[(grid >= unique_x[0]) & (grid <= unique_x[-1])]
    if len(grid) == 0:
        return unique_x, mean_y
    return grid, savgol(np.interp(grid, unique_x, mean_y))


def read_table(path: str, x_column: str) -> dict:
    """A sweep's runs: x (log10 of the x column), score, score_all for the ok runs; counts."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if rows and x_column not in rows[0]:
        alternative = x_column.replace("-", "_") if "-" in x_column else x_column.replace("_", "-")
        if alternative not in rows[0]:
            raise ValueError(f"{path} has no column {x_column!r}; columns: {list(rows[0])}")
        x_column = alternative
    ok = [row for row in rows if row.get("status") == "ok"]
    return {
        "values": np.array([float(row[x_column]) for row in ok]),
        "score": np.array([float(row["score"]) for row in ok]),
        "score_all": np.array([float(row["score_all"]) for row in ok]),
        "runs": len(rows),
        "ok": len(ok),
    }


def sampled_range(path: str, x_column: str) -> tuple[float, float] | None:
    """The range LOW, HIGH that the sweep of the results table at path sampled x_column from,
    as its sweep.json (beside the table) says; None without one (or a sweep's), or for a choice."""
    try:
        config = sweep.read_config(Path(path).with_name(sweep.CONFIG_NAME))
        samples = [sweep.parse_sample(sample) for sample in config.get("samples", [])]
    except sweep.UsageError:  # no sweep.json, not a sweep's, or a sample it would refuse
        return None
    names = {x_column.replace("_", "-"), x_column.replace("-", "_")}
    return next(((s.low, s.high) for s in samples if s.name in names and s.kind != "choice"), None)


def default_bar_range(paths: list[str], tables: list[dict], x_column: str) -> tuple[float, float]:
    """The bars' range: what the sweeps sampled (all of the tables' ranges together), else the
    runs' own range, else the thesis's [1e-5, 1e-2]."""
    ranges = [sampled_range(path, x_column) for path in paths]
    ranges += [(t["values"].min(), t["values"].max()) for t, r in zip(tables, ranges, strict=True)
               if r is None and t["values"].size]  # fmt: skip
    ranges = [r for r in ranges if r is not None]
    if not ranges:
        return 1e-5, 1e-2
    return float(min(low for low, _ in ranges)), float(max(high for _, high in ranges))


def read_joint(path: str, x_column: str, y_column: str) -> dict:
    """A sweep's ok runs for a map: x and y (the two sampled columns' values) and score."""
    x, y = read_table(path, x_column), read_table(path, y_column)
    return {"x": x["values"], "y": y["values"], "score": x["score"], "runs": x["runs"]}


def decades(values: np.ndarray) -> tuple[float, float]:
    """The whole decades around positive values, in log10: (-6, -2) for 3e-6 ... 8e-3."""
    if values.size == 0:
        return -6.0, -2.0
    return math.floor(np.log10(values.min())), math.ceil(np.log10(values.max()))


def plot_joint(
    tables: list[dict],
    labels: list[str],
    out: str,
    x_label: str,
    y_label: str,
    title: str | None,
    x_range: tuple[float, float] | None = None,
) -> None:
    """Draw each table's runs at (log10 x, log10 y), coloured by score, one panel per table,
    over whole decades of x (or x_range, in log10) and of y."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scores = np.concatenate([t["score"] for t in tables])
    high = 1.0 if scores.size == 0 or scores.max() <= 1.0 else float(scores.max())
    low = min(0.0, float(scores.min())) if scores.size else 0.0
    with plt.style.context("ggplot"):
        fig, axes = plt.subplots(
            1, len(tables), figsize=(8 * len(tables) + 1, 7), squeeze=False, constrained_layout=True
        )
        for ax, table, label in zip(axes[0], tables, labels, strict=True):
            points = ax.scatter(
                np.log10(table["x"]), np.log10(table["y"]), c=table["score"], cmap="viridis",
                vmin=low, vmax=high, s=70, edgecolors="black", linewidths=0.5,
            )  # fmt: skip
            ax.set_xlim(*(x_range or decades(np.concatenate([t["x"] for t in tables]))))
            ax.set_ylim(*decades(np.concatenate([t["y"] for t in tables])))
            ax.set_xlabel(f"log10({x_label})")
            ax.set_ylabel(f"log10({y_label})")
            ax.set_title(f"{label}: {len(table['score'])} runs", fontsize=11)
        fig.colorbar(points, ax=axes[0].tolist(), label="Mean score, final 5 evaluations")
        if title:
            fig.suptitle(textwrap.fill(title, 50 + 60 * (len(tables) - 1)), fontsize=12)
        fig.savefig(out, dpi=100)
        plt.close(fig)


def joint_table(tables: list[dict], labels: list[str], x_name: str, y_name: str) -> str:
    """A markdown table of every ok run of each table, by x: x, y and its score."""
    lines = [f"| configuration | {x_name} | {y_name} | score (final 5) |", "|---|---|---|---|"]
    for table, label in zip(tables, labels, strict=True):
        for i in np.argsort(table["x"], kind="stable"):
            x, y, score = table["x"][i], table["y"][i], table["score"][i]
            lines.append(f"| {label} | {x:.3g} | {y:.3g} | {score:.3f} |")
    return "\n".join(lines)


def bar_value(values: np.ndarray, scores: np.ndarray, bar_range: tuple[float, float]) -> dict:
    """Mean, standard error and count of the scores whose value lies in bar_range (inclusive)."""
    selected = scores[(values >= bar_range[0]) & (values <= bar_range[1])]
    n = len(selected)
    mean = float(selected.mean()) if n else math.nan
    sem = float(selected.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    return {"mean": mean, "sem": sem, "n": n}


def plot(
    tables: list[dict],
    labels: list[str],
    out: str,
    *,
    x_label: str,
    x_range: tuple[float, float],
    bar_range: tuple[float, float],
    title: str | None = None,
    log_x: bool = True,
    references: dict[str, float] | None = None,
) -> None:
    """Draw the figure (two curve panels above, the bar chart below) into the PNG `out`. A
    configuration with a reference value gets a hatched bar of that value beside its own."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with plt.style.context("ggplot"):
        fig = plt.figure(figsize=(12, 9), constrained_layout=True)
        grid = fig.add_gridspec(2, 2, height_ratios=[3, 2])
        panels = [
            (fig.add_subplot(grid[0, 0]), "score_all", "Mean score, all evaluations"),
            (fig.add_subplot(grid[0, 1]), "score", "Mean score, final 5 evaluations"),
        ]
        bars = fig.add_subplot(grid[1, :])
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        all_scores = np.concatenate([t["score_all"] for t in tables] + [t["score"] for t in tables])
        y_max = 1.0 if all_scores.size == 0 or all_scores.max() <= 1.0 else None
        x_text = f"log10({x_label})" if log_x else x_label
        references = references or {}
        # with reference values, each configuration's bar shares its slot with its reference
        width, shift = (0.38, 0.2) if references else (0.6, 0.0)
        for i, (table, label) in enumerate(zip(tables, labels, strict=True)):
            color = colors[i % len(colors)]
            x = np.log10(table["values"]) if log_x else table["values"]
            for ax, key, _ in panels:
                ax.scatter(x, table[key], s=20, color=color, alpha=0.45, linewidths=0)
                curve_x, curve_y = smooth_curve(x, table[key], x_range)
                ax.plot(curve_x, curve_y, color=color, linewidth=3, label=label)
            bar = bar_value(table["values"], table["score"], bar_range)
            error = bar["sem"] if bar["n"] > 1 else 0.0
            bars.bar(i - shift, bar["mean"], width=width, color=color, yerr=error, capsize=6)
            if bar["n"]:
                text = f"{bar['mean']:.3f} (n={bar['n']})"
                bars.text(
                    i - shift, bar["mean"] + error, text, ha="center", va="bottom", fontsize=11
                )
            if label in references:
                value = references[label]
                bars.bar(
                    i + shift,
                    value,
                    width=width,
                    facecolor="none",
                    edgecolor=color,
                    hatch="//",
                    linewidth=1.5,
                )
                bars.text(
                    i + shift, value, f"ref. {value:g}", ha="center", va="bottom", fontsize=11
                )
        for ax, _, y_text in panels:
            ax.set_xlim(*x_range)
            ax.set_ylim(0, y_max)
            ax.set_xlabel(x_text)
            ax.set_ylabel(y_text)
            ax.legend(loc="best", framealpha=0.0)
        bars.set_xticks(range(len(labels)), labels)
        bars.set_xlim(-0.8, len(labels) - 0.2)
        bars.set_ylim(0, y_max)
        low, high = (f"{v:g}" for v in bar_range)
        bars.set_ylabel("Mean score, final 5 evaluations")
        bars.set_title(f"Averaged over the runs with {x_label} in [{low}, {high}]", fontsize=11)
        if title:
            fig.suptitle(title)
        fig.savefig(out, dpi=100)
        plt.close(fig)


def summary_table(
    tables: list[dict],
    labels: list[str],
    bar_range: tuple[float, float],
    references: dict[str, float] | None = None,
    x_name: str = "lr",
) -> str:
    """A markdown table: runs, the bar's mean (+- standard error) over the runs with x_name in
    bar_range and the all-evaluations mean; with reference values, a column of them."""
    low, high = (f"{v:g}" for v in bar_range)
    extra = " reference |" if references else ""
    lines = [
        f"| configuration | runs ok/all | score (final 5), {x_name} in [{low}, {high}] "
        f"| score (all evaluations), same runs |{extra}",
        "|---|---|---|---|" + ("---|" if references else ""),
    ]
    for table, label in zip(tables, labels, strict=True):
        bar = bar_value(table["values"], table["score"], bar_range)
        all_evals = bar_value(table["values"], table["score_all"], bar_range)
        sem = f" +- {bar['sem']:.3f}" if bar["n"] > 1 else ""
        lines.append(
            f"| {label} | {table['ok']}/{table['runs']} | {bar['mean']:.3f}{sem} (n={bar['n']}) "
            f"| {all_evals['mean']:.3f} |"
        )
        if references:
            lines[-1] += f" {references[label]:g} |" if label in references else "  |"
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser(
        "plot_sweep", "Plot sweep results tables (python -m a3c_tools.sweep) in the thesis's style."
    )
    parser.add_argument("tables", nargs="+", help="results.csv files, one per configuration")
    parser.add_argument(
        "--labels",
        nargs="+",
        default=None,
        help="one label per table (default: each table's folder name)",
    )
    parser.add_argument("-o", "--out", default="sweep.png", help="the PNG to write")
    parser.add_argument("--x", default="learning-rate", help="the swept column (x axis)")
    parser.add_argument("--linear-x", action="store_true", help="plot x itself, not log10(x)")
    parser.add_argument(
        "--y",
        default=None,
        help="a second column sampled jointly with x: draw a map of the runs (log10 x against "
        "log10 y, coloured by score) instead of curves",
    )
    for flag, help in (
        ("--xrange", "x axis range (default: the whole decades around the data, -6 -2 for the "
         "thesis's sweeps)"),
        ("--bar-range", "x values averaged in the bar chart (default: the range the sweeps "
         "sampled, from their sweep.json, else the runs' range; 1e-5 1e-2 in the thesis's "
         "sweeps)"),
    ):  # fmt: skip
        parser.add_argument(flag, nargs=2, type=float, metavar=("LOW", "HIGH"), help=help)
    parser.add_argument("--title", default=None)
    parser.add_argument(
        "--reference",
        action="append",
        default=[],
        metavar="LABEL=VALUE",
        help="a reference bar value for the configuration LABEL (e.g. the thesis's), drawn "
        "beside its bar and added to the table; repeatable",
    )
    args = parser.parse_args(argv)
    labels = args.labels or [Path(t).resolve().parent.name for t in args.tables]
    if len(labels) != len(args.tables):
        print(f"error: {len(args.tables)} tables but {len(labels)} labels", file=sys.stderr)
        return 2
    references = {}
    for text in args.reference:
        label, _, value = text.rpartition("=")
        try:
            references[label] = float(value)
        except ValueError:
            label = ""
        if label not in labels:
            print(
                f"error: --reference {text!r}: expected LABEL=VALUE with LABEL one of {labels}",
                file=sys.stderr,
            )
            return 2
    x_name = "lr" if args.x in ("learning-rate", "learning_rate") else args.x
    try:
        if args.y is not None:
            joint = [read_joint(t, args.x, args.y) for t in args.tables]
        else:
            tables = [read_table(t, args.x) for t in args.tables]
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.y is not None:
        x_range = tuple(args.xrange) if args.xrange else None
        plot_joint(joint, labels, args.out, args.x, args.y, args.title, x_range)
        print(joint_table(joint, labels, x_name, args.y))
        print(f"wrote {args.out}")
        return 0
    log_x = not args.linear_x
    values = np.concatenate([t["values"] for t in tables])
    if args.xrange:
        x_range = tuple(args.xrange)
    elif log_x:  # whole decades around the data: -6 -2 for the thesis's sweeps (and no data)
        x_range = decades(values)
    else:
        x_range = (float(values.min()), float(values.max())) if values.size else (0.0, 1.0)
    if args.bar_range:
        bar_range = tuple(args.bar_range)
    else:
        bar_range = default_bar_range(args.tables, tables, args.x)
    plot(
        tables,
        labels,
        args.out,
        x_label=args.x,
        x_range=x_range,
        bar_range=bar_range,
        title=args.title,
        log_x=log_x,
        references=references,
    )
    print(summary_table(tables, labels, bar_range, references, x_name))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    run_main(main)
