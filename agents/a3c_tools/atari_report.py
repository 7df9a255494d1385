"""The Atari lines across seeds and games, with rliable: docs/atari.md's "Across seeds and games".

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
the mean of the middle half of the runs' scores) and the mean, each with a 95% stratified
bootstrap interval (rliable's get_interval_estimates: seeds resampled within each game,
percentile intervals). Per game: the mean raw score over seeds with a 95% bootstrap interval, and
each seed's score. `--figure` draws the lines' performance profiles (rliable's
create_performance_profile: the fraction of runs scoring above each normalised score tau, with
its 95% band) with rliable's plot_utils.

rliable draws its resamples from NumPy's global generator (StratifiedBootstrap ignores its
random_state), so each estimate here is made under np.random.seed(--seed), the generator's
state restored afterwards: the same input gives the same intervals. Bad input (a missing run
folder or evaluation, an unknown game) is one line, exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3c_tools import ROOT, run_main

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

CONFIG = Path(__file__).with_name("atari_report.toml")
MARK_SLACK = 1_000  # an evaluation this many steps past a mark or fewer is the mark's
INTERVAL_REPS = 50_000  # rliable's default resamples for get_interval_estimates
PROFILE_REPS = 2_000  # and for create_performance_profile
CONFIDENCE = 0.95


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
    iqm: tuple[float, float, float] = (math.nan,) * 3  # (point, low, high), human-normalised
    mean: tuple[float, float, float] = (math.nan,) * 3
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
        with open(config, "rb") as f:
            data = tomllib.load(f)
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ReportError(f"{config}: {e}") from None
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


@contextlib.contextmanager
def seeded(seed: int) -> Iterator[None]:
    """NumPy's global generator seeded (rliable resamples with it), its state kept."""
    state = np.random.get_state()  # noqa: NPY002 (rliable's resamples use the legacy generator)
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


def t_interval(scores: list[float]) -> tuple[float, float]:
    """The 95% Student-t interval of the mean of a few seeds' scores ((nan, nan) for one)."""
    from scipy import stats

    if len(scores) < 2:
        return math.nan, math.nan
    mean, half = float(np.mean(scores)), float(stats.sem(scores))
    half *= float(stats.t.ppf(0.5 + CONFIDENCE / 2, len(scores) - 1))
    return mean - half, mean + half


def score_matrix(line: Line) -> np.ndarray:
    """rliable's (runs x games) matrix of human-normalised scores."""
    return np.array([g.normalised for g in line.games]).T


def estimate(lines: list[Line], reps: int | None, seed: int) -> None:
    """Each line's IQM and mean over games and seeds and each game's mean over seeds, with
    their 95% stratified bootstrap intervals (rliable), into the lines."""
    from rliable import library as rly
    from rliable import metrics

    def iqm_and_mean(scores: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_iqm(scores), metrics.aggregate_mean(scores)])

    def mean(scores: np.ndarray) -> np.ndarray:
        return np.array([metrics.aggregate_mean(scores)])

    reps = reps or INTERVAL_REPS
    for line in lines:
        with seeded(seed):
            points, intervals = rly.get_interval_estimates(
                {line.label: score_matrix(line)}, iqm_and_mean, reps=reps,
                confidence_interval_size=CONFIDENCE,
            )  # fmt: skip
        point, (low, high) = points[line.label], intervals[line.label]
        line.iqm = (point[0], low[0], high[0])
        line.mean = (point[1], low[1], high[1])
        game_means = []
        for game in line.games:
            with seeded(seed):
                points, intervals = rly.get_interval_estimates(
                    {game.game: np.array(game.scores)[:, None]}, mean, reps=reps,
                    confidence_interval_size=CONFIDENCE,
                )  # fmt: skip
            (low,), (high,) = intervals[game.game]
            game_means.append((float(points[game.game][0]), float(low), float(high)))
        line.game_means = tuple(game_means)


def steps_text(step: int | str) -> str:
    return "the final evaluation" if step == "final" else f"the evaluation at {step / 1e6:g}M steps"


def link(folder: Path, links_from: Path) -> str:
    return Path(os.path.relpath(folder / "evaluations.csv", links_from.resolve())).as_posix()


