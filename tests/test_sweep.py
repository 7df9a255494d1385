"""Tests of agents/a3c_tools/sweep.py and agents/a3c_tools/plot_sweep.py.

Most use a fake agent script written into tmp_path (no torch, a fraction of a second per run):
it writes an evaluations.csv whose returns follow from its learning rate, fails above a learning
rate, and can be held running to test interrupts. Two tiny sweeps of the real agents/a3c_ff.py
check the local and the Ray backend end to end.
"""

import contextlib
import csv
import json
import math
import multiprocessing
import multiprocessing.synchronize
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import read_checkpoint, run_main

ROOT = Path(__file__).resolve().parents[1]
SWEEP = ["-m", "a3c_tools.sweep"]  # the tools, with this interpreter
PLOT = ["-m", "a3c_tools.plot_sweep"]
A3C = ROOT / "agents" / "a3c_ff.py"
LR = "learning-rate=loguniform:1e-6:1e-2"
CONFIG = {"samples": [LR], "fixed_flags": [], "seed": 1, "total_timesteps": None}


from a3c_tools import plot_sweep as plot_sweep  # noqa: E402
from a3c_tools import sweep as sweep  # noqa: E402

FAKE_AGENT = textwrap.dedent(
    """
    import argparse, math, os, signal, sys, time

    parser = argparse.ArgumentParser()
    parser.add_argument("--learning-rate", type=float, default=1e-3)
    parser.add_argument("--total-timesteps", type=int, default=700)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--run-dir", required=True)
    parser.add_argument("--num-workers", type=int, default=1)
    parser.add_argument("--fail-above", type=float, default=math.inf)
    parser.add_argument("--hold", default=None, help="wait while this file exists")
    parser.add_argument("--busy", action="store_true", help="refused: folder in use")
    args = parser.parse_args()
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "starts.log"), "a") as f:
        f.write(f"{os.path.basename(args.run_dir)} {os.getpid()}\\n")
    open(os.path.join(args.run_dir, f"attempt-{os.getpid()}"), "w").close()
    if args.busy:
        print(f"error: the run folder {args.run_dir} is in use by process 4242 (a run or resume "
              "training there); wait for it to end or stop it", file=sys.stderr)
        sys.exit(2)
    stopped = []
    signal.signal(signal.SIGINT, lambda *_: stopped.append("SIGINT"))
    while args.hold and os.path.exists(args.hold) and not stopped:
        time.sleep(0.02)
    if stopped:
        print("stopped by SIGINT: checkpoint written")
        sys.exit(0)
    if args.learning_rate > args.fail_above:
        print("Traceback ...\\nerror: diverged", file=sys.stderr)
        sys.exit(1)
    level = min(1.0, -math.log10(args.learning_rate) / 6)
    with open(os.path.join(args.run_dir, "evaluations.csv"), "w") as f:
        f.write("global_step,wall_time_s,mean_return,std_return,episodes\\n")
        for i in range(8):  # returns level * i / 7 at steps 0, 100, ..., 700
            f.write(f"{i * args.total_timesteps // 7},0.1,{level * i / 7},0.0,5\\n")
    print(f"done: final eval {level:.3f}")
    """
)


# an agent script as the real ones are built: a tyro Args dataclass, run under a __main__ guard
ARGS_AGENT = textwrap.dedent(
    """
    import os
    from dataclasses import dataclass
    from typing import Literal

    import tyro


    @dataclass
    class Args:
        learning_rate: float = 1e-3
        total_timesteps: int = 700
        seed: int = 1
        run_dir: str = "run"
        num_workers: int = 1
        anneal_lr: bool = True
        scale_obs: bool | None = None
        activation: Literal["relu", "elu"] = "relu"


    if __name__ == "__main__":
        args = tyro.cli(Args)
        with open(os.path.join(args.run_dir, "evaluations.csv"), "w") as f:
            f.write(f"global_step,mean_return\\n0,0.0\\n{args.total_timesteps},0.5\\n")
    """
)


def fake_scores(learning_rate: float) -> tuple[float, float]:
    """The fake agent's (score, score_all): returns level * i / 7, i = 0..7; the final 5 are
    i = 3..7 (sum 25), all 8 sum to 28."""
    level = min(1.0, -math.log10(learning_rate) / 6)
    return level * 25 / 35, level * 28 / 56


@pytest.fixture
def fake_agent(tmp_path: Path) -> Path:
    path = tmp_path / "fake_agent.py"
    path.write_text(FAKE_AGENT)
    return path


@pytest.fixture
def args_agent(tmp_path: Path) -> Path:
    # a file name of its own: load_script keeps one module per file name in this process
    path = tmp_path / f"args_agent_{tmp_path.name}.py"
    path.write_text(ARGS_AGENT)
    return path


