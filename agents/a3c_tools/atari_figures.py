"""The thesis's Atari figures (6.9, 6.10, 7.8) as one command each: every line over seeds, drawn.

    python -m a3c_tools.atari_figures --list                 # the figures, games, lines, flags
    python -m a3c_tools.atari_figures fig6.9 --seeds 3 --steps 2000000 --out figures/atari
    python -m a3c_tools.atari_figures fig7.8 --seeds 3 --steps 2000000 --out figures/atari \\
        --games Breakout --lines ff lpq_fig78 glpq_fig78 --dry-run
    python -m a3c_tools.atari_figures all --out figures/atari --plot-only

Design. The figures, their games, lines (script and flags, the text's and the as-run forms where
they differ) and the thesis's numbers are data: atari_figures.toml beside this file (its header
gives the format). Each (figure, game, line) is one a3c_tools.sweep of a fixed configuration,
with no sampled flag: its run i is seed 1 + 1000 i (sweep.py's run seeds), in
OUT/FIG/GAME/LINE/runs/run-000i, so sweep.py's locking, resuming and Ray backend are reused:

    python -m a3c_tools.sweep agents/SCRIPT --out OUT/FIG/GAME/LINE --runs N \\
        --total-timesteps S --seed 1 -- --env GAMENoFrameskip-v4 COMMON FLAGS \\
        --eval-interval 1000000 --eval-episodes E --num-workers W

Resuming is sweep.py's: a run in the line's results.csv (finished) is skipped, one that was
interrupted goes on from its checkpoint.pt (`--resume`), and a folder holding another
configuration (other steps, flags, episodes or workers) is refused with one line (exit 2); a
larger --seeds adds seeds. A line that two figures share (A3C FF of 6.9 and 7.8) names the first
with `same_as`: its runs are made once, in that figure's folder.

Locally (the default) each run takes --num-workers workers (default: this machine's cores, as
the committed Atari runs did, so one run at a time uses every core), and the lines are run in
rounds of one seed each (seed 1 of every game and line, then seed 1001, ...), so that a stopped
figure has covered its lines evenly. With --backend ray each line's seeds run at once over the
cluster (sweep.py's Ray path; one line after the other). To split a figure over machines without
Ray, give each machine some --games or --lines into its own OUT and copy the folders together
before --plot-only.

Protocol. The thesis evaluated every 1M steps with 50 episodes (docs/thesis-notes.md, its
captions of Figures 6.9, 6.10 and 7.8) and averaged 5 runs per line. Here the interval is 1M
steps (--eval-interval) and the episodes per evaluation --eval-episodes (default 10, which keeps
the evaluator's share of a 2-core machine near 5%; the thesis: 50).

Drawing. OUT/FIG/FIG.png has one panel per game: each line is the mean over seeds of the
evaluation score against steps, the band the mean +- one standard error over seeds (the thesis's
shaded areas are standard errors), over the seeds with the most evaluations (a run under way
or cut short is left out of the curve, its label says how many) and at the steps each of them
has reached; the thesis's values read off its figure (where the data file has them) are
markers at the right edge, labelled "thesis, N M steps", and its statement is written under the
panels. OUT/FIG/curves.csv
holds the plotted values (figure, game, line, step, seeds, mean, se), OUT/FIG/results.csv a row
per run (figure, game, line, seed, final_score, final_step). A figure is drawn after its runs,
or from whatever runs exist with --plot-only. Each drawing also writes the line's every
evaluation to OUT/FIG/GAME/LINE/evaluations.csv (seed, global_step, mean_return, episodes) and
reads it back the next time: the run folders (runs/, with their checkpoints) are not committed,
so a line whose run folders are gone is still drawn; a run folder with an evaluation takes the
place of its seed's rows (it is the run that goes on).

Exit codes: 0 when done, 1 when some line's every run failed, 2 for bad arguments, a malformed
atari_figures.toml or a folder holding another configuration (nothing is created), 3 when a
run was in use elsewhere (resumed by hand; the same command goes on once it is free), 130 when
interrupted.
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import os
import shlex
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

from a3c_tools import AGENTS, figure_sweeps, run_main, sweep
from a3c_tools.figure_sweeps import DataError, display, plural, positive_int

DATA = Path(__file__).with_name("atari_figures.toml")
EVAL_INTERVAL = 1_000_000  # the thesis's: an evaluation every 1M steps
EVAL_EPISODES = 10  # the thesis: 50
THESIS_EPISODES = 50
SEED = 1  # sweep.py's default: run seeds 1, 1001, 2001, ...


@dataclass(frozen=True)
class Line:
    slug: str
    label: str
    script: str
    flags: str
    source: str
    same_as: str = ""

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.flags)


@dataclass(frozen=True)
class Number:
    """A value of the thesis's, read off its figure: [low, high] at steps."""

    game: str
    line: str
    low: float
    high: float
    steps: int
    note: str