def render(games: dict[str, tuple[float, float]], lines: list[Line], links_from: Path) -> str:
    """The report's three Markdown tables: per line, per line and game, the normalisation."""
    out = [
        "| line | games x seeds | IQM, human-normalised [95% CI] "
        "| mean, human-normalised [95% CI] |",
        "|---|---|---:|---:|",
    ]
    for line in lines:
        names = ", ".join(g.game for g in line.games)
        iqm, mean = line.iqm, line.mean
        out.append(
            f"| {line.label} | {names} x {len(line.games[0].scores)} "
            f"| {iqm[0]:.2f} [{iqm[1]:.2f}, {iqm[2]:.2f}] "
            f"| {mean[0]:.2f} [{mean[1]:.2f}, {mean[2]:.2f}] |"
        )
    out += [
        "",
        "| line | game | a run's score | seeds' scores (seed 1 / 2 / ...) "
        "| mean [95% bootstrap CI] | [95% t CI] | human-normalised, per seed |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for line in lines:
        for game, (point, low, high) in zip(line.games, line.game_means, strict=True):
            seeds = " / ".join(
                f"[{score:.1f}]({link(folder, links_from)})"
                for score, folder in zip(game.scores, game.folders, strict=True)
            )
            normalised = " / ".join(f"{n:.2f}" for n in game.normalised)
            t_low, t_high = t_interval(game.scores)
            t_text = "-" if math.isnan(t_low) else f"[{t_low:.1f}, {t_high:.1f}]"
            out.append(
                f"| {line.label} | {game.game} | {steps_text(game.step)} | {seeds} "
                f"| {point:.1f} [{low:.1f}, {high:.1f}] | {t_text} | {normalised} |"
            )
    out += ["", "| game | random | human |", "|---|---:|---:|"]
    out += [f"| {game} | {random:g} | {human:g} |" for game, (random, human) in games.items()]
    return "\n".join(out) + "\n"


def plot_profile(lines: list[Line], path: Path, reps: int | None, seed: int) -> None:
    """The lines' performance profiles (score distributions over runs and games) with their
    95% stratified bootstrap bands, drawn by rliable's plot_utils."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import library as rly
    from rliable import plot_utils

    scores = {
        f"{line.label}: {', '.join(g.game for g in line.games)} x {len(line.games[0].scores)} "
        "seeds": score_matrix(line)
        for line in lines
    }
    top = max(float(m.max()) for m in scores.values())
    tau = np.linspace(0.0, max(1.5, math.ceil(top * 1.05)), 601)
    with seeded(seed):
        profiles, bands = rly.create_performance_profile(
            scores, tau, reps=reps or PROFILE_REPS, confidence_interval_size=CONFIDENCE
        )
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    colours = {label: f"C{i}" for i, label in enumerate(scores)}
    plot_utils.plot_performance_profiles(
        profiles, tau, performance_profile_cis=bands, colors=colours, ax=ax,
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
        "Performance profile, v4 NoFrameskip, with 95% stratified bootstrap bands",
        fontsize="medium",
    )
    ax.legend(loc="upper right", fontsize="medium", frameon=False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m a3c_tools.atari_report",
        description="The Atari lines across seeds and games with rliable: the IQM and mean of "
        "human-normalised scores with 95%% stratified bootstrap intervals, per game the mean "
        "over seeds, and a performance-profile figure.",
    )
    parser.add_argument(
        "--config", type=Path, default=CONFIG, help="the lines (default: atari_report.toml)"
    )
    parser.add_argument("-o", "--output", type=Path, help="write the tables here, not stdout")
    parser.add_argument("--figure", type=Path, help="draw the performance profile (a PNG) here")
    parser.add_argument(
        "--reps",
        type=int,
        help=f"bootstrap resamples of every interval and band (default: rliable's, "
        f"{INTERVAL_REPS:,} for the intervals, {PROFILE_REPS:,} for the profile's band)",
    )
    parser.add_argument("--seed", type=int, default=0, help="the resamples' seed (default 0)")
    parser.add_argument(
        "--links-from",
        type=Path,
        help="make the links to each run's evaluations.csv relative to this folder (default: "
        "the output's folder, or the repository root on stdout)",
    )
    options = parser.parse_args(argv)
    if options.reps is not None and options.reps < 1:
        print(f"error: --reps must be >= 1 (got {options.reps})", file=sys.stderr)
        return 2
    try:
        games, lines = load(options.config)
    except ReportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    estimate(lines, options.reps, options.seed)
    links_from = options.links_from or (options.output.parent if options.output else ROOT)
    text = render(games, lines, links_from)
    if options.output:
        options.output.parent.mkdir(parents=True, exist_ok=True)
        options.output.write_text(text)
    else:
        print(text, end="")
    if options.figure:
        plot_profile(lines, options.figure, options.reps, options.seed)
    return 0


if __name__ == "__main__":
    run_main(main)
