"""The Atari lines across seeds and games: docs/atari.md's "Across seeds and games".

    python -m a3c_tools.atari_report                      # the tables, Markdown, on stdout
    python -m a3c_tools.atari_report -o results/atari_report/report.md \\
        --figure results/atari_report/performance_profile.png

The lines are data: agents/a3c_tools/atari_report.toml (`--config` another), per line and game
the committed run folders (one per seed) and the step whose evaluation scores a run. A run's
score is its evaluation (mean_return of its evaluations.csv) taken at that step: the first
evaluation at or after it, within MARK_SLACK steps, since the evaluator takes it at the worker
update that reaches the mark (5,000,080 for 5M at 2 workers x 16 envs x t_max 5), or its last
evaluation with step = "final".

Scores are human-normalised per game, (score - random) / (human - random), with the random and
human scores the TOML gives. Per line, over its games and seeds: the interquartile mean (IQM,
the mean of the middle half of the runs' scores, rliable's aggregate_iqm) and the mean, the
mean with a 95% Student-t interval over seeds (of each seed's mean over the games). Per game:
the mean raw score over seeds with its 95% t interval, and each seed's score. No interval is
given below MIN_SEEDS seeds, and none for the IQM: a bootstrap (rliable's stratified one, or a
percentile interval of a game's mean) over 3 seeds does not hold its level; with 3 seeds a
percentile bootstrap's interval is the lowest and highest seed. The t interval's coverage is
exact for normal scores at any number of seeds (a3c_tools.paired gives the method). `--figure`
draws the lines' performance profiles (the fraction of runs scoring above each normalised
score tau, as rliable's create_performance_profile computes it, without its bootstrap band)
with rliable's plot_utils.

The report is deterministic: nothing is resampled. Bad input (a missing run folder or
evaluation, an unknown game) is one line, exit code 2.
"""

from __future__ import annotations

import csv
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3c_tools import ATARI_REPORT_CONFIG, ROOT, read_toml, run_main, tool_parser
from a3c_tools.paired import MIN_PAIRS

CONFIG = ATARI_REPORT_CONFIG
MARK_SLACK = 1_000  # an evaluation this many steps past a mark or fewer is the mark's
CONFIDENCE = 0.95
MIN_SEEDS = MIN_PAIRS  # fewer seeds: no interval


class ReportError(Exception):
    """Bad input: reported as one line, exit code 2."""


@dataclass
class GameRuns:
    """One game of one line: its runs (one per seed) and each run's score."""

    game: str
    step: int | str  # the mark whose evaluation scores a run, or "final"
    folders: list[Path]
    scores: list[float]  # raw game scores, one per run
    normalised: list[float]


@dataclass
class Line:
    label: str
    games: list[GameRuns]
    iqm: float = math.nan  # human-normalised
    mean: tuple[float, float, float] = (math.nan,) * 3  # (point, low, high), human-normalised
    game_means: tuple[tuple[float, float, float], ...] = ()  # per game, raw scores


def normalise(score: float, random: float, human: float) -> float:
    """The human-normalised score: 0 at random play, 1 at the human score."""
    return (score - random) / (human - random)


def read_evaluations(folder: Path) -> list[tuple[int, float]]:
    """(global_step, mean_return) of each evaluation of a run folder, in its order."""
    path = folder / "evaluations.csv"
    if not folder.is_dir():
        raise ReportError(f"{folder}: no such run folder")
    if not path.is_file():
        raise ReportError(f"{path}: no such file")
    try:
        with open(path, newline="") as f:
            rows = [(int(r["global_step"]), float(r["mean_return"])) for r in csv.DictReader(f)]
    except (KeyError, TypeError, ValueError) as e:
        raise ReportError(f"{path}: not an evaluations.csv ({e!r})") from None
    if not rows:
        raise ReportError(f"{path}: no evaluations")
    return rows


def score_at(rows: list[tuple[int, float]], step: int | str) -> tuple[int, float] | None:
    """The evaluation (global_step, mean_return) that scores a run at `step`: the first at or
    after it and at most MARK_SLACK steps past it, or the last with step "final"; None if the
    run has none there."""
    if step == "final":
        return rows[-1]
    for global_step, value in rows:
        if global_step >= step:
            return (global_step, value) if global_step - step <= MARK_SLACK else None
    return None


def resolve(folder: str) -> Path:
    """A run folder as the TOML names it: relative to the repository, or absolute."""
    return (ROOT / folder).resolve()


