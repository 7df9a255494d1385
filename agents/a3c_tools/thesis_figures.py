"""Every thesis Catch figure as one command: its lines as the thesis's code ran them, swept, drawn.

The thesis's Catch figures (6.3, 6.5-6.8, 7.1-7.3, 7.5-7.7, A.1-A.3, C.1) are learning-rate
sweeps. For each figure this tool runs every line with the flags that reproduce its configuration
as run (read from the thesis's own code: docs/thesis-figures-as-run.md and the "As run" section
of docs/thesis-notes.md), through a3c_tools.sweep, at a budget of your choosing, and draws the
figure with a3c_tools.plot_sweep, next to the thesis's numbers where they are known. The
figures, their lines, flags and evidence are data: thesis_figures.toml beside this file (its
header gives the format).

    python -m a3c_tools.thesis_figures --list                  # every figure, its lines and flags
    python -m a3c_tools.thesis_figures fig7.6 --runs 8 --steps 250000 --out sweeps/thesis
    python -m a3c_tools.thesis_figures fig6.6 fig6.7 --runs 50 --steps 1000000 --num-workers 12 \\
        --lr-range 1e-6:1e-2 --out sweeps/thesis          # the thesis's own budget
    python -m a3c_tools.thesis_figures all --runs 8 --steps 250000 --out sweeps/thesis --dry-run

For each line of figure FIG it runs

    python -m a3c_tools.sweep agents/SCRIPT --out OUT/FIG/LINE --runs N --total-timesteps S \\
        --seed SEED --sample learning-rate=loguniform:LOW:HIGH [the line's samples] \\
        -- [the line's flags] --eval-interval S/20 [--num-workers W]

then `python -m a3c_tools.plot_sweep OUT/FIG/*/results.csv --labels ... --out OUT/FIG/FIG.png`
(figures that sweep a second flag, A.1 and C.1, get a second plot against it) and writes
OUT/FIG/FIG.md: the plot's table, the thesis's statement and the lines' notes.

Budget. Evaluations come every S/20 steps, 20 per run as in the thesis (50,000 in 1M), so that a
run's score, the mean of its final 5 evaluations, covers its last 20% of training (see
results/sweep_catch/reproduce.sh). The defaults (learning rates log-uniform in [1e-5, 1e-2], the
range the thesis's bars average over; sweep seed 1; one worker per run) are those of the first
reproduction, results/sweep_catch/, so run i of every line gets the same learning rate and seed as
its run i. The thesis ran 50-100 learning rates in [1e-6, 1e-2] per line, 1M steps, 12 workers.

Resuming. sweep.py resumes: the same command again skips the runs already in each line's
results.csv, and a larger --runs extends them. --round K runs the lines in rounds of K more runs
each (as reproduce.sh does), so that a stopped figure has covered its lines evenly. A line that
appears in several figures with the same configuration (A3C FF as run, the baseline of most) names
the first with `same_as`: its runs are that line's, run once, in that line's folder, and every
figure that shows it plots them (a test checks that both lines' flags parse to the same Args).

Exit codes: 0 when done, 1 when some line's every run failed, 2 for bad arguments (nothing is
created), a malformed thesis_figures.toml or a sweep folder holding another configuration, 3
when a run was in use elsewhere (resumed by hand; the same command goes on once it is free),
130 when interrupted.
"""

from __future__ import annotations

import argparse
import functools
import math
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

from a3c_tools import AGENTS, figure_sweeps, run_main
from a3c_tools.figure_sweeps import DataError, display, execute, plural, positive_int

PLOT = ["-m", "a3c_tools.plot_sweep"]
DATA = Path(__file__).with_name("thesis_figures.toml")  # the figures: lines, flags, evidence
DEFAULT_LR_RANGE = (1e-5, 1e-2)  # the range the thesis's bars average over
EVALUATIONS_PER_RUN = 20  # the thesis: every 50,000 steps in 1M
DEFAULT_SEED = 1  # sweep.py's default, and the first reproduction's
THESIS_BUDGET = "thesis: 50-100 lrs in [1e-6, 1e-2], 1M steps, 12 workers"


