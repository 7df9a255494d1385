"""Tests of a3c_tools.atari_figures (the thesis's Atari figures 6.9, 6.10 and 7.8 as one command
each) and of its data file agents/a3c_tools/atari_figures.toml.

--list and --dry-run are checked against the data file; every line's sweep is checked by
sweep.py's own dry run (which checks every flag against the script); bad arguments exit 2 with
one line and create nothing; the runs, their resuming and refusal are run through sweep.py with
a stand-in agent script; the drawing is checked on synthetic evaluations.csv files. The slow
test trains a tiny real Breakout line.
"""

import csv
import json
import math
import shlex
import shutil
import textwrap
from pathlib import Path

import pytest
from a3c_tools import atari_figures as figures
from a3c_tools import sweep
from conftest import ROOT, run_main

COMMON = "--envs-per-worker 16 --t-max 5 --optim-eps 1e-5 --rms-init 1 --weight-init he"


def run_tool(*args: str, cwd: Path = ROOT):
    return run_main(figures.main, list(args), cwd)


def sweeps(stdout: str) -> list[list[str]]:
    return [shlex.split(row) for row in stdout.splitlines() if row.startswith("python -m")]


# ------------------------------------------------------------------------------------------------
# The data file, --list and --dry-run
# ------------------------------------------------------------------------------------------------
def test_the_figures_games_and_lines():
    assert figures.figure_ids() == ("fig6.9", "fig6.10", "fig7.8")
    games = {figure.id: figure.games for figure in figures.data().figures}
    assert games == {"fig6.9": ("BeamRider", "Breakout"), "fig6.10": ("Pong",),
                     "fig7.8": ("Breakout", "BeamRider")}  # fmt: skip
    slugs = {figure.id: [line.slug for line in figure.lines] for figure in figures.data().figures}
    assert slugs == {"fig6.9": ["ff", "lws", "ww"], "fig6.10": ["vf1.0", "vf0.5"],
                     "fig7.8": ["ff", "lpq", "lpq_fig78", "glpq", "glpq_fig78",
                                "glpq_as_run"]}  # fmt: skip
    assert figures.data().common == COMMON
    assert figures.by_id("fig7.8").lines[0].same_as == "fig6.9/ff"


def test_list_names_every_figure_line_and_flag():
    result = run_tool("--list")
    assert result.returncode == 0, result.stderr
    for text in ("fig6.9", "fig6.10", "fig7.8", "a3c_lws.py", "a3c_ww.py", "--vf-coef 1.0",
                 "--vf-coef 0.5", "--prototypes-per-action 15 --competition-size 10",
                 "--temperature cold --mu-form code", "4000-4300", COMMON,
                 "--eval-interval 1000000"):  # fmt: skip
        assert text in result.stdout, text