def run_sweep(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """`python -m a3c_tools.sweep *args` from the repository root, in process (its runs are
    processes of their own all the same)."""
    return run_main(sweep.main, list(args))


def read_table(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def starts(fake_agent: Path) -> list[tuple[str, int]]:
    log = fake_agent.parent / "starts.log"
    if not log.exists():
        return []
    return [(line.split()[0], int(line.split()[1])) for line in log.read_text().splitlines()]


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return not f.read().split(") ")[1].startswith("Z")
    except FileNotFoundError:
        return False


# ------------------------------------------------------------------------------------------------
# Sampling, scoring, rows
# ------------------------------------------------------------------------------------------------
def test_parse_sample_kinds_and_errors():
    s = sweep.parse_sample("--learning-rate=loguniform:1e-6:1e-2")
    assert (s.name, s.kind, s.low, s.high) == ("learning-rate", "loguniform", 1e-6, 1e-2)
    assert sweep.parse_sample("gamma=uniform:0.9:0.99").kind == "uniform"
    assert sweep.parse_sample("activation=choice:relu,elu").choices == ("relu", "elu")
    for bad in [
        "learning-rate",
        "lr=normal:0:1",
        "lr=uniform:1",
        "lr=uniform:2:1",
        "lr=loguniform:0:1",
        "lr=choice:",
        "seed=uniform:0:1",
        "lr=uniform:a:b",
    ]:
        with pytest.raises(sweep.UsageError):
            sweep.parse_sample(bad)


def test_draw_maps_the_unit_interval_onto_each_distribution():
    log = sweep.parse_sample("lr=loguniform:1e-6:1e-2")
    assert [log.draw(u) for u in (0.0, 0.25, 0.5)] == ["1e-06", "1e-05", "0.0001"]
    assert sweep.parse_sample("g=uniform:2:4").draw(0.75) == "3.5"
    choice = sweep.parse_sample("a=choice:x,y,z")
    assert [choice.draw(u) for u in (0.0, 0.34, 0.67, 0.999)] == ["x", "y", "z", "z"]


def test_samples_are_reproducible_per_run_and_log_uniform():
    samples = [sweep.parse_sample(LR), sweep.parse_sample("activation=choice:relu,elu")]
    first = [sweep.sample_values(samples, 7, i) for i in range(2000)]
    assert first == [sweep.sample_values(samples, 7, i) for i in range(2000)]
    assert first[:5] != [sweep.sample_values(samples, 8, i) for i in range(5)]
    exponents = np.log10([float(v["learning-rate"]) for v in first])
    assert exponents.min() >= -6 and exponents.max() <= -2
    # log-uniform: each decade holds a quarter of the draws (binomial sd about 1%)
    counts = np.histogram(exponents, bins=[-6, -5, -4, -3, -2])[0] / len(exponents)
    assert np.all(np.abs(counts - 0.25) < 0.04), counts
    elu = sum(v["activation"] == "elu" for v in first) / len(first)
    assert abs(elu - 0.5) < 0.04


def test_plan_runs_sets_seeds_workers_and_budget():
    config = {
        "samples": [LR],
        "fixed_flags": ["--eval-interval", "100"],
        "seed": 3,
        "total_timesteps": 5000,
    }
    runs = sweep.plan_runs(config, 3)
    assert [r.seed for r in runs] == [3, 1003, 2003]
    assert [r.run_id for r in runs] == ["run-0000", "run-0001", "run-0002"]
    flags = runs[1].flags
    assert flags[:2] == ["--eval-interval", "100"]
    assert sweep.flag_value(flags, "learning-rate") == runs[1].sampled["learning-rate"]
    assert sweep.flag_value(flags, "num-workers") == "1" and runs[1].workers == 1
    assert sweep.flag_value(flags, "total-timesteps") == "5000"
    assert sweep.flag_value(flags, "seed") == "1003"
    config["fixed_flags"] = ["--num-workers=3"]
    assert sweep.plan_runs(config, 1)[0].workers == 3
    assert sweep.flag_value(sweep.plan_runs(config, 1)[0].flags, "num-workers") == "3"


def test_score_is_the_mean_of_the_final_5_evaluations():
    returns = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0, 1.0]
    text = "global_step,wall_time_s,mean_return,std_return,episodes\n" + "".join(
        f"{i * 50000},1.0,{r},0.0,50\n" for i, r in enumerate(returns)
    )
    scores = sweep.score_evaluations(text)
    assert scores["score"] == pytest.approx((0.4 + 0.6 + 0.8 + 1.0 + 1.0) / 5)
    assert scores["score_all"] == pytest.approx(4.0 / 7)
    assert scores["evaluations"] == 7 and scores["final_step"] == "300000"
    short = sweep.score_evaluations("global_step,mean_return\n0,0.5\n10,1.0\n")
    assert short["score"] == 1.0  # fewer than 5 evaluations: all of them but the untrained one
    assert short["score_all"] == 0.75
    only = sweep.score_evaluations("global_step,mean_return\n0,0.5\n")
    assert only["score"] == 0.5  # step 0's counts where it is the only one
    with pytest.raises(ValueError):
        sweep.score_evaluations("global_step,wall_time_s,mean_return,std_return,episodes\n")


def test_result_rows_for_each_way_a_run_ends():
    run = sweep.plan_runs(CONFIG, 1)[0]
    evaluations = "global_step,mean_return\n0,0.25\n"
    base = {
        "returncode": 0,
        "interrupted": False,
        "wall_time_s": 1.234,
        "stdout_tail": "done:",
        "stderr_tail": "",
        "evaluations_csv": evaluations,
    }
    ok = sweep.result_row(run, base)
    assert (ok["status"], ok["score"], ok["wall_time_s"], ok["error"]) == ("ok", 0.25, 1.23, "")
    assert ok["learning-rate"] == run.sampled["learning-rate"] and ok["seed"] == 1
    assert sweep.result_row(run, {**base, "interrupted": True}) is None
    # a resumed run: this process saw its last part only, its evaluations' clock all of it
    resumed = {**base, "evaluations_csv": "global_step,wall_time_s,mean_return\n9,80.5,0.5\n"}
    assert sweep.result_row(run, resumed)["wall_time_s"] == 80.5
    crashed = sweep.result_row(
        run, {**base, "returncode": 1, "stderr_tail": "error: worker 0 failed:\nTraceback\nBoom"}
    )
    assert crashed["status"] == "failed" and crashed["score"] == ""
    assert crashed["error"] == "exit code 1: error: worker 0 failed:: Boom"
    killed = sweep.result_row(run, {**base, "returncode": -9, "stderr_tail": ""})
    assert killed["error"] == "killed by SIGKILL"
    stopped = sweep.result_row(run, {**base, "stdout_tail": "step 5\nstopped by SIGTERM: eval"})
    assert stopped["status"] == "failed" and "stopped by SIGTERM" in stopped["error"]
    missing = sweep.result_row(run, {**base, "evaluations_csv": None})
    assert missing["status"] == "failed" and "no evaluations.csv" in missing["error"]


# tyro's error for a3c_ff.py --lr 0.01, as a run's stderr.log holds it
TYRO_BOX = """\
╭─ Unrecognized options ──────────────────────────╮
│ Unrecognized options: --lr, 0.01                │
│ ─────────────────────────────────────────────── │
│ Perhaps you meant:                              │
│     --anneal-lr, --no-anneal-lr                 │
│         (default: True)                         │
│ ─────────────────────────────────────────────── │
│ For full helptext, run a3c_ff.py --help         │
╰─────────────────────────────────────────────────╯
"""


def test_a_failed_runs_error_is_its_last_meaningful_line():
    run = sweep.plan_runs(CONFIG, 1)[0]
    failed = {"returncode": 2, "interrupted": False, "wall_time_s": 1.0, "stdout_tail": "",
              "evaluations_csv": None}  # fmt: skip
    row = sweep.result_row(run, {**failed, "stderr_tail": TYRO_BOX})
    assert row["error"] == "exit code 2: Unrecognized options: --lr, 0.01"
    traceback = "Traceback (most recent call last):\n  ...\nRuntimeError: boom\n\n──────\n"
    row = sweep.result_row(run, {**failed, "stderr_tail": traceback})
    assert row["error"] == "exit code 2: RuntimeError: boom"  # borders and blank lines skipped
    long = sweep.result_row(run, {**failed, "stderr_tail": "error: " + "é" * 1000})
    assert len(long["error"]) == sweep.ERROR_CHARS and long["error"].endswith("éé…")


def test_log_tails_start_at_a_whole_character(tmp_path):
    log = tmp_path / "stderr.log"
    log.write_text("é" * 3000 + "x")  # 6001 bytes: the last 4000 start inside an é
    tail = sweep._tail(log)
    assert tail == "é" * 1999 + "x"


# ------------------------------------------------------------------------------------------------
# The sweep with the fake agent
# ------------------------------------------------------------------------------------------------
def test_sweep_records_scores_and_failures(fake_agent, tmp_path):
    out = tmp_path / "out"
    result = run_sweep(
        str(fake_agent),
        "--out",
        str(out),
        "--runs",
        "6",
        "--seed",
        "2",
        "--sample",
        LR,
        "--",
        "--fail-above",
        "1e-4",
    )
    assert result.returncode == 0, result.stderr
    rows = read_table(out)
    assert [r["run_id"] for r in rows] == [f"run-{i:04d}" for i in range(6)]
    statuses = {r["status"] for r in rows}
    assert statuses == {"ok", "failed"}, rows  # seed 2 samples learning rates on both sides
    for row in rows:
        lr = float(row["learning-rate"])
        assert f"--learning-rate {row['learning-rate']}" in row["flags"]
        assert float(row["wall_time_s"]) > 0
        if lr > 1e-4:
            assert row["status"] == "failed"
            assert row["error"] == "exit code 1: error: diverged" and row["score"] == ""
        else:
            score, score_all = fake_scores(lr)
            assert row["status"] == "ok" and row["error"] == ""
            assert float(row["score"]) == pytest.approx(score)
            assert float(row["score_all"]) == pytest.approx(score_all)
            assert row["evaluations"] == "8"
    assert "failed" in result.stdout and "done:" in result.stdout


def test_every_run_failing_exits_1(fake_agent, tmp_path):
    result = run_sweep(
        str(fake_agent),
        "--out",
        str(tmp_path / "out"),
        "--runs",
        "2",
        "--sample",
        LR,
        "--",
        "--fail-above",
        "1e-9",
    )
    assert result.returncode == 1
    assert [r["status"] for r in read_table(tmp_path / "out")] == ["failed", "failed"]


def test_restart_skips_finished_runs_and_extends(fake_agent, tmp_path):
    out = str(tmp_path / "out")

    def args(runs: int) -> list[str]:
        return [str(fake_agent), "--out", out, "--runs", str(runs), "--sample", LR, "--",
                "--fail-above", "1e-4"]  # fmt: skip

    assert run_sweep(*args(3)).returncode in (0, 1)
    first = read_table(Path(out))
    assert run_sweep(*args(5)).returncode in (0, 1)
    again = run_sweep(*args(5))
    assert "0 to run" in again.stdout
    rows = read_table(Path(out))
    assert rows[:3] == first  # finished runs, failed ones too, are kept as they were
    assert len(rows) == 5
    started = [run_id for run_id, _ in starts(fake_agent)]
    assert sorted(started) == [f"run-{i:04d}" for i in range(5)]  # each run started once


def test_restart_with_another_configuration_is_refused(fake_agent, tmp_path):
    out = str(tmp_path / "out")
    assert run_sweep(str(fake_agent), "--out", out, "--runs", "1", "--sample", LR).returncode == 0
    result = run_sweep(
        str(fake_agent),
        "--out",
        out,
        "--runs",
        "1",
        "--sample",
        "learning-rate=loguniform:1e-5:1e-2",
    )
    assert result.returncode == 2
    assert "another configuration" in result.stderr and "samples" in result.stderr
    result = run_sweep(str(fake_agent), "--out", out, "--runs", "1", "--sample", LR, "--seed", "9")
    assert result.returncode == 2 and "seed" in result.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--runs", "0"], "--runs must be >= 1"),
        (["--sample", "lr=normal:0:1"], "expected NAME=loguniform"),
        (["--", "--seed", "3"], "the sweep sets it"),
        (["--address", "auto"], "--address needs --backend ray"),
    ],
)
def test_bad_arguments_exit_2(fake_agent, tmp_path, args, message):
    result = run_sweep(str(fake_agent), "--out", str(tmp_path / "out"), *args)
    assert result.returncode == 2
    assert message in result.stderr