@dataclass(frozen=True)
class Figure:
    id: str
    caption: str
    thesis: str
    games: tuple[str, ...]
    lines: tuple[Line, ...]
    numbers: tuple[Number, ...] = ()
    note: str = ""


@dataclass(frozen=True)
class Data:
    env: str
    common: str
    figures: tuple[Figure, ...]


# ------------------------------------------------------------------------------------------------
# The data file
# ------------------------------------------------------------------------------------------------
KEYS = {
    "file": {"env": str, "common": str, "figure": list},
    "figure": {"id": str, "caption": str, "thesis": str, "games": list, "line": list,
               "note?": str, "number?": list},
    "line": {"slug": str, "label": str, "script": str, "flags": str, "source": str,
             "same_as?": str},
    "number": {"game": str, "line": str, "low": (int, float), "high": (int, float),
               "steps": int, "note": str},
}  # fmt: skip


def read_figure(entry: object, file: str, index: int) -> Figure:
    figure = figure_sweeps.table(entry, KEYS["figure"], "figure", f"{file}: figure {index}")
    where = f"{file}: figure {figure['id']}"
    games = figure["games"]
    if not all(isinstance(g, str) and g.isidentifier() for g in games):
        raise DataError(f"{where}: games must be a list of names, got {games!r}")
    lines = []
    for i, raw in enumerate(figure["line"], 1):
        line = figure_sweeps.table(raw, KEYS["line"], "line", f"{where}, line {i}")
        at = f"{where}, line {line['slug']}"
        figure_sweeps.check_line(line, at)
        figure_sweeps.words(line["flags"], at)
        lines.append(Line(**line))
    slugs = [line.slug for line in lines]
    figure_sweeps.check_unique(slugs, "lines with slug", where)
    numbers = []
    for i, raw in enumerate(figure.get("number", []), 1):
        number = figure_sweeps.table(raw, KEYS["number"], "number", f"{where}, number {i}")
        if number["game"] not in games or number["line"] not in slugs:
            raise DataError(f"{where}, number {i}: no game {number['game']!r} or line "
                            f"{number['line']!r} in this figure")  # fmt: skip
        numbers.append(Number(**number))
    rest = {key: figure.get(key, "") for key in ("id", "caption", "thesis", "note")}
    return Figure(**rest, games=tuple(games), lines=tuple(lines), numbers=tuple(numbers))


def load_data(path: Path = DATA) -> Data:
    """The figures of a data file (atari_figures.toml), checked; a DataError if malformed."""
    file, data = figure_sweeps.read_file(path, KEYS["file"])
    if "{game}" not in data["env"]:
        raise DataError(f"{file}: env {data['env']!r} has no {{game}}")
    figure_sweeps.words(data["common"], f"{file}: common")
    figures = tuple(read_figure(entry, file, i) for i, entry in enumerate(data["figure"], 1))
    figure_sweeps.check_unique([figure.id for figure in figures], "figures with id", file)
    figure_sweeps.check_same_as(figures, file, other_runs)
    return Data(data["env"], data["common"], figures)


def other_runs(figure: Figure, line: Line, owner: Figure, target: Line) -> str | None:
    """What keeps a line from sharing the runs of target, its same_as (None: nothing)."""
    if (target.script, target.argv) != (line.script, line.argv):
        return "runs another script or other flags"
    if not set(figure.games) <= set(owner.games):
        return f"does not run every game of {figure.id}"
    return None


@functools.cache
def data() -> Data:
    return load_data(DATA)


def figure_ids() -> tuple[str, ...]:
    return tuple(figure.id for figure in data().figures)


