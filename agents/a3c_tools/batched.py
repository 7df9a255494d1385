"""The sweep's batched backend (`python -m a3c_tools.sweep ... --backend batched`): the sweep's
runs checked before anything runs (the runtime's `batch_problem`, a3c_runtime.batchable, and
`probe`: one update of the network under vmap), and `run_batched`, the sweep's runs as batches
of the runtime's a3c_runtime.batched, each run's folder locked first with the runtime's own
lock. Anything the batch cannot take is refused in one line before anything runs.
"""

from __future__ import annotations

import copy
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from a3c_runtime import Checkpoint, UsageError, WriteFailed, load_checkpoint
from a3c_runtime.batchable import batch_problem, resolve_run_args
from a3c_runtime.batched import (
    FILES_PER_RUN,
    BatchedA3C,
    BatchedRun,
    allow_open_files,
    train_batched,
)
from a3c_runtime.run_folder import RunFolder
from a3c_runtime.snapshots import arrays_of

from catch_env.catch import BALL_START_ROW


def resumable_checkpoint(agent: Any, run_dir: Path) -> Checkpoint | None:
    """The run folder's checkpoint if it holds the worker's state (an exact resume), else None
    (the run starts again)."""
    path = run_dir / "checkpoint.pt"
    if not path.is_file():
        return None
    checkpoint = load_checkpoint(str(path), agent)
    return checkpoint if checkpoint.workers.get(0) else None


def episode_row(checkpoint: Checkpoint | None) -> int:
    """The row of the ball in the game a run resumes (a new run's: the start row). A game of
    Catch ends when its ball, falling a row per step, reaches the paddle's row, so runs whose
    balls are on one row end their episodes at the same steps for as long as they run: the
    lockstep of a batch. Runs at one global step may differ: a run resumed by hand with more
    workers for a while counts their steps too."""
    if checkpoint is None:
        return BALL_START_ROW
    env_state = arrays_of(checkpoint.workers[0][1]["env"])  # (restored_state reads it so)
    return int(np.asarray(env_state["env"]["ball_row"])[0])


def check_batchable(script: str, runs_args: list[Any] | None, device: str = "cpu") -> None:
    """UsageError (one line) unless the sweep's runs (their parsed Args: a3c_tools.sweep's
    checked_run_args; None for a script that is not an agent's) can be one batch on device: before
    anything runs."""
    if runs_args is None:  # (no Args to batch: not an agent script)
        raise UsageError(f"--backend batched runs the agent scripts, not {script}; use "
                         "--backend local")  # fmt: skip
    problem = batch_problem(script, runs_args)
    if problem is not None:
        raise UsageError(problem)
    if runs_args[0].precision == "tf32" and device != "cuda":
        raise UsageError("--precision tf32 is a GPU's: it needs --device cuda")
    from a3c_tools import load_script

    module = load_script(script)
    probe(module, [resolve_run_args(copy.deepcopy(args)) for args in runs_args[:2]])


def probe(module: ModuleType, runs_args: list[Any]) -> None:
    """UsageError (one line) where the network with these flags does not run under vmap (a
    layer that branches on its data, say): one update of a batch of these runs, before any run
    folder exists."""
    runs = [BatchedRun(dataclasses.replace(args, total_timesteps=10**9, precision=(
        "fp32" if args.precision == "tf32" else args.precision)))  # (TF32: the network's fp32)
        for args in runs_args]  # fmt: skip
    try:
        BatchedA3C(module, runs, "cpu").update()
    except UsageError:
        raise
    except Exception as e:  # functorch's "Batching rule not implemented for ...", and the like
        detail = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"--backend batched cannot batch {module.AGENT.script} with these "
                         f"flags: its network does not run under vmap ({detail}); use --backend "
                         "local") from None  # fmt: skip


def run_batched(
    script: str,
    todo: list[Any],
    out: Path,
    record: Callable[[Any, dict], None],
    should_stop: Callable[[], str | None],
    device: str,
) -> None:
    """The sweep's runs `todo` (a3c_tools.sweep.Run) as batches on `device`. Each run's folder
    is locked first, with the runtime's own lock, as the run itself would lock it: a run in use
    elsewhere (resumed by hand) is neither read nor touched, and is recorded "in use", as the
    process backend records it. The runs that resume from the same step (their checkpoints'; 0
    for new ones), their games at the same step of an episode, are one batch. Each finished run
    is recorded as the process backend records it; a stopped batch records nothing (its runs
    resume from their checkpoints on the next start). should_stop() names the signal that stops
    the sweep, or None."""
    from a3c_tools import load_script, parsed_flags
    from a3c_tools.run_lock import IN_USE_TEXT, clear_run_folder, run_holder

    module = load_script(script)
    allow_open_files(FILES_PER_RUN * len(todo) + 256)
    groups: dict[tuple[int, int], list[tuple[Any, BatchedRun]]] = {}
    folders: list[RunFolder] = []
    try:
        for run in todo:
            run_dir = out / "runs" / run.run_id
            args = resolve_run_args(parsed_flags(module.Args, run.command(script, run_dir)[1:]))
            try:  # before anything in the folder is read or changed
                folder = RunFolder(run_dir)
            except UsageError as e:
                if IN_USE_TEXT in str(e):  # resumed by hand, say: left alone, runs next time
                    holder = run_holder(run_dir) or "?"
                    result = {"returncode": None, "interrupted": False, "in_use": holder}
                else:  # (a file in its place, say) failed, as the run itself would fail
                    result = {"returncode": 2, "interrupted": False, "in_use": None,
                              "stdout_tail": "", "stderr_tail": f"error: {e}",
                              "evaluations_csv": None}  # fmt: skip
                record(run, {**result, "wall_time_s": 0.0})
                continue
            folders.append(folder)
            checkpoint = resumable_checkpoint(module.AGENT, run_dir)
            if checkpoint is None:  # a partial run that wrote no checkpoint starts again
                clear_run_folder(run_dir)
            start = checkpoint.global_step if checkpoint else 0
            group = groups.setdefault((start, episode_row(checkpoint)), [])
            group.append((run, BatchedRun(args, checkpoint, folder)))
        for key in sorted(groups):
            if should_stop():
                return
            start, group = key[0], groups[key]
            where = f"resuming at step {start:,}" if start else "from step 0"
            print(f"batched: {len(group)} runs on {device}, {where}", flush=True)
            try:
                outcomes = train_batched(module, [batch for _, batch in group], device, should_stop)
            except (WriteFailed, OSError) as e:  # a full disk, say: the checkpoints are whole
                print(f"error: {e}; each run's last checkpoint survives: start the sweep again "
                      "to resume them", file=sys.stderr, flush=True)  # fmt: skip
                raise SystemExit(1) from None
            for (run, batched), outcome in zip(group, outcomes, strict=True):
                if outcome["outcome"] != "done":
                    continue  # resumes next time
                csv_path = Path(batched.args.run_dir) / "evaluations.csv"
                record(run, {"returncode": 0, "interrupted": False,
                             "wall_time_s": outcome["wall_time_s"],
                             "stdout_tail": outcome["stdout"], "stderr_tail": "",
                             "evaluations_csv": csv_path.read_text()})  # fmt: skip
            for _, batched in group:  # its part done: free for a run resumed by hand
                batched.folder.close()
    finally:
        for folder in folders:
            folder.close()