def test_dry_run_prints_the_commands(fake_agent, tmp_path):
    result = run_sweep(
        str(fake_agent),
        "--out",
        str(tmp_path / "out"),
        "--runs",
        "2",
        "--total-timesteps",
        "500",
        "--sample",
        LR,
        "--dry-run",
    )
    assert result.returncode == 0
    lines = result.stdout.splitlines()
    assert len(lines) == 2 and "--total-timesteps 500 --seed 1001" in lines[1]
    assert not (tmp_path / "out").exists()


def wait_for_starts(fake_agent: Path, count: int, timeout: float = 30) -> list[tuple[str, int]]:
    deadline = time.time() + timeout
    while len(starts(fake_agent)) < count:
        assert time.time() < deadline, "the runs did not start"
        time.sleep(0.05)
    return starts(fake_agent)


def test_interrupted_sweep_records_nothing_half_done_and_reruns(fake_agent, tmp_path):
    out, hold = tmp_path / "out", tmp_path / "hold"
    hold.touch()
    command = [
        sys.executable,
        *SWEEP,
        str(fake_agent),
        "--out",
        str(out),
        "--runs",
        "3",
        "--cpus",
        "2",
        "--sample",
        LR,
        "--",
        "--hold",
        str(hold),
    ]
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT
    )
    held = wait_for_starts(fake_agent, 2)  # two at once on 2 CPUs, the third waits
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=30)
    assert process.returncode == 130, stderr
    assert "interrupted" in stdout
    assert len(starts(fake_agent)) == 2
    assert not any(alive(pid) for _, pid in held)
    assert not (out / "results.csv").exists()  # the stopped runs are not recorded
    for run_id, pid in held:  # the stopped runs' folders are left as they were
        assert (out / "runs" / run_id / f"attempt-{pid}").exists()

    hold.unlink()
    result = run_sweep(*command[3:])
    assert result.returncode == 0, result.stderr
    assert [r["status"] for r in read_table(out)] == ["ok"] * 3
    assert sorted(run_id for run_id, _ in starts(fake_agent)) == [
        "run-0000",
        "run-0000",
        "run-0001",
        "run-0001",
        "run-0002",
    ]
    for run_id, pid in held:  # rerun from scratch: the old attempt's files are gone
        assert not (out / "runs" / run_id / f"attempt-{pid}").exists()