def test_a_dry_run_needs_only_the_figure(tmp_path):
    result = run_tool("fig7.8", "--games", "Breakout", "--dry-run", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    rows = result.stdout.splitlines()
    assert rows[0] == "# OUT stands for --out, SEEDS stands for --seeds, STEPS stands for --steps"
    command = shlex.split(next(row for row in rows if row.startswith("python -m a3c_tools.sweep")))
    assert command[command.index("--runs") + 1] == "SEEDS"
    assert command[command.index("--total-timesteps") + 1] == "STEPS"
    assert list(tmp_path.iterdir()) == []
    real = run_tool("fig7.8", "--seeds", "1", cwd=tmp_path)
    assert real.returncode == 2 and "required: --out, --steps" in real.stderr


@pytest.mark.parametrize("figure", ["fig6.9", "fig6.10", "fig7.8"])
def test_dry_run_prints_a_sweep_per_game_and_line(figure, tmp_path):
    out = tmp_path / "out"
    result = run_tool(figure, "--seeds", "3", "--steps", "2000000", "--out", str(out),
                      "--dry-run", "--num-workers", "2")  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert not out.exists()
    commands = sweeps(result.stdout)
    fig = figures.by_id(figure)
    assert len(commands) == len(fig.games) * len(fig.lines)
    for command, (game, line) in zip(
        commands, [(g, line) for g in fig.games for line in fig.lines], strict=True
    ):
        own = command[: command.index("--")]
        after = command[command.index("--") + 1 :]
        owner = line.same_as.split("/")[0] if line.same_as else figure
        slug = line.same_as.split("/")[1] if line.same_as else line.slug
        assert own[3] == f"agents/{line.script}"
        assert own[own.index("--out") + 1] == str(out / owner / game / slug)
        assert own[own.index("--runs") + 1] == "3"
        assert own[own.index("--total-timesteps") + 1] == "2000000"
        assert after == ["--env", f"{game}NoFrameskip-v4", *COMMON.split(), *line.argv,
                         "--eval-interval", "1000000", "--eval-episodes", "10",
                         "--num-workers", "2"]  # fmt: skip
    if figure == "fig6.10":
        assert [sweep.flag_value(c, "vf-coef") for c in commands] == ["1.0", "0.5"]


def test_a_shared_line_is_marked_and_games_and_lines_select(tmp_path):
    result = run_tool("fig6.9", "fig7.8", "--seeds", "1", "--steps", "10", "--out", "o",
                      "--dry-run", "--games", "breakout", "--lines", "ff",
                      "glpq_fig78")  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = [row for row in result.stdout.splitlines() if not row.startswith("# fig")]
    assert len(rows) == 3 and rows[1].startswith("# (the runs above)")
    assert all("BreakoutNoFrameskip-v4" in row for row in rows)
    assert "o/fig7.8/Breakout/glpq_fig78" in rows[2]


def test_every_line_is_accepted_by_its_script(capsys):
    """sweep.py's dry run checks every flag against the script (its Args)."""
    seen = set()
    for figure in figures.data().figures:
        for game in figure.games:
            for line in figure.lines:
                options = figures.parse_args([figure.id, "--seeds", "1", "--steps", "10",
                                              "--out", "/nonexistent/o"])  # fmt: skip
                command = figures.sweep_command(figure, game, line, options, 1)[2:]
                if shlex.join(command) in seen:
                    continue
                seen.add(shlex.join(command))
                code = sweep.main([*command[: command.index("--")], "--dry-run",
                                   *command[command.index("--") :]])  # fmt: skip
                assert code == 0, (figure.id, game, line.slug, capsys.readouterr().err)
    assert len(seen) == 2 * 3 + 2 + 2 * 5  # FF of 7.8 is 6.9's


# ------------------------------------------------------------------------------------------------
# Bad input
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "args, message",
    [
        (["fig9.9", "--seeds", "3", "--steps", "10"], "valid: fig6.9, fig6.10, fig7.8, all"),
        (["fig6.10", "--seeds", "3", "--steps", "10", "--games", "Breakout"], "valid: Pong"),
        (["fig6.9", "--seeds", "0", "--steps", "10"], "must be >= 1"),
        (["fig6.9", "--seeds", "3", "--steps", "10", "--lines", "lpq"], "valid: ff, lws, ww"),
        (["fig6.9", "--seeds", "3"], "--steps"),
        (["--seeds", "3", "--steps", "10"], "name a figure"),
    ],
)
def test_bad_arguments_exit_2_with_one_line_and_create_nothing(tmp_path, args, message):
    result = run_tool(*args, "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_malformed_data_file_exits_2_with_one_line(tmp_path, monkeypatch):
    text = figures.DATA.read_text()
    for old, new, message in [
        ('slug = "lws"', 'slug = "ff"', "two lines with slug 'ff'"),
        ('games = ["Pong"]', "games = 3", "games must be a list"),
        (
            'caption = "A3C FF, LWS and WW on Beam Rider (a) and Breakout (b)"',
            'caption = ""',
            "figure 1: no caption",
        ),
        ('same_as = "fig6.9/ff"', 'same_as = "fig6.9/nope"', "is no FIG/SLUG"),
        ('script = "a3c_ww.py"', 'script = "a3c_zz.py"', "is not in"),
        ('[[figure]]\nid = "fig6.9"', '[[figure]\nid = "fig6.9"', "atari_figures.toml"),
    ]:
        data = tmp_path / "atari_figures.toml"
        assert old in text
        data.write_text(text.replace(old, new, 1))
        monkeypatch.setattr(figures, "data", lambda data=data: figures.load_data(data))
        result = run_tool("fig6.9", "--seeds", "1", "--steps", "10", "--out", str(tmp_path / "o"),
                          "--dry-run")  # fmt: skip
        assert result.returncode == 2, old
        assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr, old
        assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------------
# Runs: through sweep.py, with a stand-in agent
# ------------------------------------------------------------------------------------------------
FAKE_AGENT = textwrap.dedent(
    """
    import argparse, json, os

    parser = argparse.ArgumentParser()
    for flag in ("--env", "--t-max", "--vf-coef", "--eval-interval", "--eval-episodes",
                 "--num-workers", "--total-timesteps", "--seed", "--run-dir", "--resume"):
        parser.add_argument(flag)
    args = parser.parse_args()
    here = os.path.dirname(os.path.abspath(__file__))
    if args.resume:  # the run's own flags, from its checkpoint
        run_dir = os.path.dirname(args.resume)
        saved = json.load(open(args.resume))
    else:
        run_dir, saved = args.run_dir, vars(args)
    with open(os.path.join(here, "starts.log"), "a") as f:
        f.write(f"{os.path.basename(run_dir)} {'resume' if args.resume else 'start'}\\n")
    json.dump(saved, open(os.path.join(run_dir, "checkpoint.pt"), "w"))
    total, interval = int(saved["total_timesteps"]), int(saved["eval_interval"])
    level = float(saved["vf_coef"]) * 10 + int(saved["seed"]) % 7
    with open(os.path.join(run_dir, "evaluations.csv"), "w") as f:
        f.write("global_step,wall_time_s,mean_return,std_return,episodes\\n")
        for step in [*range(0, total, interval), total]:
            f.write(f"{step},0.1,{level * step / total},0.0,{saved['eval_episodes']}\\n")
    """
)

FAKE_DATA = textwrap.dedent(
    """
    env = "{game}NoFrameskip-v4"
    common = "--t-max 5"

    [[figure]]
    id = "fig6.10"
    caption = "lambda_V"
    thesis = "1.0 does not learn"
    games = ["Pong"]

    [[figure.line]]
    slug = "vf1.0"
    label = "lambda_V = 1.0"
    script = "a3c_ff.py"
    flags = "--vf-coef 1.0"
    source = "as run"

    [[figure.line]]
    slug = "vf0.5"
    label = "lambda_V = 0.5"
    script = "a3c_ff.py"
    flags = "--vf-coef 0.5"
    source = "the text"

    [[figure.number]]
    game = "Pong"
    line = "vf0.5"
    low = 5
    high = 7
    steps = 10000000
    note = "read off the figure"
    """
)


@pytest.fixture
def fake(tmp_path, monkeypatch):
    """The tool with a data file of one figure (6.10) whose script is the stand-in agent."""
    agents = tmp_path / "agents"
    agents.mkdir()
    (agents / "a3c_ff.py").write_text(FAKE_AGENT)
    (tmp_path / "atari_figures.toml").write_text(FAKE_DATA)
    monkeypatch.setattr(figures, "AGENTS", agents)
    loaded = figures.load_data(tmp_path / "atari_figures.toml")
    monkeypatch.setattr(figures, "data", lambda: loaded)
    return agents


def starts(agents: Path) -> list[str]:
    log = agents / "starts.log"
    return log.read_text().splitlines() if log.exists() else []


def test_runs_resume_skip_the_finished_and_refuse_another_configuration(fake, tmp_path, capfd):
    out = tmp_path / "out"
    args = ["fig6.10", "--out", str(out), "--eval-interval", "100", "--num-workers", "1",
            "--eval-episodes", "2"]  # fmt: skip
    assert run_tool(*args, "--steps", "300", "--seeds", "1").returncode == 0
    assert starts(fake) == ["run-0000 start", "run-0000 start"]  # one seed of each line
    # an interrupted second seed of lambda_V 1.0: a checkpoint, no row in the table
    run = out / "fig6.10" / "Pong" / "vf1.0" / "runs" / "run-0001"
    run.mkdir(parents=True)
    flags = {"total_timesteps": "300", "eval_interval": "100", "vf_coef": "1.0", "seed": "1001",
             "eval_episodes": "2"}  # fmt: skip
    (run / "checkpoint.pt").write_text(json.dumps(flags))
    (fake / "starts.log").unlink()
    assert run_tool(*args, "--steps", "300", "--seeds", "2").returncode == 0
    assert sorted(starts(fake)) == ["run-0001 resume", "run-0001 start"]  # finished: skipped
    with (out / "fig6.10" / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["line"], r["seed"], r["final_step"]) for r in rows] == [
        ("vf1.0", "1", "300"), ("vf1.0", "1001", "300"), ("vf0.5", "1", "300"),
        ("vf0.5", "1001", "300")]  # fmt: skip
    assert float(rows[1]["final_score"]) == pytest.approx(10 * 1.0 + 1001 % 7)
    (fake / "starts.log").unlink()
    capfd.readouterr()
    result = run_tool(*args, "--steps", "400", "--seeds", "2")  # another budget
    assert result.returncode == 2
    errors = [row for row in capfd.readouterr().err.splitlines() if row.strip()]
    assert len(errors) == 1 and "total_timesteps" in errors[0], errors
    assert starts(fake) == []


