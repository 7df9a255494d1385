"""A run is the same run in any batch (issue 101): run k of the batched backend ends bit for bit
the same, its network, optimizer statistics, generator, game and evaluations, whether it ran
alone, in a batch of 2 or in a batch of 7; so a sweep killed at any moment, whose restart
regroups its runs by the step each checkpoint left them at, ends as the sweep that was never
killed."""

import csv
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from a3c_runtime import batched, load_checkpoint
from a3c_runtime.batched import BatchedA3C, BatchedRun, train_batched
from conftest import ROOT, load_script, tiny_args

NETWORKS = ("a3c_ff", "a3c_lstm", "a3c_lws", "a3c_ss", "a3c_ww", "a3c_lpq", "a3c_glpq")
SEEDS_AND_RATES = [(1 + 1000 * i, rate) for i, rate in
                   enumerate((7e-4, 3e-3, 1e-4, 2e-3, 5e-4, 1e-3, 4e-4))]  # fmt: skip
K = 3  # the run compared (one of the 7)


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    batched.set_up_device("cpu")


def batch_of(module, indices, **flags) -> BatchedA3C:
    runs = [BatchedRun(tiny_args(module, seed=SEEDS_AND_RATES[i][0],
                                 learning_rate=SEEDS_AND_RATES[i][1], precision="fp32", **flags))
            for i in indices]  # fmt: skip
    return BatchedA3C(module, runs, "cpu")


@pytest.mark.parametrize("name", NETWORKS)
def test_every_networks_run_is_bit_identical_alone_and_in_batches_of_2_and_7(name):
    # three updates: the first already takes other kernels for one run than for two or more
    # (the value head's matrix-vector product; a convolution's weight gradient)
    module = load_script(name)
    found = []
    for indices in ([K], [K, 0], list(range(7))):
        batch = batch_of(module, indices, t_max=5, total_timesteps=10**6)
        for _ in range(3):
            batch.update()
        i = indices.index(K)
        found.append([t[i].clone() for t in [*batch.params, *batch.optimizer.square_avg]])
    for other in found[1:]:
        assert all(torch.equal(a, b) for a, b in zip(found[0], other, strict=True))


def same(a, b) -> bool:
    """Bit for bit, through dicts, sequences, tensors and arrays."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return a == b


def run_state(module, run_dir: Path) -> tuple:
    """A run folder's checkpoint (network, optimizer, step, worker) and evaluations (all but
    their wall time)."""
    checkpoint = load_checkpoint(str(run_dir / "checkpoint.pt"), module.AGENT)
    with open(run_dir / "evaluations.csv") as f:
        rows = [{k: v for k, v in row.items() if k != "wall_time_s"}
                for row in csv.DictReader(f)]  # fmt: skip
    return (checkpoint.model, checkpoint.optimizer, checkpoint.global_step, checkpoint.workers,
            rows)  # fmt: skip


def run_k_in_batches(tmp_path: Path, steps: int, t_max: int = 5) -> list[tuple]:
    """Run K's checkpoint (network, optimizer, step, worker) and evaluations (all but their wall
    time) after `steps`, trained alone, in a batch of 2 and in a batch of 7."""
    module = load_script("a3c_ff")
    found = []
    for indices in ([K], [K, 0], list(range(7))):
        folder = tmp_path / f"batch-of-{len(indices)}"
        runs = [BatchedRun(tiny_args(module, seed=SEEDS_AND_RATES[i][0],
                                     learning_rate=SEEDS_AND_RATES[i][1], precision="fp32",
                                     total_timesteps=steps, t_max=t_max,
                                     eval_interval=steps // 2,
                                     eval_episodes=3, run_dir=str(folder / f"run-{i}")))
                for i in indices]  # fmt: skip
        train_batched(module, runs, "cpu", log_interval=1e9)
        found.append(run_state(module, folder / f"run-{K}"))
    return found


def test_a_runs_checkpoint_and_evaluations_are_the_same_in_any_batch(tmp_path):
    alone, of_two, of_seven = run_k_in_batches(tmp_path, 60)
    assert alone[2] == 60 and len(alone[4]) == 3  # steps 0, 30 and 60
    assert same(alone, of_two) and same(alone, of_seven)


@pytest.mark.slow
def test_a_runs_checkpoint_after_2000_steps_is_the_same_in_any_batch(tmp_path):
    alone, of_two, of_seven = run_k_in_batches(tmp_path, 2000, t_max=20)  # the default
    assert alone[2] >= 2000  # (whole episodes of 15 steps: 2,010)
    assert same(alone, of_two) and same(alone, of_seven)


# --- faults: a batched sweep killed again and again ----------------------------------------
RUNS, STEPS = 2, 1500  # a sweep of 2 runs, checkpointed every 60 steps (4 episodes of 15)
SWEEP = ["agents/a3c_ff.py", "--runs", str(RUNS), "--total-timesteps", str(STEPS),
         "--backend", "batched", "--sample", "learning-rate=loguniform:1e-4:1e-2", "--",
         "--eval-interval", "300", "--eval-episodes", "3",
         "--checkpoint-interval", "60"]  # fmt: skip
# the sweep, killed (SIGKILL) right after run-0000's checkpoint at `step` is written and before
# run-0001's is: a restart then finds its runs at different steps and batches them apart
KILLED_BETWEEN_WRITES = """
import os, signal, sys
sys.path[:0] = [{agents!r}, {root!r}]
import a3c_runtime.batched as b
write = b.save_checkpoint
def save_checkpoint(path, shared, args, wall_time, script, snapshot):
    write(path, shared, args, wall_time, script, snapshot)
    if path.parent.name == "run-0000" and snapshot["global_step"] >= {step}:
        os.kill(os.getpid(), signal.SIGKILL)