def test_a_second_sweep_in_the_same_folder_is_refused(fake_agent, tmp_path):
    hold = tmp_path / "hold"
    hold.touch()
    out = tmp_path / "out"
    args = [str(fake_agent), "--out", str(out), "--runs", "1", "--sample", LR, "--",
            "--hold", str(hold)]  # fmt: skip
    first = subprocess.Popen([sys.executable, *SWEEP, *args], stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)  # fmt: skip
    wait_for_starts(fake_agent, 1)
    second = run_sweep(*args)
    assert second.returncode == 2
    assert f"{out} is held by another sweep (pid {first.pid})" in second.stderr
    hold.unlink()
    assert first.wait(30) == 0
    assert len(starts(fake_agent)) == 1
    assert not (out / "runs" / "sweep.lock").exists()


def _race(barrier: multiprocessing.synchronize.Barrier, argv: list[str], log: Path) -> None:
    """One of two forked sweeps: wait for the other, then start; exit with the sweep's code."""
    with open(log, "w") as f, contextlib.redirect_stderr(f), contextlib.redirect_stdout(f):
        barrier.wait()
        code = sweep.main(argv)
    sys.exit(code)


def test_two_sweeps_started_together_one_runs_the_other_is_refused(
    args_agent, tmp_path, monkeypatch
):
    """Two sweeps started at the same instant into one new folder, 20 times: one runs, the
    other exits 2 naming the one that holds the folder, and the folder is the winner's alone
    (its sweep.json and results.csv, no temp file), with the same and with other seeds."""
    ctx = multiprocessing.get_context("fork")
    release = ctx.Event()

    def stand_in(command: list[str], run_dir: str, stop_level=None) -> dict:
        # the winner's run: no subprocess, and it lasts until the loser is out
        release.wait(30)
        evaluations = "global_step,mean_return\n0,0.5\n"
        return {"returncode": 0, "interrupted": False, "wall_time_s": 0.01, "stdout_tail": "",
                "stderr_tail": "", "evaluations_csv": evaluations}  # fmt: skip

    monkeypatch.setattr(sweep, "execute_run", stand_in)
    assert sweep.script_flags(args_agent)  # loaded here: both forks reach the lock at once
    for attempt in range(20):
        out = tmp_path / f"out-{attempt}"
        seeds = (1, 1) if attempt % 2 else (1, 2)
        barrier, logs = ctx.Barrier(2), [tmp_path / f"log-{attempt}-{i}" for i in (0, 1)]
        release.clear()
        argvs = [[str(args_agent), "--out", str(out), "--runs", "1", "--seed", str(seed),
                  "--sample", LR] for seed in seeds]  # fmt: skip
        sweeps = [
            ctx.Process(target=_race, args=(barrier, argv, log))
            for argv, log in zip(argvs, logs, strict=True)
        ]
        for process in sweeps:
            process.start()
        deadline = time.time() + 30
        while all(process.is_alive() for process in sweeps):
            assert time.time() < deadline, "neither sweep ended"
            time.sleep(0.005)
        [loser] = [process for process in sweeps if not process.is_alive()]
        [winner] = [process for process in sweeps if process is not loser]
        message = logs[sweeps.index(loser)].read_text()
        assert loser.exitcode == 2, message
        lock = out / "runs" / "sweep.lock"
        assert message == (
            f"error: {out} is held by another sweep (pid {winner.pid}) ({lock}); wait for it "
            "to end, or use another --out\n"
        )
        release.set()
        winner.join(30)
        assert winner.exitcode == 0, logs[sweeps.index(winner)].read_text()
        seed = seeds[sweeps.index(winner)]
        assert json.loads((out / "sweep.json").read_text())["seed"] == seed
        assert [row["seed"] for row in read_table(out)] == [str(seed)]
        assert sorted(path.name for path in out.iterdir()) == ["results.csv", "runs", "sweep.json"]
        assert not lock.exists()


def test_the_lock_goes_when_the_sweep_ends_and_a_stale_one_does_not_block(fake_agent, tmp_path):
    out = tmp_path / "out"
    lock = out / "runs" / "sweep.lock"
    args = [str(fake_agent), "--out", str(out), "--sample", LR]
    assert sweep.main([*args, "--runs", "1"]) == 0
    assert not lock.exists()
    assert sweep.main([*args, "--runs", "1", "--seed", "9"]) == 2  # refused: it goes too
    assert not lock.exists()
    lock.write_text("12345\n")  # what a killed sweep leaves: the file, which nobody locks
    assert sweep.main([*args, "--runs", "2"]) == 0
    assert [row["status"] for row in read_table(out)] == ["ok", "ok"]
    assert not lock.exists()


@pytest.mark.parametrize("kind", ["Args dataclass", "argparse --help"])
def test_a_flag_the_script_lacks_is_refused_before_anything_is_created(
    fake_agent, args_agent, tmp_path, capsys, kind
):
    script = args_agent if kind == "Args dataclass" else fake_agent
    out = tmp_path / "out"
    base = [str(script), "--out", str(out), "--runs", "1"]
    assert sweep.main([*base, "--sample", "lr=loguniform:1e-4:1e-2"]) == 2
    assert capsys.readouterr().err == (
        f"error: --sample lr: {script.name} has no flag --lr; did you mean --learning-rate?\n"
    )
    assert sweep.main([*base, "--sample", LR, "--", "--num-worker", "2"]) == 2
    assert capsys.readouterr().err == (
        f"error: after `--`: {script.name} has no flag --num-worker; did you mean --num-workers?\n"
    )
    assert sweep.main([*base, "--", "--zzz"]) == 2
    assert "has no flag --zzz; its flags: " in capsys.readouterr().err
    assert not out.exists() and not starts(fake_agent)
    # nothing was created: the corrected command takes the same folder
    assert sweep.main([*base, "--sample", LR, "--", "--num-workers", "1"]) == 0
    assert [row["status"] for row in read_table(out)] == ["ok"]


def test_a_value_a_run_would_refuse_refuses_the_sweep_before_anything_is_created(
    args_agent, tmp_path, capsys
):
    out = tmp_path / "out"
    code = sweep.main([str(args_agent), "--out", str(out), "--runs", "1", "--sample",
                       "activation=choice:tanh"])  # fmt: skip
    assert code == 2 and not out.exists()
    assert capsys.readouterr().err == (
        "error: run-0000 (activation=tanh): invalid choice 'tanh' for argument '--activation'. "
        "Expected one of ('relu', 'elu'); nothing was run\n"
    )