def test_curves_are_the_mean_and_standard_error_over_seeds(fake, tmp_path):
    out = tmp_path / "out"
    # run 3 under way (or cut short): the curve is the three runs that reached the last step
    returns = {0: [0.0, 2.0, 4.0], 1: [0.0, 4.0, 8.0], 2: [0.0, 6.0, 12.0], 3: [0.0]}
    for index, values in returns.items():
        run = out / "fig6.10" / "Pong" / "vf0.5" / "runs" / f"run-{index:04d}"
        run.mkdir(parents=True)
        rows = [f"{step * 1000000},1.0,{v},0.0,10" for step, v in enumerate(values)]
        (run / "evaluations.csv").write_text("global_step,wall_time_s,mean_return,std_return,"
                                             "episodes\n" + "\n".join(rows) + "\n")  # fmt: skip
    result = run_tool("fig6.10", "--out", str(out), "--plot-only")
    assert result.returncode == 0, result.stderr
    assert (out / "fig6.10" / "fig6.10.png").stat().st_size > 0
    with (out / "fig6.10" / "curves.csv").open() as f:
        curves = list(csv.DictReader(f))
    assert [(r["line"], r["step"], r["seeds"]) for r in curves] == [
        ("vf0.5", "0", "3"),
        ("vf0.5", "1000000", "3"),
        ("vf0.5", "2000000", "3"),
    ]
    assert float(curves[1]["mean"]) == pytest.approx(4.0)
    assert float(curves[1]["se"]) == pytest.approx(2.0 / math.sqrt(3))  # std 2 over 3 seeds
    assert float(curves[2]["mean"]) == pytest.approx(8.0)
    with (out / "fig6.10" / "results.csv").open() as f:
        results = [(r["seed"], r["final_score"], r["final_step"]) for r in csv.DictReader(f)]
    assert results == [("1", "4", "2000000"), ("1001", "8", "2000000"), ("2001", "12", "2000000"),
                       ("3001", "0", "0")]  # fmt: skip


