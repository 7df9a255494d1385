"""The analyses of committed runs (a3c_tools.future_work_*, a3c_tools.training_scalars), end to
end: on the committed results where they need nothing else, each output against the committed
one; on generated run folders where they need what the repository does not commit (per-run
logs and checkpoints)."""

import re
import shutil
from pathlib import Path

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
from a3c_tools import (
    future_work_growth,
    future_work_initial_policy,
    future_work_summary,
    future_work_trained_scale,
    training_scalars,
)
from conftest import ROOT, load_script, shared_for, tiny_args

FUTURE_WORK = ROOT / "results" / "future_work_catch"


def numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+\.\d+|-?\d+|nan", text)]


def test_the_summary_of_the_committed_runs_is_the_committed_one(tmp_path, capsys):
    folder = tmp_path / "future_work_catch"
    shutil.copytree(FUTURE_WORK, folder)
    assert future_work_summary.main([str(folder)]) == 0
    assert capsys.readouterr().out == (FUTURE_WORK / "summary.txt").read_text()
    assert (folder / "curves.csv").read_text() == (FUTURE_WORK / "curves.csv").read_text()
    assert (folder / "curves.png").stat().st_size > 10_000


def test_the_figures_legend_says_where_curves_were_not_kept(tmp_path):
    """A line scored in results.csv whose runs' curves are gone is named in its panel's legend
    with its run count; a line with fewer curves than runs says how many of how many."""
    rows = [{"config": "lpq_growth_f32", "run_id": f"run-{i:04d}", "global_step": str(step),
             "mean_return": "0.5"} for i in range(2) for step in (0, 50_000)]  # fmt: skip
    finished = {"lpq_f32": 15, "lpq_growth_f32": 3, "lws": 2}
    legends = future_work_summary.plot(rows, tmp_path / "curves.png", finished)
    assert legends["prototype growth"] == ["lpq_f32 (15 runs: curves not kept)",
                                           "lpq_growth_f32 (n=2 of 3 runs)"]  # fmt: skip
    assert legends["online local weight sharing"] == ["lws (2 runs: curves not kept)"]
    assert legends["prototypes from the data"] == ["lpq_f32 (15 runs: curves not kept)"]


def test_the_initial_policies_are_the_committed_ones(capsys):
    assert future_work_initial_policy.main([]) == 0
    out = capsys.readouterr().out.splitlines()
    committed = (FUTURE_WORK / "initial_policy.txt").read_text().splitlines()
    assert out[0] == committed[0] and len(out) == len(committed) == 3
    for ours, theirs in zip(out[1:], committed[1:], strict=True):
        np.testing.assert_allclose(numbers(ours), numbers(theirs), rtol=2e-3, atol=2e-4)


def test_the_training_scalars_of_a_committed_run_are_the_committed_ones(capsys):
    run = ROOT / "results" / "breakout_a3c_ff" / "native_10M"
    assert training_scalars.main([str(run)]) == 0
    assert capsys.readouterr().out == (run / "training_scalars.txt").read_text()


def test_growth_steps_are_read_from_each_runs_log(tmp_path, capsys):
    runs = tmp_path / "lpq_growth"
    (runs / "runs" / "run-0000").mkdir(parents=True)
    (runs / "results.csv").write_text("run_id,status\nrun-0000,ok\nrun-0001,failed\n")
    (runs / "runs" / "run-0000" / "stdout.log").write_text(
        "step 1\nprototype growth at step 50,000: pruned for actions [0, 2], grown for [1]; "
        "active per action [15, 17, 15]\nprototype growth at step 100,000: pruned for actions [],"
        " grown for [0, 1]; active per action [16, 18, 15]\n"
    )
    assert future_work_growth.main([str(tmp_path)]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert rows[0] == future_work_growth.HEADER
    assert rows[1].split() == ["lpq_growth", "run-0000", "2", "2", "3", "[16,", "18,", "15]"]
    assert len(rows) == 2  # the failed run is left out


def test_an_analysis_without_its_run_folders_says_so(tmp_path, capsys):
    (tmp_path / "lpq_growth").mkdir()
    (tmp_path / "lpq_growth" / "results.csv").write_text("run_id,status\n")
    with pytest.raises(SystemExit) as error:
        future_work_growth.main([str(tmp_path)])
    assert error.value.code == 2
    assert "run the configurations first" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        future_work_trained_scale.main([str(tmp_path)])


def test_trained_scale_reads_each_runs_final_checkpoint(tmp_path, capsys):
    """Generated runs whose final checkpoints are the networks as built: nothing moved."""
    for config, script in future_work_trained_scale.CONFIGS.items():
        module = load_script(Path(script).stem)
        (tmp_path / config / "runs" / "run-0000").mkdir(parents=True)
        (tmp_path / config / "results.csv").write_text("run_id,status,seed\nrun-0000,ok,4\n")
        torch.manual_seed(4)
        args = tiny_args(module, seed=4)
        shared = shared_for(module, args)
        if module.AGENT.initialize is not None:
            module.AGENT.initialize(shared.model, args)
        path = tmp_path / config / "runs" / "run-0000" / "checkpoint.pt"
        runtime.save_checkpoint(path, shared, args, 0.0, module.AGENT.script)
    assert future_work_trained_scale.main([str(tmp_path)]) == 0
    rows = capsys.readouterr().out.splitlines()[1:]
    assert [row.split()[0] for row in rows] == ["glpq", "glpq_data", "glpq_value"]
    for row in rows:
        values = numbers(row.split(None, 2)[2])
        assert values[0] == values[1] and values[2] == values[3]  # |h|^2, |w|^2: unchanged
        assert values[4] == 0.0  # the prototypes did not move


def test_trained_scale_refuses_a_changed_checkpoint_in_one_line(tmp_path, capsys):
    for config, script in future_work_trained_scale.CONFIGS.items():
        module = load_script(Path(script).stem)
        (tmp_path / config / "runs" / "run-0000").mkdir(parents=True)
        (tmp_path / config / "results.csv").write_text("run_id,status,seed\nrun-0000,ok,4\n")
        args = tiny_args(module, seed=4)
        path = tmp_path / config / "runs" / "run-0000" / "checkpoint.pt"
        runtime.save_checkpoint(path, shared_for(module, args), args, 0.0, module.AGENT.script)
        path.write_bytes(path.read_bytes()[:-100])  # truncated
    assert future_work_trained_scale.main([str(tmp_path)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "is corrupt: " in err