@pytest.mark.parametrize(
    "script, flags, message",
    [
        (A3C, ["--", "--eval-interval", "-5"], "run-0000: --eval-interval must be > 0 (got -5)"),
        (
            A3C,
            ["--sample", "gamma=uniform:0.5:1.5"],
            "run-0001 (gamma=1.09943): --gamma must be in [0, 1] (got 1.09943)",
        ),  # run-0000 draws 0.73
        (A3C, ["--", "--precision", "tf32"], "run-0000: --precision tf32 is a GPU's"),
        (
            ROOT / "agents" / "a3c_glpq.py",
            ["--sample", "tau=uniform:-1:1", "--", "--temperature", "fixed"],
            "run-0000 (tau=-0.845764): --tau must be > 0",
        ),  # the network's own check
    ],
)
def test_an_agents_runs_are_checked_as_their_start_checks_them(
    tmp_path, capsys, script, flags, message
):
    out = tmp_path / "out"
    code = sweep.main([str(script), "--out", str(out), "--runs", "3", "--total-timesteps", "1000",
                       *flags])  # fmt: skip
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err
    assert err.startswith(f"error: {message}") and err.endswith("; nothing was run\n")
    assert err.count("\n") == 1


def test_args_flags_are_read_as_tyro_spells_them(args_agent):
    flags = sweep.script_flags(args_agent)
    assert flags["learning-rate"] == flags["learning_rate"] == "learning-rate"
    assert flags["no-anneal-lr"] == flags["no_anneal_lr"] == "no-anneal-lr"
    assert "scale-obs" in flags and "no-scale-obs" not in flags  # tyro: bool | None has no --no-x
    assert "no-learning-rate" not in flags


def test_killed_sweep_takes_its_runs_with_it(fake_agent, tmp_path):
    hold = tmp_path / "hold"
    hold.touch()
    command = [
        sys.executable,
        *SWEEP,
        str(fake_agent),
        "--out",
        str(tmp_path / "out"),
        "--runs",
        "1",
        "--sample",
        LR,
        "--",
        "--hold",
        str(hold),
    ]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    [(_, pid)] = wait_for_starts(fake_agent, 1)
    process.kill()
    process.wait(10)
    deadline = time.time() + 10
    while alive(pid) and time.time() < deadline:
        time.sleep(0.05)
    assert not alive(pid), "the run outlived its killed sweep"


@pytest.mark.parametrize("how", ["stop level", "KeyboardInterrupt"])
def test_execute_run_stops_its_run_with_sigint(fake_agent, tmp_path, how):
    """The local backend asks a run to stop through its stop level; a Ray cancel raises
    KeyboardInterrupt in the task. Both run in threads with SIGINT blocked, as Ray's are: the
    run must see the SIGINT all the same, and checkpoint and exit well within the grace time."""
    hold = tmp_path / "hold"
    hold.touch()
    run_dir = tmp_path / "run"
    command = [str(fake_agent), "--hold", str(hold), "--run-dir", str(run_dir)]

    def stop_level() -> int:
        if not starts(fake_agent):
            return 0
        if how == "KeyboardInterrupt":
            raise KeyboardInterrupt
        return 1

    results = {}

    def in_thread() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        results["run"] = sweep.execute_run(command, str(run_dir), stop_level)

    thread = threading.Thread(target=in_thread)
    thread.start()
    thread.join(60)
    result = results["run"]
    assert result["interrupted"] and result["returncode"] == 0, result
    assert "stopped by SIGINT" in result["stdout_tail"]
    assert result["wall_time_s"] < sweep.STOP_GRACE_S / 2
    assert sweep.result_row(sweep.plan_runs(CONFIG, 1)[0], result) is None


AUTOGROUPS = Path("/proc/sys/kernel/sched_autogroup_enabled")