def test_a_line_whose_run_folders_are_gone_is_drawn_from_its_kept_evaluations(fake, tmp_path):
    out = tmp_path / "out"
    line = out / "fig6.10" / "Pong" / "vf0.5"
    header = "global_step,wall_time_s,mean_return,std_return,episodes\n"
    for index, values in {0: [0.0, 2.0], 1: [0.0, 4.0]}.items():
        run = line / "runs" / f"run-{index:04d}"
        run.mkdir(parents=True)
        rows = [f"{step * 1000000},1.0,{v},0.0,10" for step, v in enumerate(values)]
        (run / "evaluations.csv").write_text(header + "\n".join(rows) + "\n")
    assert run_tool("fig6.10", "--out", str(out), "--plot-only").returncode == 0
    drawn = {name: (out / "fig6.10" / name).read_text() for name in ("curves.csv", "results.csv")}
    with (line / "evaluations.csv").open() as f:
        kept = [(r["seed"], r["global_step"], r["mean_return"], r["episodes"])
                for r in csv.DictReader(f)]  # fmt: skip
    assert kept == [("1", "0", "0.0", "10"), ("1", "1000000", "2.0", "10"),
                    ("1001", "0", "0.0", "10"), ("1001", "1000000", "4.0", "10")]  # fmt: skip
    shutil.rmtree(line / "runs")  # a new checkout: the run folders are not committed
    assert run_tool("fig6.10", "--out", str(out), "--plot-only").returncode == 0
    assert {name: (out / "fig6.10" / name).read_text() for name in drawn} == drawn
    # seed 1001 started again: its run folder takes the place of its kept rows
    run = line / "runs" / "run-0001"
    run.mkdir(parents=True)
    (run / "evaluations.csv").write_text(header)  # begun, no evaluation yet: the kept rows stay
    assert run_tool("fig6.10", "--out", str(out), "--plot-only").returncode == 0
    assert {name: (out / "fig6.10" / name).read_text() for name in drawn} == drawn
    (run / "evaluations.csv").write_text(header + "0,1.0,-1.0,0.0,10\n")
    assert run_tool("fig6.10", "--out", str(out), "--plot-only").returncode == 0
    assert sorted(p.name for p in line.iterdir()) == ["evaluations.csv", "runs"]  # no temp file
    with (out / "fig6.10" / "results.csv").open() as f:
        results = [(r["seed"], r["final_score"], r["final_step"]) for r in csv.DictReader(f)]
    assert results == [("1", "2", "1000000"), ("1001", "-1", "0")]
    with (out / "fig6.10" / "curves.csv").open() as f:  # seed 1001 under way: seed 1's curve
        assert [(r["step"], r["seeds"], r["mean"]) for r in csv.DictReader(f)] == [
            ("0", "1", "0"),
            ("1000000", "1", "2"),
        ]