def by_id(figure: str) -> Figure:
    return next(each for each in data().figures if each.id == figure)


# ------------------------------------------------------------------------------------------------
# Runs
# ------------------------------------------------------------------------------------------------
def run_as(figure: Figure, line: Line) -> tuple[str, Line]:
    """The figure id and line whose runs a line's are: its own, or its same_as line's."""
    owner, own = figure_sweeps.run_as(figure, line, by_id)
    return owner.id, own


def line_folder(out: Path, figure: Figure, game: str, line: Line) -> Path:
    fig, own = run_as(figure, line)
    return out / fig / game / own.slug


def sweep_command(
    figure: Figure, game: str, line: Line, options: argparse.Namespace, runs: int
) -> list[str]:
    """The sweep.py command of one line on one game (without the interpreter)."""
    _, own = run_as(figure, line)
    command = [*figure_sweeps.SWEEP, display(AGENTS / own.script), "--out"]
    command += [str(line_folder(Path(options.out), figure, game, line)), "--runs", str(runs)]
    seed = getattr(options, "seed", None) or SEED  # a campaign item may name its own
    command += ["--total-timesteps", str(options.steps), "--seed", str(seed)]
    command += ["--backend", options.backend]
    for flag, value in (("--address", options.address), ("--cpus", options.cpus)):
        if value is not None:
            command += [flag, str(value)]
    command += ["--", "--env", data().env.replace("{game}", game), *shlex.split(data().common)]
    command += [*own.argv, "--eval-interval", str(options.eval_interval)]
    command += ["--eval-episodes", str(options.eval_episodes)]
    return command + ["--num-workers", str(options.num_workers)]


def selected(figure: Figure, options: argparse.Namespace) -> tuple[list[str], list[Line]]:
    games = [g for g in figure.games if not options.games or g in options.games]
    lines = [line for line in figure.lines if not options.lines or line.slug in options.lines]
    return games, lines


def selected_runs(figure: Figure, options: argparse.Namespace) -> list[tuple[str, Line]]:
    """The selected (game, line) pairs of a figure, game by game."""
    games, lines = selected(figure, options)
    return [(game, line) for game in games for line in lines]


def run_figures(figures: list[Figure], options: argparse.Namespace) -> int:
    """Run every selected line of the figures, a seed of each at a time locally, then draw."""
    sweeps = [
        figure_sweeps.Sweep(
            f"{figure.id} {game} {line.label}",
            line_folder(Path(options.out), figure, game, line),
            functools.partial(sweep_command, figure, game, line, options),
        )
        for figure in figures
        for game, line in selected_runs(figure, options)
    ]
    rounds = list(range(1, options.seeds + 1)) if options.backend == "local" else [options.seeds]
    return figure_sweeps.run_sweeps(
        sweeps, rounds, "seed", lambda: [draw(f, options) for f in figures]
    )


# ------------------------------------------------------------------------------------------------
# Drawing
# ------------------------------------------------------------------------------------------------
KEPT = "evaluations.csv"  # a line's every evaluation; its run folders (runs/) are not committed
KEPT_COLUMNS = ["seed", "global_step", "mean_return", "episodes"]


def read_tables(folder: Path) -> dict[int, list[dict[str, str]]]:
    """seed -> a line's evaluations (KEPT_COLUMNS): its kept evaluations.csv, and each run folder
    with an evaluation (runs/run-*/evaluations.csv) in place of its seed's rows; run i has
    sweep.py's seed, line_seed + 1000 i. A DataError (one line) where a file is malformed."""
    tables: dict[int, list[dict[str, str]]] = {}
    kept = folder / KEPT
    if kept.exists():
        with kept.open(newline="") as f:
            try:
                for row in csv.DictReader(f):
                    _ = int(row["global_step"]), float(row["mean_return"])  # or the file's error
                    tables.setdefault(int(row["seed"]), []).append(row)
            except (KeyError, TypeError, ValueError) as error:
                raise DataError(f"{display(kept)} is malformed ({error!r}); "
                                f"columns: {', '.join(KEPT_COLUMNS)}") from error  # fmt: skip
    first = line_seed(folder)
    for path in sorted((folder / "runs").glob("run-*/evaluations.csv")):
        seed = first + sweep.SEED_STRIDE * int(path.parent.name.removeprefix("run-"))
        with path.open(newline="") as f:
            table = [{**row, "seed": str(seed)} for row in csv.DictReader(f)]
        if table:
            tables[seed] = table
    return dict(sorted(tables.items()))


