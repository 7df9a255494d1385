"""Tests of a3c_tools.thesis_figures (every thesis Catch figure as one command), of its data file
agents/a3c_tools/thesis_figures.toml, and of a3c_tools.plot_sweep's --reference option.

Every line's flags are parsed by its own script (tyro), which then resolves its defaults and
builds its network, so that a flag a script lacks, or a network it cannot build, fails here
without training anything. A malformed data file is refused, naming the figure, the line and the
problem. The command's own behaviour (--list, --dry-run, errors, rounds, plots) is tested with
sweep.py's dry run and a stand-in for the sweeps; no agent is trained.
"""

import csv
import dataclasses
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import a3c_runtime as runtime
import pytest
from conftest import AGENTS, ROOT, load_script, run_into_a_closed_pipe, run_main

TOOL = ["-m", "a3c_tools.thesis_figures"]
REQUIRED = ["fig6.3", "fig6.5", "fig6.6", "fig6.7", "fig6.8", "fig7.1", "fig7.2", "fig7.3",
            "fig7.5", "fig7.6", "fig7.7", "figA.1", "figA.2", "figA.3", "figC.1"]  # fmt: skip
# set by the sweep for each run, or by thesis_figures.py for every line
NOT_LINE_FLAGS = {"total-timesteps", "seed", "run-dir", "runs-root", "resume", "evaluate",
                  "eval-interval", "num-workers", "learning-rate"}  # fmt: skip

from a3c_tools import figure_sweeps  # noqa: E402
from a3c_tools import plot_sweep as plot_sweep  # noqa: E402
from a3c_tools import sweep as sweep  # noqa: E402
from a3c_tools import thesis_figures as figures  # noqa: E402

LINES = [(figure, line) for figure in figures.all_figures() for line in figure.lines]


def agent(script: str):
    """The agent script a line runs (agents/<script>), loaded once per test session."""
    return load_script(Path(script).stem)


def flag_names(argv: list[str]) -> list[str]:
    return [word[2:].split("=")[0] for word in argv if word.startswith("--")]


