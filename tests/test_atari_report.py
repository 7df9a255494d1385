"""Tests of a3c_tools.atari_report (the Atari lines across seeds and games): the human
normalisation by hand, the evaluation that scores a run, the IQM and the t intervals against a
hand computation, no interval below 3 seeds, the report on the committed runs, bad input, and
the page's tables against the tool's."""

import csv

import numpy as np
import pytest
from a3c_tools import atari_report as report
from a3c_tools import read_toml
from conftest import ROOT, run_main
from scipy import stats

# the tools extra; imported here, once (arch, pandas, statsmodels: about 1.5 s), not in a test
pytest.importorskip("rliable.library")


def write_evaluations(folder, rows):
    folder.mkdir(parents=True)
    with open(folder / "evaluations.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["global_step", "wall_time_s", "mean_return", "std_return", "episodes"])
        for step, value in rows:
            writer.writerow([step, 1.0, value, 0.0, 10])


def write_config(path, games, lines):
    """A report TOML: games {name: (random, human)}, lines [(label, {game: (step, folders)})]."""
    text = ""
    for name, (random, human) in games.items():
        text += f"[games.{name}]\nrandom = {random}\nhuman = {human}\n\n"
    for label, runs in lines:
        text += f'[[line]]\nlabel = "{label}"\n'
        for game, (step, folders) in runs.items():
            step = f'"{step}"' if step == "final" else step
            names = ", ".join(f'"{folder}"' for folder in folders)
            text += f"[line.games.{game}]\nstep = {step}\nruns = [{names}]\n"
    path.write_text(text)
    return path


def test_normalisation_by_hand():
    # Breakout: random 1.7, human 30.5; Pong: random -20.7, human 14.6
    assert report.normalise(1.7, 1.7, 30.5) == 0.0
    assert report.normalise(30.5, 1.7, 30.5) == 1.0
    assert report.normalise(349.0, 1.7, 30.5) == pytest.approx(347.3 / 28.8)
    assert report.normalise(-20.7, -20.7, 14.6) == 0.0
    assert report.normalise(20.3, -20.7, 14.6) == pytest.approx(41.0 / 35.3)
    assert report.normalise(-21.0, -20.7, 14.6) < 0  # below random play


def test_a_run_is_scored_by_the_evaluation_taken_at_its_mark(tmp_path):
    rows = [(0, -21.0), (4_500_080, 18.5), (5_000_080, 20.3), (5_500_000, 20.9)]
    write_evaluations(tmp_path / "run", rows)
    read = report.read_evaluations(tmp_path / "run")
    assert read == [(step, value) for step, value in rows]
    # the 5M mark's evaluation, taken 80 steps past it by the worker update that reached it
    assert report.score_at(read, 5_000_000) == (5_000_080, 20.3)
    assert report.score_at(read, 4_500_000) == (4_500_080, 18.5)
    assert report.score_at(read, 0) == (0, -21.0)
    assert report.score_at(read, "final") == (5_500_000, 20.9)
    assert report.score_at(read, 3_000_000) is None  # the next one, 4.5M, is not 3M's
    assert report.score_at(read, 6_000_000) is None  # past the run's end
    # and through the TOML, with a line of one game and one seed
    config = write_config(
        tmp_path / "r.toml",
        {"Pong": (-20.7, 14.6)},
        [("x", {"Pong": (5_000_000, [tmp_path / "run"])})],
    )
    games, lines = report.load(config)
    assert lines[0].games[0].scores == [20.3]
    assert lines[0].games[0].normalised == [pytest.approx(41.0 / 35.3)]


def test_the_iqm_is_the_mean_of_the_middle_half(tmp_path):
    # 2 games x 4 seeds, random 0 and human 1 so that scores are their normalised scores:
    # sorted, the 8 values are 0.1 0.2 0.5 0.7 0.9 1.5 3.0 9.0; the middle half is 0.5 0.7 0.9 1.5
    values = {"A": [0.5, 9.0, 0.1, 1.5], "B": [0.7, 0.2, 3.0, 0.9]}
    runs = {}
    for game, scores in values.items():
        folders = []
        for seed, score in enumerate(scores):
            folder = tmp_path / f"{game}{seed}"
            write_evaluations(folder, [(0, 0.0), (1000, score)])
            folders.append(folder)
        runs[game] = ("final", folders)
    config = write_config(tmp_path / "r.toml", {"A": (0, 1), "B": (0, 1)}, [("l", runs)])
    _, lines = report.load(config)
    assert report.score_matrix(lines[0]).shape == (4, 2)  # rliable's runs x games
    report.estimate(lines)
    line = lines[0]
    assert line.iqm == pytest.approx((0.5 + 0.7 + 0.9 + 1.5) / 4)
    assert line.mean[0] == pytest.approx(sum(values["A"] + values["B"]) / 8)
    # the line's mean: a t interval over the 4 seeds' means over the 2 games
    per_seed = (np.array(values["A"]) + np.array(values["B"])) / 2
    expected = stats.t.interval(0.95, 3, loc=per_seed.mean(), scale=stats.sem(per_seed))
    assert line.mean[1:] == pytest.approx(expected)
    # a game's mean: a t interval over its 4 seeds
    game = np.array(values["A"])
    expected = stats.t.interval(0.95, 3, loc=game.mean(), scale=stats.sem(game))
    assert line.game_means[0] == pytest.approx((game.mean(), *expected))


def test_below_three_seeds_no_interval_is_given(tmp_path):
    folders = []
    for seed, score in enumerate([10.0, 30.0]):
        folders.append(tmp_path / f"run{seed}")
        write_evaluations(folders[-1], [(0, 0.0), (1000, score)])
    config = write_config(tmp_path / "r.toml", {"A": (0, 100)}, [("l", {"A": ("final", folders)})])
    done = run_main(report.main, ["--config", str(config)])
    assert done.returncode == 0, done.stderr
    assert "| 20.0 (no interval below 3 seeds) |" in done.stdout
    assert "| 0.20 (no interval below 3 seeds) |" in done.stdout
    assert "[" not in done.stdout.split("| A | the final evaluation |")[1].split(") |")[-1]


def committed_score(folder, step):
    with open(ROOT / folder / "evaluations.csv", newline="") as f:
        rows = [(int(r["global_step"]), r["mean_return"]) for r in csv.DictReader(f)]
    return next(value for global_step, value in rows if step <= global_step <= step + 1000)


def test_the_report_on_the_committed_runs_gives_their_scores(tmp_path):
    figure = tmp_path / "profile.png"
    done = run_main(report.main, ["--figure", str(figure)])
    assert done.returncode == 0, done.stderr
    assert figure.stat().st_size > 10_000
    config = read_toml(report.CONFIG)
    line = config["line"][0]
    normalised = []
    for game, spec in line["games"].items():
        random, human = config["games"][game]["random"], config["games"][game]["human"]
        cells = []
        for folder in spec["runs"]:
            value = committed_score(folder, spec["step"])  # the evaluations.csv text, as is
            cells.append(f"[{float(value):.1f}]({folder}/evaluations.csv)")
            normalised.append((float(value) - random) / (human - random))
        assert " / ".join(cells) in done.stdout, game
    # Breakout's final evaluations and Pong's at 5M steps, seeds 1 / 2 / 3
    assert "[349.0](" in done.stdout and "[411.9](" in done.stdout and "[15.6](" in done.stdout
    middle = sorted(normalised)[1:-1]  # 6 runs: the 25% trimmed mean drops one at each end
    assert f"| {line['label']} | Breakout, Pong x 3 | {np.mean(middle):.2f} | " in done.stdout
    assert f"| {np.mean(normalised):.2f} [" in done.stdout
    assert "| 375.9 [295.4, 456.4] |" in done.stdout  # Breakout: a t interval, not the seeds'
    assert "bootstrap" not in done.stdout
    assert "| Breakout | 1.7 | 30.5 |" in done.stdout and "| Pong | -20.7 | 14.6 |" in done.stdout


@pytest.mark.parametrize(
    ("runs", "message"),
    [
        (["results/no_such_run"], "no_such_run: no such run folder"),
        (["results/pong_a3c_ff"], "no evaluation at step 7000000"),  # Pong's 5M run: no 7M
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(tmp_path, runs, message):
    config = write_config(
        tmp_path / "r.toml", {"Pong": (-20.7, 14.6)}, [("x", {"Pong": (7_000_000, runs)})]
    )
    done = run_main(report.main, ["--config", str(config)])
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error: ")
    assert message in done.stderr


def test_a_game_without_normalisation_scores_is_refused(tmp_path):
    write_evaluations(tmp_path / "run", [(0, 1.0)])
    config = write_config(
        tmp_path / "r.toml",
        {"Pong": (-20.7, 14.6)},
        [("x", {"Qbert": ("final", [tmp_path / "run"])})],
    )
    done = run_main(report.main, ["--config", str(config)])
    assert done.returncode == 2 and "no random and human scores for Qbert" in done.stderr


@pytest.mark.slow
def test_the_atari_page_and_the_committed_report_hold_the_tools_tables():
    """The page's tables and the committed report are the tool's."""
    done = run_main(report.main, ["--links-from", "docs"])
    assert done.returncode == 0, done.stderr
    assert done.stdout in (ROOT / "docs" / "atari.md").read_text(), (
        "docs/atari.md is stale: python -m a3c_tools.atari_report --links-from docs"
    )
    folder = ROOT / "results" / "atari_report"
    committed = run_main(report.main, ["--links-from", str(folder)])
    assert (folder / "report.md").read_text() == committed.stdout