def line_seed(folder: Path) -> int:
    """Run 0's seed of a line's sweep: its sweep.json's (a campaign item may name its own, as
    the confirmatory study's do), else sweep.py's default, SEED."""
    config = folder / sweep.CONFIG_NAME
    if not config.exists():
        return SEED
    try:
        seed = sweep.read_config(config).get("seed", SEED)
    except sweep.UsageError as error:
        raise DataError(str(error)) from error
    if type(seed) is not int:
        raise DataError(f"{display(config)}: its seed is {seed!r}, not a whole number")
    return seed


def keep_tables(folder: Path, tables: dict[int, list[dict[str, str]]]) -> None:
    """Write a line's evaluations to its kept evaluations.csv, all or nothing: a temp file of
    this process's own, flushed to disk, renamed over it (a full disk leaves the old file whole
    and raises the OSError)."""
    partial = folder / f"{KEPT}.{os.getpid()}.partial"
    try:
        with partial.open("w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(KEPT_COLUMNS)
            writer.writerows([row.get(c) or "" for c in KEPT_COLUMNS]
                             for table in tables.values() for row in table)  # fmt: skip
            f.flush()
            os.fsync(f.fileno())
        partial.replace(folder / KEPT)
    finally:
        partial.unlink(missing_ok=True)


def runs_of(
    tables: dict[int, list[dict[str, str]]], episodes: set[str] | None = None
) -> dict[int, list[tuple[int, float]]]:
    """seed -> [(step, mean return)] of a line's tables. Adds the episodes per evaluation to
    episodes."""
    runs = {}
    for seed, table in tables.items():
        runs[seed] = [(int(r["global_step"]), float(r["mean_return"])) for r in table]
        if episodes is not None:
            episodes.update(r.get("episodes") or "?" for r in table)
    return runs


def furthest(runs: dict[int, list[tuple[int, float]]]) -> dict[int, list[tuple[int, float]]]:
    """The runs of a line with the most evaluations: the curve is theirs, since a run under way
    (or cut short) would otherwise end every seed's curve at the step it has reached."""
    full = max((len(rows) for rows in runs.values()), default=0)
    return {seed: rows for seed, rows in runs.items() if len(rows) == full}


def curve(runs: dict[int, list[tuple[int, float]]]) -> list[tuple[int, int, float, float]]:
    """(step, seeds, mean, standard error) at each step every run has reached."""
    by_step: dict[int, list[float]] = {}
    for rows in runs.values():
        for step, value in rows:
            by_step.setdefault(step, []).append(value)
    points = []
    for step in sorted(by_step):
        values = by_step[step]
        if len(values) < len(runs):
            continue
        mean = sum(values) / len(values)
        n = len(values)
        se = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1) / n) if n > 1 else 0.0
        points.append((step, n, mean, se))
    return points