def run_tool(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """`python -m a3c_tools.thesis_figures *args`, in process."""
    return run_main(figures.main, list(args), cwd)


# ------------------------------------------------------------------------------------------------
# The table
# ------------------------------------------------------------------------------------------------
def test_every_thesis_catch_figure_is_there():
    assert list(figures.figure_ids()) == REQUIRED


def test_the_table_is_consistent():
    for figure in figures.all_figures():
        slugs = [line.slug for line in figure.lines]
        labels = [line.label for line in figure.lines]
        assert len(set(slugs)) == len(slugs) and len(set(labels)) == len(labels), figure.id
        assert all(slug == Path(slug).name and " " not in slug for slug in slugs)
        assert {label for label, _ in figure.numbers} <= set(labels), figure.id
        assert figure.caption and figure.thesis, figure.id
        for line in figure.lines:
            where = f"{figure.id} {line.label}"
            assert (AGENTS / line.script).is_file(), where
            assert line.source, where
            names = flag_names(line.argv)
            assert not set(names) & NOT_LINE_FLAGS, where
            assert len(set(names)) == len(names), f"{where}: a flag given twice"
            for sample in line.samples:
                assert sweep.parse_sample(sample).name not in NOT_LINE_FLAGS, where
            assert not set(line.sample_names()) & set(names), where
            # lambda_V as run: 1.0 for the presets up to 69 (A3C FF variants, LWS), else 0.5
            expected_vf = "1.0" if line.script in ("a3c_ff.py", "a3c_lws.py") else "0.5"
            assert sweep.flag_value(line.argv, "vf-coef") == expected_vf, where
            if line.script == "a3c_glpq.py":  # every as-run GLPQ line: the code's mu
                assert sweep.flag_value(line.argv, "mu-form") == "code", where
        for plot in figure.plots:
            assert plot.x == "learning-rate" or all(
                plot.x in line.sample_names() for line in figure.lines
            ), figure.id
    # the one figure whose numbers the thesis gives
    assert dict(figures.by_id("fig7.6").numbers) == {
        "A3C FF": 0.73,
        "GLPQ cold": 0.77,
        "GLPQ hot": 0.78,
        "GLPQ searing": 0.81,
    }


@pytest.mark.parametrize(
    ("figure", "line"), LINES, ids=[f"{figure.id}-{line.slug}" for figure, line in LINES]
)
def test_every_line_is_accepted_by_its_script(figure, line, capsys):
    """The script parses the line's flags (and its sampled flags, with a value in range),
    resolves its defaults and builds its network."""
    import tyro

    import catch_env  # noqa: F401  (registers Catch-v0)

    module = agent(line.script)
    fields = {field.name for field in dataclasses.fields(module.Args)}
    sampled = []
    for name in ["learning-rate", *line.sample_names()]:
        assert name.replace("-", "_") in fields, f"{line.script} has no --{name}"
    for sample in line.samples:
        parsed = sweep.parse_sample(sample)
        sampled += [f"--{parsed.name}", parsed.draw(0.5)]
    argv = [*line.argv, *sampled, "--learning-rate", "1e-3", "--total-timesteps", "1000"]
    argv += ["--eval-interval", "50", "--num-workers", "1"]
    try:
        args = tyro.cli(module.Args, args=argv)
    except SystemExit:
        pytest.fail(f"{line.script} rejects {shlex.join(line.argv)}:\n{capsys.readouterr().err}")
    for word, value in zip(line.argv, line.argv[1:], strict=False):
        if word == "--temperature":  # spot checks that the flags took
            assert args.temperature == value
        if word == "--vf-coef":
            assert args.vf_coef == float(value)
    args = runtime.resolve_defaults(args)
    module.ActorCritic(3, args)  # network-level errors (UsageError) surface here


# ------------------------------------------------------------------------------------------------
# The data file
# ------------------------------------------------------------------------------------------------
MINIMAL = """
[flags]
FF = "--vf-coef 1.0"

[[figure]]
id = "fig6.7"
caption = "ELU against ReLU"
thesis = \"\"\"ELU is worse
    than ReLU.\"\"\"

[figure.numbers]
ELU = 0.5

[[figure.line]]
slug = "relu"
label = "ReLU"
script = "a3c_ff.py"
flags = "{FF} --activation relu"
source = "preset 13"

[[figure.line]]
slug = "elu"
label = "ELU"
script = "a3c_ff.py"
flags = "{FF} --activation elu"
samples = ["grad-clip=loguniform:0.5:40"]
source = "preset 4"
"""


def write_data(folder: Path, old: str = "", new: str = "", name: str = "figures.toml") -> Path:
    """MINIMAL in folder/name, its first old replaced by new."""
    assert old in MINIMAL
    path = folder / name
    path.write_text(MINIMAL.replace(old, new, 1))
    return path


def test_the_loader_reads_a_data_file(tmp_path):
    (figure,) = figures.load_figures(write_data(tmp_path))
    assert (figure.id, figure.caption, figure.note) == ("fig6.7", "ELU against ReLU", "")
    assert figure.thesis == "ELU is worse than ReLU."  # a line break reads as a space
    assert [line.flags for line in figure.lines] == [
        "--vf-coef 1.0 --activation relu",
        "--vf-coef 1.0 --activation elu",
    ]
    assert figure.lines[1].samples == ("grad-clip=loguniform:0.5:40",)
    assert figure.numbers == (("ELU", 0.5),)
    assert figure.plots == (figures.Plot(),)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('script = "a3c_ff.py"\n', "", "figure fig6.7, line 1 (ReLU): no script"),
        ('slug = "elu"\n', "", "figure fig6.7, line 2 (ELU): no slug"),
        ('slug = "elu"', 'slug = "elu"\nscrpit = "a3c_ff.py"',
         "line 2 (ELU): unknown key 'scrpit' (a line has slug, label, script,"),
        ('source = "preset 4"', "source = 4", "line 2 (ELU): source must be a string, got 4"),
        ('"a3c_ff.py"', '"a3c_fff.py"', "line 1 (ReLU): script 'a3c_fff.py' is not in"),
        ('slug = "relu"', 'slug = "a/relu"', "line 1 (ReLU): slug 'a/relu' is not a plain"),
        ('slug = "elu"', 'slug = "relu"', "figure fig6.7: two lines with slug 'relu'"),
        ("{FF} --activation elu", "{FX} --activation elu",
         "line 2 (ELU): flags name {FX}, which [flags] does not define"),
        ("--activation elu", "--activation 'elu", "line 2 (ELU): flags are not shell words"),
        ('["grad-clip=loguniform:0.5:40"]', '["grad-clip"]',
         "line 2 (ELU): samples must be NAME=DIST strings"),
        ("ELU = 0.5", "Elu = 0.5", "fig6.7: numbers name 'Elu', which is no line's label"),
        ("ELU = 0.5", 'ELU = "0.5"', "fig6.7: numbers: 'ELU' = '0.5' is not a number"),
        ('caption = "ELU against ReLU"\n', "", "figure 1: no caption"),
        ('caption = "ELU against ReLU"', 'caption = ""', "figure 1: no caption"),
        ('source = "preset 4"\n', 'source = "preset 4"\n\n[[figure.plot]]\nx = "tau"\n',
         "figure fig6.7, plot 1: x is 'tau', which not every line samples"),
        ("[flags]", "[flags", "Expected ']'"),
        ('source = "preset 13"', 'source = "preset 13"\nsame_as = "fig6.7/elx"',
         "line 'ReLU': same_as 'fig6.7/elx' is no FIG/SLUG of this file"),
        ('source = "preset 13"', 'source = "preset 13"\nsame_as = "fig6.7/elu"',
         "line 'ReLU': same_as 'fig6.7/elu' runs another script or samples other flags"),
    ],
)  # fmt: skip
def test_the_loader_refuses_a_malformed_data_file(tmp_path, old, new, message):
    path = write_data(tmp_path, old, new)
    with pytest.raises(figures.DataError, match=re.escape(message)) as error:
        figures.load_figures(path)
    assert str(error.value).startswith(f"{figures.display(path)}: ")


