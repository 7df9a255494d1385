"""Plot learning curves from the evaluations.csv files that the A3C scripts write.

    python -m a3c_tools.plot_evaluations runs/<run>/evaluations.csv [more.csv ...] -o curve.png

Each file is one line: the mean evaluation return against global steps, with +-1 standard error of
that mean (std / sqrt(episodes)) shaded. --wall-time draws a second panel with every line against
its own wall time (for runs of different speeds, such as several scripts compared); without it
the figure has no wall-time axis. --threshold draws a horizontal line (e.g.
0.9 for Catch) and prints the first evaluation that reaches it; --reference VALUE=LABEL draws a
labelled dotted line, such as random play's score on an Atari game.
"""

import csv
import sys
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")  # files only; no display needed
import matplotlib.pyplot as plt  # noqa: E402

from a3c_tools import run_main, tool_parser

COLUMNS = ("global_step", "wall_time_s", "mean_return", "std_return", "episodes")


def read_evaluations(path: Path) -> dict[str, list[float]]:
    """The columns of an evaluations.csv as lists of floats; ValueError if it is not one."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: not an evaluations.csv (missing columns {missing})")
        rows = list(reader)
    if not rows:
        raise ValueError(f"{path}: no evaluations yet")
    return {c: [float(row[c]) for row in rows] for c in COLUMNS}


def first_reaching(data: dict[str, list[float]], threshold: float) -> int | None:
    """The index of the first evaluation whose mean return is >= threshold, or None."""
    return next((i for i, m in enumerate(data["mean_return"]) if m >= threshold), None)


def parse_reference(text: str) -> tuple[float, str]:
    """VALUE=LABEL (e.g. "1.7=random play") as (value, label); ValueError otherwise."""
    value, sep, label = text.partition("=")
    try:
        return float(value), label.strip() if sep else ""
    except ValueError:
        raise ValueError(f"--reference {text!r} is not VALUE=LABEL, e.g. 1.7=random") from None


def plot(paths: list[Path], labels: list[str], output: Path, threshold: float | None,
         title: str | None, references: list[tuple[float, str]] = (),
         wall_time_panel: bool = False) -> None:  # fmt: skip
    if wall_time_panel:
        fig, (ax, ax_wall) = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    else:
        fig, ax = plt.subplots(figsize=(7, 4.2))
    axes = (ax, ax_wall) if wall_time_panel else (ax,)
    for path, label in zip(paths, labels, strict=True):
        data = read_evaluations(path)
        steps, mean = np.array(data["global_step"]), np.array(data["mean_return"])
        sem = np.array(data["std_return"]) / np.sqrt(data["episodes"])
        (line,) = ax.plot(steps, mean, marker="o", markersize=3, label=label)
        ax.fill_between(steps, mean - sem, mean + sem, color=line.get_color(), alpha=0.2)
        if wall_time_panel:
            minutes = np.array(data["wall_time_s"]) / 60
            ax_wall.plot(minutes, mean, marker="o", markersize=3, color=line.get_color())
            ax_wall.fill_between(minutes, mean - sem, mean + sem, color=line.get_color(),
                                 alpha=0.2)  # fmt: skip
        if threshold is not None:
            i = first_reaching(data, threshold)
            walls = data["wall_time_s"]
            reached = (f"first >= {threshold:g} at step {steps[i]:,.0f}, {walls[i]:.0f} s"
                       if i is not None else f"never >= {threshold:g}")  # fmt: skip
            print(f"{path}: {len(steps)} evaluations; {reached}; last {mean[-1]:.3f} at step "
                  f"{steps[-1]:,.0f}, {data['wall_time_s'][-1]:.0f} s")  # fmt: skip
    for each in axes:
        if threshold is not None:
            each.axhline(threshold, color="gray", linestyle="--", linewidth=1)
        for value, label in references:
            each.axhline(value, color="black", linestyle=":", linewidth=1)
            each.annotate(label, (0.01, value), xycoords=("axes fraction", "data"), fontsize=8,
                          va="bottom")  # fmt: skip
        each.grid(alpha=0.3)
    if wall_time_panel:
        ax_wall.set_xlabel("wall time (minutes)")
    ax.set_xlabel("global steps")
    ax.set_ylabel("evaluation mean return")
    if title:
        fig.suptitle(title, fontsize=10)
    if wall_time_panel:
        # one legend below both panels, where it cannot cover a curve
        columns = len(paths) if len(paths) <= 3 else -(-len(paths) // 2)
        rows = -(-len(paths) // columns)
        fig.legend(loc="lower center", ncol=columns, fontsize=9, frameon=False)
        fig.tight_layout(rect=(0, 0.07 * rows, 1, 1))
    else:
        ax.legend(loc="best")
        fig.tight_layout()
    fig.savefig(output, dpi=120)
    print(f"wrote {output}")


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser("plot_evaluations", __doc__.split("\n")[0])
    parser.add_argument("csv", nargs="+", type=Path, help="evaluations.csv files")
    parser.add_argument("-o", "--output", type=Path, required=True, help="the PNG to write")
    parser.add_argument("--labels", nargs="+", help="one legend label per file")
    parser.add_argument("--threshold", type=float, help="draw this return and report reaching it")
    parser.add_argument("--title", help="the figure title")
    parser.add_argument("--reference", action="append", default=[], metavar="VALUE=LABEL",
                        help="a labelled dotted line, e.g. 1.7=random (repeatable)")  # fmt: skip
    parser.add_argument("--wall-time", action="store_true",
                        help="a second panel: every line against its own wall time")  # fmt: skip
    opts = parser.parse_args(argv)
    labels = opts.labels or [p.parent.name for p in opts.csv]
    if len(labels) != len(opts.csv):
        parser.error(f"--labels needs {len(opts.csv)} labels, got {len(labels)}")
    try:
        references = [parse_reference(r) for r in opts.reference]
        plot(opts.csv, labels, opts.output, opts.threshold, opts.title, references,
             opts.wall_time)  # fmt: skip
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    run_main(main)