def draw(figure: Figure, options: argparse.Namespace) -> Path | None:
    """OUT/FIG/FIG.png, curves.csv and results.csv from the runs there are; None when none."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(options.out) / figure.id
    games, lines = selected(figure, options)
    episodes: set[str] = set()
    folders = {(g, line.slug): line_folder(Path(options.out), figure, g, line)
               for g in games for line in lines}  # fmt: skip
    tables = {key: read_tables(folder) for key, folder in folders.items()}
    if not any(tables.values()):
        print(f"{figure.id}: no runs in {display(out)}; not drawn", file=sys.stderr)
        return None
    for key, folder in folders.items():
        if tables[key]:
            keep_tables(folder, tables[key])
    found = {key: runs_of(table, episodes) for key, table in tables.items()}
    out.mkdir(parents=True, exist_ok=True)
    results, curves = [], []
    fig, axes = plt.subplots(1, len(games), figsize=(6.4 * len(games), 4.8), squeeze=False)
    for ax, game in zip(axes[0], games, strict=True):
        top = 0
        for i, line in enumerate(lines):
            runs = found[game, line.slug]
            for seed, rows in sorted(runs.items()):
                step, value = rows[-1]
                results.append([figure.id, game, line.slug, seed, value, step])
            drawn = furthest(runs)
            points = curve(drawn)
            curves += [[figure.id, game, line.slug, *point] for point in points]
            if not points:
                continue
            steps = [p[0] / 1e6 for p in points]
            means, ses = [p[2] for p in points], [p[3] for p in points]
            top = max(top, steps[-1])
            colour = f"C{i}"
            behind = len(runs) - len(drawn)
            label = f"{line.label} ({plural(len(drawn), 'seed')}" + (
                f"; {behind} more under way or cut short)" if behind else ")"
            )
            ax.plot(steps, means, color=colour, marker="o", label=label)
            low = [m - s for m, s in zip(means, ses, strict=True)]
            high = [m + s for m, s in zip(means, ses, strict=True)]
            ax.fill_between(steps, low, high, color=colour, alpha=0.2, linewidth=0)
        for number in figure.numbers:
            if number.game != game or number.line not in [line.slug for line in lines]:
                continue
            i = [line.slug for line in lines].index(number.line)
            mid, half = (number.low + number.high) / 2, (number.high - number.low) / 2
            label = (
                f"thesis, {number.steps / 1e6:g}M steps: {number.low:g}-{number.high:g} "
                f"({lines[i].label}, {number.note})"
            )
            x = (top or 1) * (1.03 + 0.02 * i)  # beside the curves; apart from each other
            ax.errorbar([x], [mid], yerr=[half], color=f"C{i}", marker="D", capsize=4,
                        linestyle="none", label=label)  # fmt: skip
        ax.set_title(game)
        ax.set_xlabel("steps (millions)")
        ax.set_ylabel("mean score per evaluation")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
        if not any(found[game, line.slug] for line in lines):
            ax.text(0.5, 0.5, "no runs yet", transform=ax.transAxes, ha="center", color="grey")
        if top == 0:  # step 0 or nothing: matplotlib would span +-0.04 M steps around it
            ax.set_xlim(-0.05, 1.1)  # the thesis's markers sit at 1.03 to 1.07
    title = textwrap.wrap(  # one panel holds about 80 characters of the title's size
        f"Thesis Figure {figure.id.removeprefix('fig')}: the mean over seeds, shaded +- one "
        f"standard error over seeds; {'/'.join(sorted(episodes))} episodes per evaluation (the "
        f"thesis: 5 runs, {THESIS_EPISODES} episodes per evaluation)",
        80 * len(games),
    )
    fig.suptitle("\n".join(title), fontsize=10)
    fig.text(0.01, 0.01, f"thesis: {figure.thesis}", fontsize=7, wrap=True)
    fig.tight_layout(rect=(0, 0.08, 1, 1))  # the suptitle is laid out with the panels
    png = out / f"{figure.id}.png"
    fig.savefig(png, dpi=100)
    plt.close(fig)
    write_csv(out / "results.csv", ["figure", "game", "line", "seed", "final_score",
                                    "final_step"], results)  # fmt: skip
    write_csv(out / "curves.csv", ["figure", "game", "line", "step", "seeds", "mean", "se"], curves)
    print(f"wrote {display(png)}, {display(out / 'results.csv')}, {display(out / 'curves.csv')}")
    return png


def write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows([f"{v:.6g}" if isinstance(v, float) else v for v in row] for row in rows)


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def list_figures(figures: list[Figure]) -> str:
    out = [f"every line: --env {data().env} {data().common} [flags]", ""]
    for figure in figures:
        out += [f"{figure.id}  {figure.caption}  (games: {', '.join(figure.games)})"]
        out += [f"  thesis: {figure.thesis}"]
        if figure.note:
            out.append(f"  note: {figure.note}")
        for line in figure.lines:
            out.append(f"  - {line.label} [{line.slug}]: {line.script} {line.flags}".rstrip())
            out.append(f"      source: {line.source}")
            if line.same_as:
                out.append(f"      runs: {line.same_as}'s (the same configuration, run once)")
        for n in figure.numbers:
            out.append(f"  thesis {n.game} {n.line}: {n.low:g}-{n.high:g} at {n.steps:,} steps "
                       f"({n.note})")  # fmt: skip
        out.append("")
    out.append(
        f"Every run also gets --eval-interval {EVAL_INTERVAL} --eval-episodes E (the thesis: "
        f"{THESIS_EPISODES}) --num-workers W, and from sweep.py --total-timesteps, --seed and "
        "--run-dir."
    )
    return "\n".join(out)


def parse_args(argv: list[str]) -> argparse.Namespace:
    from a3c_tools.sweep import cpu_count

    cores = cpu_count()
    parser = figure_sweeps.figure_parser(
        "atari_figures",
        "%(prog)s FIG [FIG ...] --out OUT --seeds N --steps S [options]\n"
        "       %(prog)s FIG [FIG ...] --out OUT --plot-only\n"
        "       %(prog)s FIG [FIG ...] --dry-run [--out OUT] [--seeds N] [--steps S] [options]\n"
        "       %(prog)s --list [FIG ...]",
        "Run a thesis Atari figure's lines over seeds through a3c_tools.sweep and draw it. See "
        "the module docstring for more.",
        figure_ids(),
        "the commands",
    )
    parser.add_argument("--plot-only", action="store_true", help="draw the runs there are")
    parser.add_argument("--out", default=None, help="the output folder (gets OUT/FIG/GAME/LINE)")
    parser.add_argument("--seeds", type=positive_int, default=None, help="runs per line")
    parser.add_argument("--steps", type=positive_int, default=None, help="steps per run")
    parser.add_argument("--games", nargs="+", default=None, help="only these games")
    parser.add_argument("--lines", nargs="+", default=None, help="only these lines (slugs)")
    parser.add_argument(
        "--eval-episodes",
        type=positive_int,
        default=EVAL_EPISODES,
        help=f"episodes per evaluation (default {EVAL_EPISODES}; the thesis {THESIS_EPISODES})",
    )
    parser.add_argument(
        "--eval-interval",
        type=positive_int,
        default=EVAL_INTERVAL,
        help=f"steps between evaluations (default {EVAL_INTERVAL:,}, the thesis's)",
    )
    parser.add_argument(
        "--num-workers",
        type=positive_int,
        default=cores,
        help=f"workers per run (default: this machine's cores, {cores})",
    )
    figure_sweeps.add_backend_arguments(parser)
    options = parser.parse_args(argv)
    options.ids = figure_sweeps.chosen_figures(parser, options.figures, figure_ids())
    figures = [by_id(i) for i in options.ids] or list(data().figures)
    games = list(dict.fromkeys(g for figure in figures for g in figure.games))
    if options.games:
        by_name = {g.lower(): g for g in games}
        for game in options.games:
            if game.lower() not in by_name:
                named = ", ".join(options.ids) or "the figures"
                parser.error(f"unknown game {game!r} for {named}; valid: {', '.join(games)}")
        options.games = [by_name[g.lower()] for g in options.games]
    if options.lines:
        slugs = list(dict.fromkeys(line.slug for figure in figures for line in figure.lines))
        for slug in options.lines:
            if slug not in slugs:
                parser.error(f"unknown line {slug!r}; valid: {', '.join(slugs)}")
    if options.list:
        return options
    figure_sweeps.check_run_options(
        parser, options, figure_ids(), ["out"] if options.plot_only else ["out", "seeds", "steps"]
    )
    return options


def dry_run(figure: Figure, options: argparse.Namespace) -> list[list[str]]:
    """A figure's commands: a sweep per selected game and line."""
    runs = selected_runs(figure, options)
    return [sweep_command(figure, game, line, options, options.seeds) for game, line in runs]


def main(argv: list[str] | None = None) -> int:
    code = figure_sweeps.data_or_exit(data, "atari_figures")
    if code is not None:
        return code
    options = parse_args(sys.argv[1:] if argv is None else argv)
    figures = [by_id(i) for i in options.ids] if options.ids else list(data().figures)
    if options.plot_only and not options.list:
        try:
            drawn = [draw(figure, options) for figure in figures]
        except DataError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        except OSError as error:  # a full disk, say: keep_tables left every kept file whole
            print(f"error: {error}; the kept evaluations.csv files are unchanged", file=sys.stderr)
            return 1
        return 0 if any(drawn) else 1
    return figure_sweeps.run_command(
        options, figures, list_figures, dry_run, "(the runs above)", run_figures
    )


if __name__ == "__main__":
    run_main(main)