def test_a_line_of_the_scripts_defaults_has_empty_flags(tmp_path):
    """The one key that may be empty: flags, "" for the script's defaults (as atari_figures'
    lines are; both read their files with figure_sweeps.table)."""
    figure, *_ = figures.load_figures(write_data(tmp_path, '"{FF} --activation relu"', '""'))
    assert figure.lines[0].flags == "" and figure.lines[0].argv == []


def test_the_loader_refuses_a_chain_of_same_as(tmp_path):
    path = write_data(
        tmp_path, 'source = "preset 13"', 'source = "preset 13"\nsame_as = "fig6.7/elu"'
    )
    path.write_text(
        path.read_text().replace(
            'source = "preset 4"', 'source = "preset 4"\nsame_as = "fig6.7/relu"'
        )
    )
    with pytest.raises(figures.DataError, match="is itself same_as 'fig6.7/"):
        figures.load_figures(path)


SHARED = [(figure, line) for figure, line in LINES if line.same_as]


@pytest.mark.parametrize(
    ("figure", "line"), SHARED, ids=[f"{figure.id}-{line.slug}" for figure, line in SHARED]
)
def test_a_shared_line_has_the_configuration_of_the_line_it_names(figure, line):
    """A line that shows another figure's runs (same_as) parses, in its script, to the same Args
    as that line: the two are one configuration, so running it once is enough."""
    import tyro

    other_figure, other = figures.run_as(figure, line)
    assert other is not line and f"{other_figure.id}/{other.slug}" == line.same_as
    module = agent(line.script)
    common = ["--learning-rate", "1e-3", "--total-timesteps", "1000", "--seed", "3"]
    parsed = [
        runtime.resolve_defaults(tyro.cli(module.Args, args=[*each.argv, *common]))
        for each in (line, other)
    ]
    assert parsed[0] == parsed[1]