def load(config: Path) -> tuple[dict[str, tuple[float, float]], list[Line]]:
    """The games' (random, human) scores and the lines, each run scored and normalised."""
    try:
        data = read_toml(config)
    except ValueError as e:
        raise ReportError(str(e)) from None
    try:
        games = {name: (float(g["random"]), float(g["human"])) for name, g in data["games"].items()}
        raw_lines = data["line"]
    except (KeyError, TypeError, ValueError) as e:
        raise ReportError(
            f"{config}: needs [games.<Game>] random, human and [[line]] ({e!r})"
        ) from None
    lines = []
    for raw in raw_lines:
        label = raw.get("label", "?")
        runs = []
        for game, spec in raw.get("games", {}).items():
            if game not in games:
                raise ReportError(
                    f"{config}: line {label!r}: no random and human scores for {game}"
                )
            step, folders = spec.get("step"), spec.get("runs")
            if not (step == "final" or (isinstance(step, int) and step >= 0)):
                raise ReportError(f"{config}: line {label!r}, {game}: step must be >= 0 or 'final'")
            if not folders:
                raise ReportError(f"{config}: line {label!r}, {game}: no runs")
            scores = []
            for folder in map(resolve, folders):
                found = score_at(read_evaluations(folder), step)
                if found is None:
                    raise ReportError(f"{folder}: no evaluation at step {step}")
                scores.append(found[1])
            random, human = games[game]
            normalised = [normalise(s, random, human) for s in scores]
            runs.append(GameRuns(game, step, [resolve(f) for f in folders], scores, normalised))
        if not runs:
            raise ReportError(f"{config}: line {label!r} has no games")
        if len({len(r.scores) for r in runs}) > 1:
            raise ReportError(
                f"{config}: line {label!r}: every game needs the same number of runs (seeds)"
            )
        lines.append(Line(label, runs))
    if not lines:
        raise ReportError(f"{config}: no [[line]]")
    return games, lines


def t_interval(scores: list[float] | np.ndarray) -> tuple[float, float]:
    """The 95% Student-t interval of the mean of a few seeds' scores ((nan, nan) below
    MIN_SEEDS)."""
    from scipy import stats

    if len(scores) < MIN_SEEDS:
        return math.nan, math.nan
    mean, half = float(np.mean(scores)), float(stats.sem(scores))
    half *= float(stats.t.ppf(0.5 + CONFIDENCE / 2, len(scores) - 1))
    return mean - half, mean + half


def score_matrix(line: Line) -> np.ndarray:
    """rliable's (runs x games) matrix of human-normalised scores."""
    return np.array([g.normalised for g in line.games]).T


def estimate(lines: list[Line]) -> None:
    """Each line's IQM and mean over games and seeds (the mean with its 95% t interval over
    seeds) and each game's mean over seeds with its 95% t interval, into the lines."""
    from rliable import metrics

    for line in lines:
        matrix = score_matrix(line)
        line.iqm = float(metrics.aggregate_iqm(matrix))
        per_seed = matrix.mean(axis=1)  # each seed's mean over the games
        line.mean = (float(per_seed.mean()), *t_interval(per_seed))
        line.game_means = tuple(
            (float(np.mean(game.scores)), *t_interval(game.scores)) for game in line.games
        )


def shown(point: float, low: float, high: float, digits: int) -> str:
    """A mean with its interval, "375.9 [295.4, 456.4]", or the mean alone with "(no interval:
    n seeds)" where there are too few seeds for one."""
    if math.isnan(low):
        return f"{point:.{digits}f} (no interval below {MIN_SEEDS} seeds)"
    return f"{point:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def steps_text(step: int | str) -> str:
    return "the final evaluation" if step == "final" else f"the evaluation at {step / 1e6:g}M steps"


def link(folder: Path, links_from: Path) -> str:
    return Path(os.path.relpath(folder / "evaluations.csv", links_from.resolve())).as_posix()