@pytest.mark.skipif(
    not (AUTOGROUPS.is_file() and AUTOGROUPS.read_text().strip() == "1"),
    reason="the kernel does not group sessions (Linux sched_autogroup)",
)
def test_a_run_keeps_the_sweeps_autogroup_nice(tmp_path):
    """A run is a session of its own, so an autogroup of its own, which the kernel ranks by the
    group's nice alone: a campaign niced by its group would start each run at nice 0 and take
    half the CPU. The sweep is started in a session of its own here (the process boundary is
    what is tested), its group niced to 7; its run must come out in another group, niced 7."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import os, sys\n"
        "open(sys.argv[1], 'w').write(open('/proc/self/autogroup').read()"
        " + open(f'/proc/{os.getppid()}/autogroup').read())\n"
    )
    seen = tmp_path / "seen.txt"
    sweeper = (
        "import sys; from pathlib import Path; from a3c_tools import sweep\n"
        "try: Path('/proc/self/autogroup').write_text('7')\n"
        "except OSError: sys.exit(77)\n"
        "result = sweep.execute_run(sys.argv[1:3], sys.argv[3])\n"
        "sys.exit(result['returncode'])\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", sweeper, str(probe), str(seen), str(tmp_path / "run")],
        cwd=ROOT / "agents",
        start_new_session=True,
        timeout=60,
    )
    if done.returncode == 77:
        pytest.skip("this process may not set its autogroup's nice")
    assert done.returncode == 0
    run_group, sweep_group = seen.read_text().splitlines()
    assert sweep_group.endswith("nice 7"), sweep_group
    assert run_group != sweep_group and run_group.endswith("nice 7"), (run_group, sweep_group)


# ------------------------------------------------------------------------------------------------
# The plot
# ------------------------------------------------------------------------------------------------
def test_savgol_keeps_cubics_and_matches_scipy():
    x = np.linspace(-3, 2, 20)
    cubic = 0.5 * x**3 - x**2 + 2 * x - 1
    np.testing.assert_allclose(plot_sweep.savgol(cubic), cubic, atol=1e-9)
    noisy = np.random.default_rng(0).normal(size=30)
    smoothed = plot_sweep.savgol(noisy)
    assert smoothed.std() < noisy.std()
    # the window-5 cubic fit at the centre: (-3, 12, 17, 12, -3) / 35
    assert smoothed[10] == pytest.approx(np.dot([-3, 12, 17, 12, -3], noisy[8:13]) / 35)
    scipy_signal = pytest.importorskip("scipy.signal")
    np.testing.assert_allclose(smoothed, scipy_signal.savgol_filter(noisy, 5, 3), atol=1e-12)


def test_smooth_curve_interpolates_within_the_data():
    x = np.array([-5.0, -3.0, -4.0, -4.0, -2.5])
    y = np.array([0.0, 0.4, 0.1, 0.3, 0.5])  # the two runs at -4 average to 0.2: a line 0.2/decade
    grid, curve = plot_sweep.smooth_curve(x, y, (-6, -2))
    assert grid.min() >= -5 and grid.max() <= -2.5 and len(grid) > 20
    np.testing.assert_allclose(curve, 0.2 * (grid + 5), atol=1e-9)  # a line stays a line


def test_bar_value_averages_the_runs_in_range():
    values = np.array([1e-6, 1e-5, 1e-3, 1e-2, 2e-2])
    bar = plot_sweep.bar_value(values, np.array([9.0, 0.2, 0.4, 0.6, 9.0]), (1e-5, 1e-2))
    assert bar["n"] == 3 and bar["mean"] == pytest.approx(0.4)
    assert bar["sem"] == pytest.approx(0.2 / math.sqrt(3))


def test_plot_writes_a_png_and_the_table(fake_agent, tmp_path):
    tables = []
    for name, runs in (("a", "8"), ("b", "6")):
        out = tmp_path / name
        result = run_sweep(
            str(fake_agent),
            "--out",
            str(out),
            "--runs",
            runs,
            "--seed",
            "3",
            "--sample",
            LR,
            "--",
            "--fail-above",
            "3e-3",
        )
        assert result.returncode == 0, result.stderr
        tables.append(str(out / "results.csv"))
    png = tmp_path / "sweep.png"
    result = subprocess.run(
        # -o, as the README writes it
        [sys.executable, *PLOT, *tables, "--labels", "FF", "GLPQ", "-o", str(png)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    ok = [r for r in read_table(tmp_path / "a") if r["status"] == "ok"]
    # the bars average over the range the sweep sampled (LR), as sweep.json says
    in_range = [float(r["score"]) for r in ok if 1e-6 <= float(r["learning-rate"]) <= 1e-2]
    line = next(line for line in result.stdout.splitlines() if line.startswith("| FF |"))
    assert f"| {len(ok)}/8 | {np.mean(in_range):.3f}" in line
    assert f"(n={len(in_range)})" in line


# ------------------------------------------------------------------------------------------------
# Tiny sweeps of the real agent, on both backends
# ------------------------------------------------------------------------------------------------
TINY_A3C = [
    "--runs",
    "3",
    "--total-timesteps",
    "1000",
    "--sample",
    LR,
    "--",
    "--eval-interval",
    "500",
    "--eval-episodes",
    "2",
]


def check_a3c_sweep(out: Path, result: subprocess.CompletedProcess) -> None:
    assert result.returncode == 0, result.stdout + result.stderr
    rows = read_table(out)
    planned = sweep.plan_runs(
        {"samples": [LR], "fixed_flags": TINY_A3C[7:], "seed": 1, "total_timesteps": 1000}, 3
    )
    assert [r["learning-rate"] for r in rows] == [p.sampled["learning-rate"] for p in planned]
    assert [r["seed"] for r in rows] == ["1", "1001", "2001"]
    for row in rows:
        assert row["status"] == "ok", row
        evaluations = (out / "runs" / row["run_id"] / "evaluations.csv").read_text()
        expected = sweep.score_evaluations(evaluations)
        assert float(row["score"]) == pytest.approx(expected["score"])
        assert int(row["evaluations"]) >= 3 and int(row["final_step"]) >= 1000
        assert "--num-workers 1" in row["flags"]


@pytest.mark.slow
def test_tiny_a3c_sweep_local(tmp_path):
    out = tmp_path / "out"
    check_a3c_sweep(out, run_sweep(str(A3C), "--out", str(out), *TINY_A3C, timeout=300))


@pytest.mark.slow
def test_tiny_a3c_sweep_ray(tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "out"
    result = run_sweep(
        str(A3C), "--out", str(out), "--backend", "ray", "--cpus", "2", *TINY_A3C, timeout=300
    )
    check_a3c_sweep(out, result)
    assert "ray: 2 CPUs" in result.stdout


@pytest.mark.slow
def test_an_interrupted_run_resumes_with_its_own_flags(tmp_path):
    """A run stopped mid-way (the sweep was interrupted) goes on from its checkpoint when the
    sweep starts again, with the flags it was started with (--resume keeps them all)."""
    run_dir = tmp_path / "runs" / "run-0000"
    command = [str(A3C), "--total-timesteps", "4000", "--learning-rate", "0.0005",
               "--num-workers", "1", "--checkpoint-interval", "500", "--eval-interval", "2000",
               "--eval-episodes", "2", "--seed", "5", "--run-dir", str(run_dir)]  # fmt: skip
    checkpoint = run_dir / "checkpoint.pt"
    first = sweep.execute_run(command, str(run_dir), lambda: int(checkpoint.exists()))
    assert first["interrupted"] and first["returncode"] == 0, first
    step = read_checkpoint(checkpoint)["global_step"]
    assert step < 4000
    second = sweep.execute_run(command, str(run_dir))
    assert second["returncode"] == 0 and not second["interrupted"], second
    assert "resuming run run-0000 at step" in second["stdout_tail"]
    resumed = read_checkpoint(checkpoint)
    assert resumed["global_step"] >= 4000
    assert (resumed["args"]["learning_rate"], resumed["args"]["seed"]) == (0.0005, 5)


def test_the_bars_average_over_the_range_the_sweep_sampled(tmp_path, capsys):
    """The bar chart's title and the table once gave the thesis's [1e-5, 1e-2] for a sweep
    that sampled [1e-6, 1e-2] (and left its runs below 1e-5 out)."""
    rows = [("2e-06", "0.1"), ("1e-04", "0.3"), ("3e-03", "0.5")]
    table = tmp_path / "demo" / "results.csv"
    table.parent.mkdir()
    table.write_text(
        "status,learning-rate,score,score_all\n"
        + "".join(f"ok,{lr},{score},{score}\n" for lr, score in rows)
    )
    out = str(tmp_path / "sweep.png")

    def header(*flags: str) -> str:
        assert plot_sweep.main([str(table), "-o", out, *flags]) == 0
        return capsys.readouterr().out.splitlines()[0]

    # no sweep.json: the runs' own range
    assert "score (final 5), lr in [2e-06, 0.003] |" in header()
    (table.parent / "sweep.json").write_text(
        json.dumps({"samples": ["learning-rate=loguniform:1e-06:0.01"]})
    )
    assert "score (final 5), lr in [1e-06, 0.01] |" in header()
    assert plot_sweep.main([str(table), "-o", out]) == 0
    assert "| 3/3 | 0.300 +- 0.115 (n=3) |" in capsys.readouterr().out
    assert "lr in [1e-05, 0.01] |" in header("--bar-range", "1e-5", "1e-2")  # as given


# ------------------------------------------------------------------------------------------------
# A run in use elsewhere (issue 69, point 4), and an OUT that is not a sweep's (point 5)
# ------------------------------------------------------------------------------------------------
HOLD_RUN_FOLDER = """
import sys
from pathlib import Path
from a3c_runtime.run_folder import RunFolder
folder = RunFolder(Path(sys.argv[1]))  # as a run resumed by hand holds its folder
print("held", flush=True)
sys.stdin.read()  # until the test closes stdin
folder.close()
"""


@contextlib.contextmanager
def run_folder_held(path: Path):
    """The run folder locked by another process, as a3c_runtime locks it for a run training
    there (a run resumed by hand)."""
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLD_RUN_FOLDER, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder.pid
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)


def test_the_sweep_knows_the_runtimes_lock_and_its_refusal(tmp_path):
    from a3c_runtime import UsageError as RunUsageError
    from a3c_runtime.run_folder import LOCK_FILE, RunFolder
    from a3c_tools import run_lock

    assert run_lock.RUN_LOCK == LOCK_FILE
    assert sweep.run_holder is run_lock.run_holder  # the batched backend's too
    with run_folder_held(tmp_path) as pid:
        assert sweep.run_holder(tmp_path) == str(pid)
        with pytest.raises(RunUsageError, match=sweep.IN_USE_TEXT):
            RunFolder(tmp_path)
    assert sweep.run_holder(tmp_path) is None
    assert sweep.run_holder(tmp_path / "nothing") is None
    assert not (tmp_path / "nothing").exists()


def test_a_partial_run_starts_again_in_its_emptied_folder_its_lock_file_kept(tmp_path):
    """A run that wrote no checkpoint starts again in its folder, emptied all but its lock
    file: the file the next run locks is the one any other process would lock (a removed lock
    file would let two processes hold the folder at once). A run folder that is a link (the
    runs kept on another disk, say) stays one, its run in the folder it points to; a link in
    it is removed, and what that pointed to is left as it was."""
    elsewhere, disk = tmp_path / "elsewhere", tmp_path / "disk"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("mine")
    (disk / "run-0000" / "videos").mkdir(parents=True)
    (disk / "run-0000" / "evaluations.csv").write_text("global_step\n0\n")
    (disk / "run-0000" / "run.lock").write_text("12345\n")
    (disk / "run-0000" / "linked").symlink_to(elsewhere, target_is_directory=True)
    lock_inode = (disk / "run-0000" / "run.lock").stat().st_ino
    run_dir = tmp_path / "runs" / "run-0000"
    run_dir.parent.mkdir()
    run_dir.symlink_to(disk / "run-0000", target_is_directory=True)
    result = sweep.execute_run(["-c", "pass"], str(run_dir))
    assert result["returncode"] == 0 and run_dir.is_symlink()
    assert (run_dir / "run.lock").stat().st_ino == lock_inode
    assert sorted(p.name for p in run_dir.iterdir()) == ["run.lock", "stderr.log", "stdout.log"]
    assert [p.name for p in elsewhere.iterdir()] == ["keep.txt"]


def test_a_run_in_use_elsewhere_is_not_failed_and_runs_once_free(fake_agent, tmp_path):
    """Started again while one of its runs is resumed by hand, the sweep leaves that run alone,
    records no row for it, says "in use", exits 3 (not 1), and runs it on the next start."""
    out = tmp_path / "out"
    command = [str(fake_agent), "--out", str(out), "--runs", "2", "--sample", LR]
    busy = out / "runs" / "run-0001"
    busy.mkdir(parents=True)
    (busy / "stdout.log").write_text("the run resumed by hand\n")
    with run_folder_held(busy) as pid:
        result = run_sweep(*command)
        assert result.returncode == sweep.IN_USE_EXIT == 3, result.stdout + result.stderr
        assert f"run-0001 in use: {busy} is held by process {pid}" in result.stdout
        assert "not done: 1 ok, 0 failed, 1 in use elsewhere (run-0001)" in result.stdout
        assert [(r["run_id"], r["status"]) for r in read_table(out)] == [("run-0000", "ok")]
        assert [run_id for run_id, _ in starts(fake_agent)] == ["run-0000"]
        assert (busy / "stdout.log").read_text() == "the run resumed by hand\n"  # untouched
    result = run_sweep(*command)
    assert result.returncode == 0, result.stdout + result.stderr
    assert [(r["run_id"], r["status"]) for r in read_table(out)] == [
        ("run-0000", "ok"),
        ("run-0001", "ok"),
    ]


def test_the_checkpoint_of_a_run_in_use_is_judged_once_it_is_free(
    fake_agent, tmp_path, monkeypatch
):
    """A run resumed by hand with a flag that a resume may change (a longer --total-timesteps)
    holds a checkpoint the sweep would call another run's: while that run is in use the sweep
    neither judges nor touches it, and runs the others."""
    out = tmp_path / "out"
    busy = out / "runs" / "run-0001"
    busy.mkdir(parents=True)

    def foreign(script, run, run_dir):
        return f"{run_dir}/checkpoint.pt is not {run.run_id}'s" if run_dir == busy else None

    monkeypatch.setattr(sweep, "foreign_checkpoint", foreign)
    with run_folder_held(busy):
        result = run_sweep(str(fake_agent), "--out", str(out), "--runs", "2", "--sample", LR)
    assert result.returncode == 3, result.stdout + result.stderr
    assert [r["run_id"] for r in read_table(out)] == ["run-0000"]
    result = run_sweep(str(fake_agent), "--out", str(out), "--runs", "2", "--sample", LR)
    assert result.returncode == 2 and "is not run-0001's" in result.stderr  # free: judged


def test_a_run_refused_for_its_folder_in_use_is_in_use_not_failed(fake_agent, tmp_path):
    """A run that another process took between the sweep's look and the run's start exits 2
    with the runtime's "in use" line: in use, not a failure."""
    out = tmp_path / "out"
    result = run_sweep(str(fake_agent), "--out", str(out), "--runs", "1", "--", "--busy")
    assert result.returncode == 3, result.stdout + result.stderr
    assert "run-0000 in use" in result.stdout and "failed" not in result.stdout.split("not done")[0]
    assert not (out / "results.csv").exists()