def test_a_malformed_data_file_stops_the_command_with_one_line(tmp_path, monkeypatch, capsys):
    """The command beside a data file whose line lacks its script: one line, exit 2; and
    importing the tool reads nothing (the file is read on first use)."""
    data = write_data(tmp_path, 'script = "a3c_ff.py"\n', "", name="thesis_figures.toml")
    monkeypatch.setattr(figures, "DATA", data)
    monkeypatch.setattr(figures.load_figures, "__defaults__", (data,))
    figures.all_figures.cache_clear()
    try:
        assert figures.main(["--list"]) == 2
    finally:
        figures.all_figures.cache_clear()
    out, err = capsys.readouterr()
    assert out == ""
    where = f"{figures.display(data)}: figure fig6.7, line 1 (ReLU)"
    assert err == f"thesis_figures: error: {where}: no script\n"


# ------------------------------------------------------------------------------------------------
# The command
# ------------------------------------------------------------------------------------------------
def test_figure_ids_are_read_loosely():
    assert figures.figure_id("fig7.6") == "fig7.6"
    assert figures.figure_id("7.6") == "fig7.6"
    assert figures.figure_id("Fig6.3") == "fig6.3"
    assert figures.figure_id("figa.1") == "figA.1"
    assert figures.figure_id("C.1") == "figC.1"
    assert figures.figure_id("fig9.9") is None
    assert figures.figure_id("fig6.4") is None  # an Atari or non-sweep figure


def test_list_names_every_figure_line_and_flag():
    result = run_tool("--list")
    assert result.returncode == 0, result.stderr
    for figure in figures.all_figures():
        assert f"{figure.id}  " in result.stdout
        for line in figure.lines:
            assert f"{line.label} [{line.slug}]: {line.script} {line.flags}" in result.stdout
            if line.approximation:
                assert line.approximation in result.stdout
    assert "nearest to what ran" in result.stdout
    only = run_tool("--list", "A.2")
    assert "figA.2" in only.stdout and "fig7.6" not in only.stdout