@pytest.mark.parametrize("seed", [7800, "7800", None])
def test_a_line_swept_from_its_own_seed_names_its_runs_by_their_seeds(fake, tmp_path, seed):
    """A campaign item may sweep a line from a seed of its own (the confirmatory study's 7800):
    its run i is seed 7800 + 1000 i, as its sweep.json says, not sweep.py's default 1 + 1000 i
    (which would name the study's runs by seeds of other committed runs). A seed that is not a
    whole number stops the drawing with one line, exit 2."""
    out = tmp_path / "out"
    line = out / "fig6.10" / "Pong" / "vf0.5"
    header = "global_step,wall_time_s,mean_return,std_return,episodes\n"
    for index in (0, 2):
        run = line / "runs" / f"run-{index:04d}"
        run.mkdir(parents=True)
        (run / "evaluations.csv").write_text(header + f"0,1.0,{index}.0,0.0,10\n")
    config = {"script": "a3c_ff.py", "samples": [], "total_timesteps": 2000000}
    (line / "sweep.json").write_text(json.dumps({**config, "seed": seed} if seed else config))
    result = run_tool("fig6.10", "--out", str(out), "--plot-only")
    if seed == "7800":
        errors = [row for row in result.stderr.splitlines() if row.strip()]
        assert result.returncode == 2 and len(errors) == 1 and "'7800'" in errors[0], errors
        assert not (out / "fig6.10" / "fig6.10.png").exists()
        return
    assert result.returncode == 0, result.stderr
    with (out / "fig6.10" / "results.csv").open() as f:
        seeds = [r["seed"] for r in csv.DictReader(f)]
    with (line / "evaluations.csv").open() as f:
        kept = [r["seed"] for r in csv.DictReader(f)]
    expected = ["7800", "9800"] if seed else ["1", "2001"]  # no seed in sweep.json: sweep's 1
    assert seeds == kept == expected


def test_a_malformed_kept_evaluations_file_exits_2_with_one_line(fake, tmp_path):
    line = tmp_path / "out" / "fig6.10" / "Pong" / "vf0.5"
    line.mkdir(parents=True)
    kept = "seed,global_step,mean_return,episodes\n1,0,0.5,10\n"
    (line / "evaluations.csv").write_text(kept + "<<<<<<< HEAD\n")  # a merge left half done
    result = run_tool("fig6.10", "--out", str(tmp_path / "out"), "--plot-only")
    errors = [row for row in result.stderr.splitlines() if row.strip()]
    assert result.returncode == 2
    assert len(errors) == 1 and "evaluations.csv is malformed" in errors[0], errors
    assert (line / "evaluations.csv").read_text() == kept + "<<<<<<< HEAD\n"
    assert not (tmp_path / "out" / "fig6.10" / "fig6.10.png").exists()


def test_plot_only_without_runs_exits_1_and_draws_nothing(fake, tmp_path):
    result = run_tool("fig6.10", "--out", str(tmp_path / "o"), "--plot-only")
    assert result.returncode == 1 and "no runs" in result.stderr
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------------------------------------
# A tiny real line
# ------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_a_tiny_real_breakout_line(tmp_path):
    out = tmp_path / "out"
    result = run_tool("fig7.8", "--games", "Breakout", "--lines", "glpq_fig78", "--seeds", "2",
                      "--steps", "2000", "--eval-interval", "2000", "--eval-episodes", "1",
                      "--num-workers", "1", "--out", str(out))  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    with (out / "fig7.8" / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["seed"], int(r["final_step"]) >= 2000) for r in rows] == [
        ("1", True),
        ("1001", True),
    ]