@dataclass(frozen=True)
class Line:
    """One line of a thesis figure: an agent script and the flags that reproduce it as run."""

    slug: str  # its folder under OUT/FIG
    label: str  # as in the thesis figure
    script: str  # in agents/
    flags: str  # fixed flags, as run (shell words)
    source: str  # the preset and the as-run doc's evidence; (I) marks an inference
    samples: tuple[str, ...] = ()  # sampled jointly with the learning rate: NAME=DIST
    approximation: str = ""  # why these flags are only the nearest to what ran, if they are
    same_as: str = ""  # FIG/SLUG of a line with the same configuration, whose runs this one shows

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.flags)

    def sample_names(self) -> list[str]:
        return [sample.partition("=")[0] for sample in self.samples]


@dataclass(frozen=True)
class Plot:
    """One plot of a figure: the score against a swept flag, or with y a map of the runs over
    two flags sampled jointly."""

    x: str = "learning-rate"
    bar_range: tuple[float, float] | None = None  # None: plot_sweep.py's, as sampled
    suffix: str = ""  # OUT/FIG/FIG{suffix}.png
    y: str | None = None


@dataclass(frozen=True)
class Figure:
    id: str
    caption: str  # a summary of the thesis's caption
    thesis: str  # what the thesis reports: its numbers, or its qualitative statement
    lines: tuple[Line, ...]
    numbers: tuple[tuple[str, float], ...] = ()  # label -> the thesis's bar value
    plots: tuple[Plot, ...] = (Plot(),)
    note: str = ""

    @property
    def number(self) -> str:
        return self.id.removeprefix("fig")


# ------------------------------------------------------------------------------------------------
# The figures, read from thesis_figures.toml and checked
# ------------------------------------------------------------------------------------------------
# The keys of the data file's tables, and their types; "?" marks an optional key.
KEYS = {
    "file": {"flags?": dict, "figure": list},
    "figure": {"id": str, "caption": str, "thesis": str, "note?": str, "numbers?": dict,
               "line": list, "plot?": list},
    "line": {"slug": str, "label": str, "script": str, "flags": str, "source": str,
             "samples?": list, "approximation?": str, "same_as?": str},
    "plot": {"x": str, "y?": str, "bar_range?": list},
}  # fmt: skip
FRAGMENT = re.compile(r"\{(\w+)\}")  # {NAME} in a line's flags: NAME of the [flags] table


def read_line(entry: object, where: str, fragments: dict[str, str]) -> Line:
    line = figure_sweeps.table(entry, KEYS["line"], "line", where)
    figure_sweeps.check_line(line, where)
    for name in FRAGMENT.findall(line["flags"]):
        if name not in fragments:
            raise DataError(f"{where}: flags name {{{name}}}, which [flags] does not define")
    flags = FRAGMENT.sub(lambda match: fragments[match[1]], line["flags"])
    figure_sweeps.words(flags, where)
    samples = line.get("samples", [])
    if not all(isinstance(sample, str) and all(sample.partition("=")) for sample in samples):
        raise DataError(f"{where}: samples must be NAME=DIST strings, got {samples!r}")
    return Line(**{**line, "flags": flags, "samples": tuple(samples)})


def read_figure(entry: object, file: str, index: int, fragments: dict[str, str]) -> Figure:
    figure = figure_sweeps.table(entry, KEYS["figure"], "figure", f"{file}: figure {index}")
    where = f"{file}: figure {figure['id']}"
    lines = []
    for i, line in enumerate(figure["line"], 1):
        label = line.get("label") if isinstance(line, dict) else None
        at = f"{where}, line {i}" + (f" ({label})" if label else "")
        lines.append(read_line(line, at, fragments))
    for name in ("slug", "label"):
        figure_sweeps.check_unique(
            [getattr(line, name) for line in lines], f"lines with {name}", where
        )
    numbers = tuple(figure.get("numbers", {}).items())
    for label, value in numbers:
        if label not in [line.label for line in lines]:
            raise DataError(f"{where}: numbers name {label!r}, which is no line's label")
        if type(value) not in (int, float):
            raise DataError(f"{where}: numbers: {label!r} = {value!r} is not a number")
    plots = [Plot()]  # every figure's plot against the learning rate, then one per [[plot]]
    for i, entry in enumerate(figure.get("plot", []), 1):
        at = f"{where}, plot {i}"
        plot = figure_sweeps.table(entry, KEYS["plot"], "plot", at)
        for axis in ("x", "y"):
            name = plot.get(axis)
            sampled = name == "learning-rate" or all(name in line.sample_names() for line in lines)
            if name is not None and not sampled:
                raise DataError(f"{at}: {axis} is {name!r}, which not every line samples")
        bars = plot.get("bar_range")
        if bars is not None and (len(bars) != 2 or any(type(v) not in (int, float) for v in bars)):
            raise DataError(f"{at}: bar_range must be [LOW, HIGH], got {bars!r}")
        suffix = f"-{plot['x']}" + (f"-{plot['y']}" if "y" in plot else "")
        bar_range = bars and (float(bars[0]), float(bars[1]))
        plots.append(Plot(plot["x"], bar_range, suffix, plot.get("y")))
    texts = {key: figure.get(key, "") for key in ("id", "caption", "thesis", "note")}
    numbers = tuple((label, float(value)) for label, value in numbers)
    return Figure(**texts, lines=tuple(lines), numbers=numbers, plots=tuple(plots))