def test_a_row_recorded_failed_for_a_run_in_use_runs_again(fake_agent, tmp_path):
    """An older sweep recorded a run it found in use as failed, for good; such a row is run
    again, and the sweep ends ok."""
    out = tmp_path / "out"
    command = [str(fake_agent), "--out", str(out), "--runs", "1", "--sample", LR]
    assert run_sweep(*command).returncode == 0
    rows = read_table(out)
    rows[0].update(
        status="failed",
        score="",
        error=f"exit code 2: error: the run folder {out}/runs/run-0000 is in use by process "
        "4242 (a run or resume training there); wait for it to end or stop it",
    )
    with open(out / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    shutil.rmtree(out / "runs" / "run-0000")
    result = run_sweep(*command)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 to run" in result.stdout
    assert [(r["run_id"], r["status"], r["error"]) for r in read_table(out)] == [
        ("run-0000", "ok", "")
    ]


def folder_state(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() if p.is_file() else b"<folder>"
        for p in sorted(folder.rglob("*"))
    }


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ('{"script": "fake_agent.py", "samp', "not JSON"),  # a truncated file
        ('["fake_agent.py"]', "a JSON list, not an object"),
        ("", "not JSON"),
        pytest.param("[" * 100_000, "JSON nested too deep to read", id="nested 100,000 deep"),
        ('{"script": "fake_agent.py", "seed": "1"}', "its 'seed' is '1', not a whole number"),
        ('{"fixed_flags": ["--seed", 2]}', "its 'fixed_flags' is ['--seed', 2], not a list of"),
        pytest.param(
            '{"script": "' + "x" * (1 << 20) + '"}', "more than 1,048,576 bytes", id="1 MiB"
        ),
    ],
)
def test_a_sweep_json_that_is_not_an_object_refuses_in_one_line(fake_agent, tmp_path, text, reason):
    out = tmp_path / "out"
    out.mkdir()
    (out / "sweep.json").write_text(text)
    before = folder_state(out)
    result = run_sweep(str(fake_agent), "--out", str(out), "--runs", "1", "--sample", LR)
    assert result.returncode == 2
    assert result.stderr.startswith(f"error: {out / 'sweep.json'} is not a sweep's configuration")
    assert reason in result.stderr and result.stderr.count("\n") == 1
    assert folder_state(out) == before
    assert starts(fake_agent) == []