def test_dry_run_prints_the_sweeps_and_creates_nothing(tmp_path):
    out = tmp_path / "out"
    result = run_tool("--dry-run", "fig7.6", "--runs", "2", "--steps", "1000", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert not out.exists()
    commands = [shlex.split(row) for row in result.stdout.splitlines() if row.startswith("python")]
    figure = figures.by_id("fig7.6")
    assert len(commands) == len(figure.lines) + len(figure.plots)
    for command, line in zip(commands, figure.lines, strict=False):
        assert command[1:4] == ["-m", "a3c_tools.sweep", f"agents/{line.script}"]
        split = command.index("--")
        own, fixed = command[4:split], command[split + 1 :]
        assert own[own.index("--out") + 1] == str(out / figures.folder(figure, line))
        assert own[own.index("--runs") + 1] == "2"
        assert own[own.index("--total-timesteps") + 1] == "1000"
        assert own[own.index("--sample") + 1] == "learning-rate=loguniform:1e-05:0.01"
        assert fixed == [*figures.run_as(figure, line)[1].argv, "--eval-interval", "50"]
        # and sweep.py accepts the command (its own dry run creates nothing either)
        assert sweep.main([command[3], "--dry-run", *command[4:]]) == 0
    assert not out.exists()
    plot = commands[-1]
    assert plot[1:3] == ["-m", "a3c_tools.plot_sweep"]
    assert plot[plot.index("--out") + 1] == str(out / "fig7.6" / "fig7.6.png")
    assert "A3C FF=0.73" in plot and "GLPQ searing=0.81" in plot


def test_a_dry_run_into_a_closed_pipe_ends_quietly_creating_nothing(tmp_path):
    """`... --dry-run | head`: the pipe is the process boundary."""
    out = tmp_path / "out"
    argv = ["all", "--runs", "1", "--steps", "1000", "--out", str(out), "--dry-run"]
    result = run_into_a_closed_pipe([sys.executable, *TOOL, *argv])
    assert result.stderr == "" and result.returncode == 1, result.stderr
    assert not out.exists()


def test_a_dry_run_needs_only_the_figure(tmp_path):
    """What --out, --runs and --steps would fill in is printed as OUT, RUNS and STEPS, and said
    so; a real run still needs them."""
    result = run_tool("--dry-run", "fig7.6", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    rows = result.stdout.splitlines()
    assert rows[0] == "# OUT stands for --out, RUNS stands for --runs, STEPS stands for --steps"
    command = shlex.split(next(row for row in rows if row.startswith("python -m a3c_tools.sweep")))
    assert command[command.index("--runs") + 1] == "RUNS"
    assert command[command.index("--total-timesteps") + 1] == "STEPS"
    assert command[command.index("--eval-interval") + 1] == "STEPS/20"
    assert command[command.index("--out") + 1].startswith("OUT/fig")
    given = run_tool("--dry-run", "fig7.6", "--runs", "2", "--steps", "1000", "--out", "x")
    assert "stands for" not in given.stdout
    assert list(tmp_path.iterdir()) == []
    real = run_tool("fig7.6", "--runs", "2", cwd=tmp_path)
    assert real.returncode == 2 and "required: --out, --steps" in real.stderr


def test_dry_run_prints_a_shared_sweep_once():
    """A line that several figures share is one sweep: the dry run prints its command once and
    marks its repeats, so the printed commands are what a run of `all` would start."""
    result = run_tool("--dry-run", "all", "--runs", "2", "--steps", "1000", "--out", "x")
    assert result.returncode == 0, result.stderr
    rows = result.stdout.splitlines()
    sweeps = [row for row in rows if row.startswith("python -m a3c_tools.sweep")]
    repeats = [row.removeprefix("# (the sweep above) ") for row in rows if "sweep above" in row]
    assert repeats, "some figures share a line (A3C FF's is in most of them)"
    assert len(sweeps) == len(set(sweeps))
    assert set(repeats) <= set(sweeps)


def test_samples_come_after_the_learning_rate(tmp_path):
    """Run i of every line draws the first reproduction's learning rate and seed for run i,
    joint samples (A.1's c_g) included: the learning rate is sampled first."""
    reproduction = ROOT / "results" / "sweep_catch" / "a3c_ff" / "results.csv"
    with open(reproduction, newline="") as f:
        first = {row["run_id"]: (row["learning-rate"], row["seed"]) for row in csv.DictReader(f)}
    result = run_tool("--dry-run", "figA.1", "--runs", "8", "--steps", "250000", "--out", "x")
    command = shlex.split(next(r for r in result.stdout.splitlines() if "a3c_tools.sweep" in r))
    split = command.index("--")
    samples = [command[i + 1] for i in range(4, split) if command[i] == "--sample"]
    assert samples == ["learning-rate=loguniform:1e-05:0.01", "grad-clip=loguniform:0.5:40"]
    config = {"samples": samples, "fixed_flags": command[split + 1 :], "seed": 1}
    runs = sweep.plan_runs({**config, "total_timesteps": 250000}, len(first))  # 8, or extended
    assert {run.run_id: (run.sampled["learning-rate"], str(run.seed)) for run in runs} == first


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["fig9.9", "--runs", "2", "--steps", "100"], "unknown figure 'fig9.9'; valid: fig6.3"),
        (["fig7.6", "--runs", "2", "--steps", "100", "--bogus"], "unrecognized arguments"),
        (["fig7.6", "--runs", "0", "--steps", "100"], "--runs"),
        (["fig7.6", "--runs", "2", "--steps", "100", "--lr-range", "1e-2:1e-5"], "LOW < HIGH"),
        (["fig7.6", "--runs", "2"], "--steps"),
        (["--runs", "2", "--steps", "100"], "name a figure"),
    ],
)
def test_bad_arguments_exit_2_with_one_line_and_create_nothing(tmp_path, args, message):
    out = tmp_path / "out"
    result = run_tool(*args, "--out", str(out))
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and message in result.stderr
    assert result.stdout == "" and not out.exists()