def load_figures(path: Path = DATA) -> tuple[Figure, ...]:
    """The figures of a data file (thesis_figures.toml), checked; a DataError if malformed."""
    file, data = figure_sweeps.read_file(path, KEYS["file"])
    fragments = data.get("flags", {})
    for name, value in fragments.items():
        if not isinstance(value, str):
            raise DataError(f"{file}: [flags] {name} must be a string, got {value!r}")
        fragments[name] = " ".join(value.split())
    figures = [read_figure(entry, file, i, fragments) for i, entry in enumerate(data["figure"], 1)]
    figure_sweeps.check_unique([figure.id for figure in figures], "figures with id", file)
    figure_sweeps.check_same_as(figures, file, other_sweep)
    return tuple(figures)


def other_sweep(figure: Figure, line: Line, owner: Figure, target: Line) -> str | None:
    """What keeps a line from sharing the runs of target, its same_as (None: nothing). Their
    fixed flags may differ in spelling; a test checks that they parse to the same Args."""
    if (target.script, target.samples) != (line.script, line.samples):
        return "runs another script or samples other flags"
    return None


def folder(figure: Figure, line: Line) -> str:
    """FIG/SLUG of the folder that holds a line's runs: its own, or its same_as line's."""
    return line.same_as or f"{figure.id}/{line.slug}"


def run_as(figure: Figure, line: Line) -> tuple[Figure, Line]:
    """The figure and line whose sweep a line's runs are: itself, or its same_as line."""
    return figure_sweeps.run_as(figure, line, by_id)


@functools.cache
def all_figures() -> tuple[Figure, ...]:
    """thesis_figures.toml's figures, read on first use (a DataError if it is malformed)."""
    return load_figures()


def figure_ids() -> tuple[str, ...]:
    return tuple(figure.id for figure in all_figures())


def by_id(figure: str) -> Figure:
    return next(each for each in all_figures() if each.id == figure)


# ------------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------------
def figure_id(text: str) -> str | None:
    """The figure id for fig7.6, Fig7.6, 7.6, figa.1, A.1 ...; None when there is no such figure."""
    return figure_sweeps.figure_id(text, figure_ids())


def sweep_command(figure: Figure, line: Line, options: argparse.Namespace, runs: int) -> list[str]:
    """The sweep.py command of one line (without the interpreter)."""
    low, high = options.lr_range
    command = [
        *figure_sweeps.SWEEP,
        display(AGENTS / line.script),
        "--out",
        str(Path(options.out) / figure.id / line.slug),
        "--runs",
        str(runs),
        "--total-timesteps",
        str(options.steps),
        "--seed",
        str(options.seed),
        "--sample",  # first, so that run i draws the first reproduction's learning rate
        f"learning-rate=loguniform:{low:g}:{high:g}",
    ]
    for sample in line.samples:
        command += ["--sample", sample]
    command += ["--backend", options.backend]
    for flag, value in (
        ("--device", options.device),
        ("--address", options.address),
        ("--cpus", options.cpus),
        ("--max-concurrent", options.max_concurrent),
    ):
        if value is not None:
            command += [flag, str(value)]
    command += ["--", *line.argv, "--eval-interval", str(eval_interval(options.steps))]
    if options.num_workers is not None:
        command += ["--num-workers", str(options.num_workers)]
    return command