def test_where_the_runs_data_goes_is_each_starts_own(fake_agent, tmp_path):
    """The flags that send a run's data elsewhere (W&B tracking, its entity and project) are
    not the sweep's configuration: a sweep whose sweep.json has them, started again without
    them, is the same sweep, and its runs go without them."""
    out = tmp_path / "out"
    assert run_sweep(str(fake_agent), "--out", str(out), "--runs", "1").returncode == 0
    config = json.loads((out / "sweep.json").read_text())
    tracked = ["--track", "--wandb-entity", "someone-else", "--wandb-project-name=theirs"]
    config["fixed_flags"] = [*tracked, *config["fixed_flags"]]  # as a start with them wrote it
    (out / "sweep.json").write_text(json.dumps(config))
    result = run_sweep(str(fake_agent), "--out", str(out), "--runs", "2")
    assert result.returncode == 0, result.stderr
    assert [row["status"] for row in read_table(out)] == ["ok", "ok"]
    assert "--track" not in read_table(out)[1]["flags"]


def test_a_run_resumes_with_the_starts_own_flags_of_where_its_data_goes(tmp_path):
    """A run interrupted in an earlier start resumes from its checkpoint with the flags of this
    start that send its data elsewhere: --resume takes them from the command line only."""
    recorder = tmp_path / "recorder.py"
    recorder.write_text("import sys\nopen(sys.argv[0] + '.argv', 'w').write(repr(sys.argv[1:]))\n")
    run_dir = tmp_path / "runs" / "run-0000"
    run_dir.mkdir(parents=True)
    (run_dir / "checkpoint.pt").write_bytes(b"")  # left by the earlier start
    tracked = ["--track", "--wandb-entity", "me", "--wandb_project_name=mine"]
    command = [str(recorder), "--learning-rate", "0.001", *tracked, "--seed", "1", "--run-dir",
               str(run_dir)]  # fmt: skip
    assert sweep.execute_run(command, str(run_dir))["returncode"] == 0
    argv = Path(f"{recorder}.argv").read_text()
    assert argv == repr(["--resume", str(run_dir / "checkpoint.pt"), *tracked])


def test_the_sweeps_flags_of_where_data_goes_are_the_runs():
    from a3c_runtime.resume import ELSEWHERE, flag

    names = {f[2:] for f in map(flag, ELSEWHERE)}
    assert names <= set(sweep.ELSEWHERE_FLAGS) and set(sweep.ELSEWHERE_VALUED) < names


@pytest.mark.parametrize(
    "header",
    [
        "figure,game,line,seed,final_score,final_step",  # another tool's table
        "run_id,status,score,flags,error",
        # a sweep's, with another sampled flag than this sweep's (and no sweep.json to say so)
        "run_id,status,score,score_all,evaluations,final_step,wall_time_s,seed,grad-clip,flags,"
        "error",
    ],
)
def test_a_results_csv_with_an_unknown_header_is_refused_not_replaced(fake_agent, tmp_path, header):
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.csv").write_text(header + "\n" + ",".join(["x"] * header.count(",")) + ",y\n")
    before = folder_state(out)
    result = run_sweep(str(fake_agent), "--out", str(out), "--runs", "1", "--sample", LR)
    assert result.returncode == 2
    assert result.stderr.startswith(f"error: {out / 'results.csv'}")
    assert "nothing was run or replaced" in result.stderr and result.stderr.count("\n") == 1
    assert folder_state(out) == before
    assert starts(fake_agent) == []


def test_a_figure_whose_sweep_has_a_run_in_use_is_drawn_and_exits_3(monkeypatch, tmp_path, capsys):
    """thesis_figures and atari_figures (figure_sweeps.run_sweeps) go on past a sweep that exits
    3, draw what there is, and exit 3 rather than 0: the figure is not done yet."""
    from types import SimpleNamespace

    from a3c_tools import figure_sweeps

    codes = iter([0, 3])
    monkeypatch.setattr(figure_sweeps, "execute", lambda command: (next(codes), ""))
    lines = [
        SimpleNamespace(name=name, shared="", folder=tmp_path / name, command=lambda runs: [])
        for name in ("base", "other")
    ]
    drawn = []
    assert figure_sweeps.run_sweeps(lines, [2], "run", lambda: drawn.append(1)) == 3
    assert drawn == [1] and "a run in use elsewhere, not yet done: other" in capsys.readouterr().err


def test_a_signal_twice_at_once_is_one_stop_request(monkeypatch):
    """A SIGTERM to the process group reaches a campaign's sweep directly and passed on by the
    campaign, within milliseconds: that is one request (stop the runs cleanly, so that they
    write their checkpoints), where a second Ctrl-C seconds later kills them."""
    now = [100.0]
    monkeypatch.setattr(sweep.time, "monotonic", lambda: now[0])
    stop = sweep.StopRequests()
    stop._handle(signal.SIGTERM, None)
    now[0] += 0.01
    stop._handle(signal.SIGTERM, None)
    assert stop.level == 1
    now[0] += sweep.StopRequests.SAME_STOP_S
    stop._handle(signal.SIGINT, None)
    assert stop.level == 2