def render(games: dict[str, tuple[float, float]], lines: list[Line], links_from: Path) -> str:
    """The report's three Markdown tables: per line, per line and game, the normalisation."""
    out = [
        "| line | games x seeds | IQM, human-normalised (no interval) "
        "| mean, human-normalised [95% t CI over seeds] |",
        "|---|---|---:|---:|",
    ]
    for line in lines:
        names = ", ".join(g.game for g in line.games)
        out.append(
            f"| {line.label} | {names} x {len(line.games[0].scores)} "
            f"| {line.iqm:.2f} | {shown(*line.mean, 2)} |"
        )
    out += [
        "",
        "| line | game | a run's score | seeds' scores (seed 1 / 2 / ...) "
        "| mean [95% t CI] | human-normalised, per seed |",
        "|---|---|---|---:|---:|---:|",
    ]
    for line in lines:
        for game, mean in zip(line.games, line.game_means, strict=True):
            seeds = " / ".join(
                f"[{score:.1f}]({link(folder, links_from)})"
                for score, folder in zip(game.scores, game.folders, strict=True)
            )
            normalised = " / ".join(f"{n:.2f}" for n in game.normalised)
            out.append(
                f"| {line.label} | {game.game} | {steps_text(game.step)} | {seeds} "
                f"| {shown(*mean, 1)} | {normalised} |"
            )
    out += ["", "| game | random | human |", "|---|---:|---:|"]
    used = {g.game for line in lines for g in line.games}  # the table may hold others
    out += [f"| {game} | {random:g} | {human:g} |" for game, (random, human) in games.items()
            if game in used]  # fmt: skip
    return "\n".join(out) + "\n"


def plot_profile(lines: list[Line], path: Path) -> None:
    """The lines' performance profiles (score distributions over runs and games), drawn by
    rliable's plot_utils, without a band (a bootstrap band over 3 seeds a game does not hold
    its level)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    scores = {
        f"{line.label}: {', '.join(g.game for g in line.games)} x {len(line.games[0].scores)} "
        "seeds": score_matrix(line)
        for line in lines
    }
    top = max(float(m.max()) for m in scores.values())
    tau = np.linspace(0.0, max(1.5, math.ceil(top * 1.05)), 601)
    # the fraction of a line's runs scoring above each tau (rliable's score distribution)
    profiles = {label: (m.ravel()[None, :] > tau[:, None]).mean(axis=1)
                for label, m in scores.items()}  # fmt: skip
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    colours = {label: f"C{i}" for i, label in enumerate(scores)}
    plot_utils.plot_performance_profiles(
        profiles, tau, performance_profile_cis=None, colors=colours, ax=ax,
        xlabel=r"human-normalised score $\tau$", ylabel=r"fraction of runs with score $> \tau$",
        labelsize="large", ticklabelsize="medium",
    )  # fmt: skip
    ax.axvline(1.0, color="0.4", linestyle=":", linewidth=1.2)
    ax.annotate(" human", (1.0, 0.02), color="0.3", fontsize="medium")
    # each game named above the axis at its runs' mean normalised score, over every line
    per_game: dict[str, list[float]] = {}
    for line in lines:
        for game in line.games:
            per_game.setdefault(game.game, []).extend(game.normalised)
    games_axis = ax.secondary_xaxis("top")
    games_axis.set_xticks([float(np.mean(v)) for v in per_game.values()], labels=list(per_game))
    games_axis.tick_params(length=3, labelsize="medium", labelcolor="0.3")
    games_axis.spines["top"].set_visible(False)
    ax.set_title(
        "Performance profile, v4 NoFrameskip (no band: 3 seeds a game)",
        fontsize="medium",
    )
    ax.legend(loc="upper right", fontsize="medium", frameon=False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser(
        "atari_report",
        "The Atari lines across seeds and games: the IQM and mean of human-normalised scores, "
        "per game the mean over seeds, each mean with a 95% Student-t interval over seeds (none "
        "below 3 seeds, none for the IQM), and a performance-profile figure.",
    )
    parser.add_argument(
        "--config", type=Path, default=CONFIG, help="the lines (default: atari_report.toml)"
    )
    parser.add_argument("-o", "--output", type=Path, help="write the tables here, not stdout")
    parser.add_argument("--figure", type=Path, help="draw the performance profile (a PNG) here")
    parser.add_argument(
        "--links-from",
        type=Path,
        help="make the links to each run's evaluations.csv relative to this folder (default: "
        "the output's folder, or the repository root on stdout)",
    )
    options = parser.parse_args(argv)
    try:
        games, lines = load(options.config)
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    estimate(lines)
    links_from = options.links_from or (options.output.parent if options.output else ROOT)
    text = render(games, lines, links_from)
    if options.output:
        options.output.parent.mkdir(parents=True, exist_ok=True)
        options.output.write_text(text)
    else:
        print(text, end="")
    if options.figure:
        plot_profile(lines, options.figure)
    return 0


if __name__ == "__main__":
    run_main(main)