b.save_checkpoint = save_checkpoint
from a3c_tools.sweep import main
sys.exit(main(sys.argv[1:]))
"""


def sweep_command(out: Path, killed_at: int | None = None) -> list[str]:
    if killed_at is None:
        return [sys.executable, "-m", "a3c_tools.sweep", *SWEEP[:1], "--out", str(out), *SWEEP[1:]]
    code = KILLED_BETWEEN_WRITES.format(agents=str(ROOT / "agents"), root=str(ROOT),
                                        step=killed_at)  # fmt: skip
    return [sys.executable, "-c", code, *SWEEP[:1], "--out", str(out), *SWEEP[1:]]


def sweep_env() -> dict:
    paths = [str(ROOT / "agents"), str(ROOT), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in paths if p)}


def final_state(out: Path) -> list[tuple]:
    module = load_script("a3c_ff")
    found = []
    for i in range(RUNS):
        found.append(run_state(module, out / "runs" / f"run-{i:04d}"))
    with open(out / "results.csv") as f:
        scores = sorted((row["run_id"], row["status"], row["score"]) for row in csv.DictReader(f))
    return [*found, scores]


@pytest.mark.slow
def test_a_batched_sweep_killed_ten_times_ends_as_the_sweep_never_killed(tmp_path):
    whole = subprocess.run(sweep_command(tmp_path / "whole"), cwd=ROOT, env=sweep_env(),
                           capture_output=True, text=True, timeout=600)  # fmt: skip
    assert whole.returncode == 0, whole.stdout + whole.stderr
    out, rng, kills = tmp_path / "killed", random.Random(101), 0
    # first the kill between two runs' checkpoint writes, then kills at random moments
    between = subprocess.run(sweep_command(out, killed_at=120), cwd=ROOT, env=sweep_env(),
                             capture_output=True, text=True, timeout=600)  # fmt: skip
    assert between.returncode == -signal.SIGKILL, between.stdout + between.stderr
    kills += 1
    module = load_script("a3c_ff")
    steps = [load_checkpoint(str(out / "runs" / f"run-{i:04d}" / "checkpoint.pt"),
                             module.AGENT).global_step for i in range(2)]  # fmt: skip
    assert steps[0] > steps[1]  # the restart finds them at different steps
    checkpoint = out / "runs" / "run-0000" / "checkpoint.pt"
    while kills < 11:  # each kill at a random moment: in the start, or among the checkpoints
        process = subprocess.Popen(sweep_command(out), cwd=ROOT, env=sweep_env(),
                                   stdout=subprocess.DEVNULL,
                                   stderr=subprocess.DEVNULL)  # fmt: skip
        let_through = rng.choice((0, 1, 2))  # checkpoint writes before the kill
        seen, left = checkpoint.stat().st_mtime_ns, let_through
        while left and process.poll() is None:
            time.sleep(0.02)  # (a checkpoint is renamed into place whole: its time, its write)
            if checkpoint.stat().st_mtime_ns != seen:
                seen, left = checkpoint.stat().st_mtime_ns, left - 1
        time.sleep(rng.uniform(0.2, 3.0) if let_through == 0 else rng.uniform(0.0, 0.3))
        assert process.poll() is None, "the sweep finished before its kill: make it longer"
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=60)
        kills += 1
    last = subprocess.run(sweep_command(out), cwd=ROOT, env=sweep_env(), capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert last.returncode == 0, last.stdout + last.stderr
    assert same(final_state(out), final_state(tmp_path / "whole"))