def fake_table(folder: Path, runs: int, samples: list[str]) -> None:
    """What sweep.py would leave in a line's folder: a results.csv of `runs` ok runs, beside the
    sweep.json that names what it sampled."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sweep.json").write_text(json.dumps({"samples": samples}))
    parsed = [sweep.parse_sample(s) for s in samples]
    names = [s.name for s in parsed]
    with open(folder / "results.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([*sweep.FIXED_COLUMNS, *names, *sweep.TRAILING_COLUMNS])
        for i in range(runs):
            values = sweep.sample_values(parsed, 1, i)
            score = 0.2 + 0.1 * (i % 5)
            writer.writerow([f"run-{i:04d}", "ok", score, score / 2, 20, 1000, 1.0, 1 + 1000 * i,
                             *values.values(), "", ""])  # fmt: skip


def test_a_figure_runs_its_sweeps_in_rounds_then_draws_it(tmp_path, monkeypatch):
    """With the sweeps stood in for: each line is swept in rounds of --round runs, then the
    figure is drawn (the thesis's numbers beside its bars) and summarised in FIG.md."""
    real_execute = figure_sweeps.execute
    calls = []

    def execute(command, capture=False):
        if command[:2] == figures.PLOT:
            return real_execute(command, capture)
        own = command[: command.index("--")]
        runs = int(own[own.index("--runs") + 1])
        calls.append((Path(own[own.index("--out") + 1]).name, runs))
        samples = [own[i + 1] for i, word in enumerate(own) if word == "--sample"]
        fake_table(Path(own[own.index("--out") + 1]), runs, samples)
        return 0, ""

    monkeypatch.setattr(figure_sweeps, "execute", execute)
    out = tmp_path / "out"
    argv = ["fig7.6", "--runs", "3", "--steps", "1000", "--round", "2", "--out", str(out)]
    assert figures.main(argv) == 0
    # A3C FF's runs are fig6.7's ReLU line's (same_as), swept in that line's folder
    slugs = [
        Path(figures.folder(figures.by_id("fig7.6"), line)).name
        for line in figures.by_id("fig7.6").lines
    ]
    assert slugs[0] == "relu" and (out / "fig6.7" / "relu" / "results.csv").exists()
    assert calls == [(slug, 2) for slug in slugs] + [(slug, 3) for slug in slugs]
    png = out / "fig7.6" / "fig7.6.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = (out / "fig7.6" / "fig7.6.md").read_text()
    assert "| GLPQ searing | 3/3 |" in summary and "| 0.81 |" in summary
    assert "A3C FF 0.73" in summary  # the thesis's statement
    assert "--round 2" in summary  # the command that made it


def test_a_shared_line_is_swept_once_per_round(tmp_path, monkeypatch):
    """Figures 6.6 and 6.8 both show fig6.7's ReLU runs: one sweep of them per round, and both
    figures plot them under their own labels."""
    real_execute = figure_sweeps.execute
    calls = []

    def execute(command, capture=False):
        if command[:2] == figures.PLOT:
            return real_execute(command, capture)
        own = command[: command.index("--")]
        out = Path(own[own.index("--out") + 1])
        calls.append(f"{out.parent.name}/{out.name}")
        samples = [own[i + 1] for i, word in enumerate(own) if word == "--sample"]
        fake_table(out, int(own[own.index("--runs") + 1]), samples)
        return 0, ""

    monkeypatch.setattr(figure_sweeps, "execute", execute)
    out = tmp_path / "out"
    argv = ["fig6.6", "fig6.8", "--runs", "2", "--steps", "1000", "--out", str(out)]
    assert figures.main(argv) == 0
    assert calls == ["fig6.7/relu", "fig6.6/global-norm", "fig6.8/he", "fig6.8/sussillo-abbott"]
    assert not (out / "fig6.6" / "clip-by-value").exists()
    for figure, label in (("fig6.6", "Clip by value"), ("fig6.8", "Glorot & Bengio")):
        summary = (out / figure / f"{figure}.md").read_text()
        assert f"| {label} | 2/2 |" in summary
        assert "its runs are fig6.7/relu's, the same configuration" in summary


def test_an_interrupted_sweep_stops_the_figure(tmp_path, monkeypatch):
    calls = []

    def execute(command, capture=False):
        calls.append(command)
        return 130, ""

    monkeypatch.setattr(figure_sweeps, "execute", execute)
    out = tmp_path / "out"
    assert figures.main(["fig6.7", "--runs", "2", "--steps", "100", "--out", str(out)]) == 130
    assert len(calls) == 1  # no other sweep, no plot


# ------------------------------------------------------------------------------------------------
# plot_sweep.py --reference
# ------------------------------------------------------------------------------------------------
def test_plot_sweep_table_gets_a_reference_column():
    import numpy as np

    table = {
        "values": np.array([1e-4, 1e-3]),
        "score": np.array([0.5, 0.7]),
        "score_all": np.array([0.4, 0.6]),
        "runs": 2,
        "ok": 2,
    }
    plain = plot_sweep.summary_table([table, table], ["A", "B"], (1e-5, 1e-2))
    assert "reference" not in plain  # unchanged without references
    text = plot_sweep.summary_table([table, table], ["A", "B"], (1e-5, 1e-2), {"A": 0.73})
    rows = text.splitlines()
    assert rows[0].endswith("| reference |") and rows[1] == "|---|---|---|---|---|"
    assert rows[2].startswith("| A | 2/2 | 0.600") and rows[2].endswith("| 0.73 |")
    assert rows[3].endswith("|  |")


@pytest.mark.parametrize("reference", ["C=0.5", "A", "A=high"])
def test_plot_sweep_rejects_a_bad_reference(tmp_path, reference, capsys):
    fake_table(tmp_path / "a", 2, ["learning-rate=loguniform:1e-5:1e-2"])
    table = str(tmp_path / "a" / "results.csv")
    argv = [table, table, "--labels", "A", "B", "--reference", reference]
    assert plot_sweep.main([*argv, "--out", str(tmp_path / "x.png")]) == 2
    assert "--reference" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_a_figure_with_a_joint_sample_is_drawn_against_each(tmp_path, monkeypatch):
    """Figure A.1 samples c_g with the learning rate: one plot against each, and the thesis's
    map of the runs over both."""
    real_execute = figure_sweeps.execute

    def execute(command, capture=False):
        if command[:2] == figures.PLOT:
            return real_execute(command, capture)
        own = command[: command.index("--")]
        samples = [own[i + 1] for i, word in enumerate(own) if word == "--sample"]
        fake_table(Path(own[own.index("--out") + 1]), 4, samples)
        return 0, ""

    monkeypatch.setattr(figure_sweeps, "execute", execute)
    out = tmp_path / "out"
    assert figures.main(["A.1", "--runs", "4", "--steps", "1000", "--out", str(out)]) == 0
    for name in ("figA.1.png", "figA.1-grad-clip.png", "figA.1-learning-rate-grad-clip.png"):
        assert (out / "figA.1" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = (out / "figA.1" / "figA.1.md").read_text()
    assert "grad-clip in [0.5, 40]" in summary and "lr in [1e-05, 0.01]" in summary
    # the map's table: every run, by learning rate, with its sampled c_g and its score
    rows = [row for row in summary.splitlines() if row.startswith("| Global norm clipping | ")]
    runs = [row for row in rows if "/" not in row.split("|")[2]]  # not the bars' "4/4" rows
    assert len(runs) == 4
    parsed = [plot_sweep.read_joint(str(out / "figA.1" / "global-norm" / "results.csv"),
                                    "learning-rate", "grad-clip")]  # fmt: skip
    lrs = sorted(parsed[0]["x"])
    assert [float(row.split("|")[2]) for row in runs] == pytest.approx(lrs, rel=1e-2)


def test_plot_sweep_map_needs_both_columns(tmp_path, capsys):
    fake_table(tmp_path / "a", 3, ["learning-rate=loguniform:1e-5:1e-2"])
    argv = [str(tmp_path / "a" / "results.csv"), "--y", "grad-clip"]
    assert plot_sweep.main([*argv, "--out", str(tmp_path / "x.png")]) == 2
    assert "no column 'grad-clip'" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