def steps_text(steps: int | str) -> str:
    return steps if isinstance(steps, str) else f"{steps:,}"


def eval_interval(steps: int | str) -> int | str:
    """Steps between evaluations: steps / 20; for a dry run's placeholder, "STEPS/20"."""
    if isinstance(steps, str):
        return f"{steps}/{EVALUATIONS_PER_RUN}"
    return max(1, steps // EVALUATIONS_PER_RUN)


def plot_commands(figure: Figure, options: argparse.Namespace) -> list[tuple[list[str], Path]]:
    """plot_sweep.py's commands (without the interpreter) and the PNG each writes."""
    out = Path(options.out)
    tables = [str(out / folder(figure, line) / "results.csv") for line in figure.lines]
    low, high = options.lr_range
    workers = options.num_workers or 1
    title = (
        f"Thesis Figure {figure.number} as run: {plural(options.runs, 'run')} per line, lr in "
        f"[{low:g}, {high:g}], {steps_text(options.steps)} steps, {plural(workers, 'worker')} "
        f"({THESIS_BUDGET})"
    )
    commands = []
    for plot in figure.plots:
        png = out / figure.id / f"{figure.id}{plot.suffix}.png"
        command = [*PLOT, *tables, "--labels", *(line.label for line in figure.lines)]
        command += ["--out", str(png), "--title", title]
        if plot.x != "learning-rate":
            command += ["--x", plot.x]
        if plot.y is not None:
            command += ["--y", plot.y]
        if plot.bar_range is not None:
            command += ["--bar-range", *(f"{v:g}" for v in plot.bar_range)]
        for label, value in figure.numbers:
            command += ["--reference", f"{label}={value:g}"]
        commands.append((command, png))
    return commands


def run_figures(figures: list[Figure], options: argparse.Namespace) -> int:
    """Sweep every line of the figures (in rounds of --round runs), then draw each figure."""
    step = options.round or options.runs
    sweeps = [
        figure_sweeps.Sweep(
            f"{figure.id} {line.label}",
            Path(folder(figure, line)),
            functools.partial(sweep_command, *run_as(figure, line), options),
            f" (the runs of {folder(figure, line)})" if line.same_as else "",
        )
        for figure in figures
        for line in figure.lines
    ]
    rounds = [*range(step, options.runs, step), options.runs]
    return figure_sweeps.run_sweeps(
        sweeps, rounds, "run", lambda: [draw(f, options) for f in figures]
    )


def draw(figure: Figure, options: argparse.Namespace) -> None:
    """Plot a figure's lines and write OUT/FIG/FIG.md: the tables, the thesis, the notes."""
    out = Path(options.out)
    missing = [
        line.label
        for line in figure.lines
        if not (out / folder(figure, line) / "results.csv").exists()
    ]
    if missing:
        print(f"{figure.id}: no results for {', '.join(missing)}; not plotted", file=sys.stderr)
        return
    tables = []
    for command, png in plot_commands(figure, options):
        code, stdout = execute(command, capture=True)
        if code == 0:
            table = [row for row in stdout.splitlines() if not row.startswith("wrote ")]
            tables.append(f"![{figure.id}]({png.name})\n\n" + "\n".join(table))
    summary = [
        f"# Thesis Figure {figure.number}, as run: {figure.caption}",
        "",
        f"Command: `{shlex.join(['python', '-m', 'a3c_tools.thesis_figures', *options.argv])}`",
        "",
        *tables,
        "",
        f"Thesis: {figure.thesis}",
        "",
        "Lines:",
        *(
            f"- {line.label}: `{line.script} {line.flags}` ({line.source})"
            + (f"; its runs are {line.same_as}'s, the same configuration" if line.same_as else "")
            for line in figure.lines
        ),
        *approximations(figure),
    ]
    if figure.note:
        summary += ["", f"Note: {figure.note}"]
    (out / figure.id / f"{figure.id}.md").write_text("\n".join(summary) + "\n")


def approximations(figure: Figure) -> list[str]:
    notes = [f"- {line.label}: {line.approximation}" for line in figure.lines if line.approximation]
    return ["", "Not exactly as run:", *notes] if notes else []


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def list_figures(figures: list[Figure]) -> str:
    """Every figure, its lines with their full flags, and the notes."""
    out = []
    for figure in figures:
        out += [f"{figure.id}  {figure.caption}", f"  thesis: {figure.thesis}"]
        if figure.note:
            out.append(f"  note: {figure.note}")
        for line in figure.lines:
            samples = "".join(f" --sample {sample}" for sample in line.samples)
            out.append(f"  - {line.label} [{line.slug}]: {line.script} {line.flags}{samples}")
            out.append(f"      as run: {line.source}")
            if line.same_as:
                out.append(f"      runs: {line.same_as}'s (the same configuration, run once)")
            if line.approximation:
                out.append(f"      NOT EXACT: {line.approximation}")
        out.append("")
    inexact = [
        f"  {figure.id} {line.label}: {line.approximation}"
        for figure in figures
        for line in figure.lines
        if line.approximation
    ]
    if inexact:
        out += ["Lines whose flags are the nearest to what ran, not exactly it:", *inexact, ""]
    out.append(
        "Every line also gets --eval-interval STEPS/20 (and --num-workers W when given); the "
        "learning rate is sampled log-uniform in --lr-range."
    )
    return "\n".join(out)


def lr_range(text: str) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW:HIGH, got {text!r}") from None
    if not (math.isfinite(high) and 0 < low < high):
        raise argparse.ArgumentTypeError(f"need 0 < LOW < HIGH, got {text!r}")
    return low, high


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = figure_sweeps.figure_parser(
        "thesis_figures",
        "%(prog)s FIG [FIG ...] --out OUT --runs N --steps S [options]\n"
        "       %(prog)s FIG [FIG ...] --dry-run [--out OUT] [--runs N] [--steps S] [options]\n"
        "       %(prog)s --list [FIG ...]",
        "Run a thesis Catch figure's lines as run, through a3c_tools.sweep, and draw it with "
        "a3c_tools.plot_sweep. See the module docstring for more.",
        figure_ids(),
        "the sweep and plot commands",
    )
    parser.add_argument("--out", default=None, help="the output folder (gets OUT/FIG/LINE)")
    parser.add_argument("--runs", type=positive_int, default=None, help="learning rates per line")
    parser.add_argument("--steps", type=positive_int, default=None, help="steps per run")
    parser.add_argument(
        "--lr-range",
        type=lr_range,
        default=DEFAULT_LR_RANGE,
        metavar="LOW:HIGH",
        help="learning rates log-uniform in [LOW, HIGH] (default 1e-5:1e-2; the thesis 1e-6:1e-2)",
    )
    parser.add_argument(
        "--seed", type=int, default=DEFAULT_SEED, help="the sweep seed (default 1, as sweep.py)"
    )
    parser.add_argument(
        "--num-workers",
        type=positive_int,
        default=None,
        help="workers per run (default: sweep.py's 1; the thesis ran 12)",
    )
    parser.add_argument(
        "--round",
        type=positive_int,
        default=None,
        metavar="K",
        help="run the lines in rounds of K more runs each (default: all runs of a line at once)",
    )
    figure_sweeps.add_backend_arguments(parser, batched=True, concurrent=True)
    options = parser.parse_args(argv)
    options.argv = list(argv)
    options.ids = figure_sweeps.chosen_figures(parser, options.figures, figure_ids())
    if not options.list:
        figure_sweeps.check_run_options(parser, options, figure_ids(), ["out", "runs", "steps"])
    return options


def dry_run(figure: Figure, options: argparse.Namespace) -> list[list[str]]:
    """A figure's commands: its lines' sweeps, then its plots."""
    sweeps = [sweep_command(*run_as(figure, line), options, options.runs) for line in figure.lines]
    return sweeps + [command for command, _ in plot_commands(figure, options)]


def main(argv: list[str] | None = None) -> int:
    code = figure_sweeps.data_or_exit(all_figures, "thesis_figures")
    if code is not None:
        return code
    options = parse_args(sys.argv[1:] if argv is None else argv)
    figures = [by_id(i) for i in options.ids] if options.ids else list(all_figures())
    return figure_sweeps.run_command(
        options, figures, list_figures, dry_run, "(the sweep above)", run_figures
    )


if __name__ == "__main__":
    run_main(main)
