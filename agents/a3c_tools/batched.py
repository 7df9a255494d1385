"""The sweep's batched backend (`python -m a3c_tools.sweep ... --backend batched`): which runs
it can batch (`batch_problem`, and `probe`: one update of the network under vmap), checked
before anything runs, and `run_batched`, the sweep's runs as batches of the runtime's
a3c_runtime.batched, each run's folder locked first with the runtime's own lock.

What it batches: the scripts of BATCHED_SCRIPTS (FF, LSTM, LWS, SS, WW, LPQ, GLPQ) on Catch-v0
with one worker and one env per run, RMSprop, fp32; runs that differ only in PER_RUN_FLAGS.
Anything else is refused in one line before anything runs.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from a3c_runtime import Checkpoint, UsageError, WriteFailed, load_checkpoint
from a3c_runtime.batched import (
    FILES_PER_RUN,
    BatchedA3C,
    BatchedRun,
    allow_open_files,
    train_batched,
)
from a3c_runtime.run_folder import LOCK_FILE, RunFolder
from a3c_runtime.snapshots import arrays_of

from catch_env.catch import BALL_START_ROW

# the scripts whose worker is a3c_ff.py's (GLPQ's adds its tau schedule and loss correction,
# LSTM's its recurrent state) and whose network vmaps
BATCHED_SCRIPTS = ("a3c_ff.py", "a3c_lstm.py", "a3c_lws.py", "a3c_ss.py", "a3c_ww.py",
                   "a3c_lpq.py", "a3c_glpq.py")  # fmt: skip
# flags that may differ between the runs of one batch; every other flag is the batch's
PER_RUN_FLAGS = ("seed", "learning_rate", "weight_init", "bias_init", "run_dir", "exp_name",
                 "eval_greedy")  # fmt: skip
# flag -> (what the batched backend needs, the check): a run with another value is refused
REQUIRED = {
    "env": ("Catch-v0", lambda v: v == "Catch-v0"),
    "num_workers": ("1", lambda v: v == 1),
    "envs_per_worker": ("1", lambda v: v == 1),
    "optimizer": ("rmsprop", lambda v: v == "rmsprop"),
    "precision": (
        "fp32 or auto (the batched runs compute in fp32)",
        lambda v: v in ("fp32", "auto"),
    ),
    "track": ("off", lambda v: not v),
    "capture_video": ("off", lambda v: not v),
    "time_limit": ("none", lambda v: v is None),
}
# a script's own flags that the batch needs at one value: GLPQ's tau is the batch's module state
# (its schedule follows the shared step), so a trainable tau, a parameter per run, is not batched
SCRIPT_REQUIRED = {
    "a3c_glpq.py": {
        "temperature": ("fixed, cold, hot or searing", lambda v: v != "trainable"),
    },
}


def batch_problem(script: str, runs_args: list[Any]) -> str | None:
    """Why these runs (their parsed, unresolved Args) cannot be one batch, in one line, or None."""
    name = os.path.basename(script)
    if name not in BATCHED_SCRIPTS:
        return (f"--backend batched runs {', '.join(BATCHED_SCRIPTS)}, not {name}; use "
                "--backend local")  # fmt: skip
    for args in runs_args:
        for flag, (needed, ok) in {**REQUIRED, **SCRIPT_REQUIRED.get(name, {})}.items():
            value = getattr(args, flag)
            if not ok(value):
                return (f"--backend batched cannot batch --{flag.replace('_', '-')} {value}: it "
                        f"needs {needed}; use --backend local")  # fmt: skip
    first = vars(runs_args[0])
    for args in runs_args[1:]:
        for flag, value in vars(args).items():
            if flag not in PER_RUN_FLAGS and value != first[flag]:
                return (f"--backend batched cannot batch runs that differ in "
                        f"--{flag.replace('_', '-')} ({first[flag]} and {value}): only "
                        f"{', '.join('--' + f.replace('_', '-') for f in PER_RUN_FLAGS)} may; "
                        "use --backend local")  # fmt: skip
    return None


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


def clear_run_folder(folder: RunFolder) -> None:
    """Remove what a partial run left in its locked folder, all but the lock file (removing
    that would let another process take the folder while this one trains there)."""
    for path in folder.path.iterdir():
        if path.name == LOCK_FILE:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


def planned_args(module: ModuleType, flags: list[str]) -> Any:
    """A run's Args as its command line gives them (unresolved), or UsageError in one line."""
    import contextlib
    import io

    import tyro

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            return tyro.cli(module.Args, args=flags)
    except SystemExit:
        # tyro's box (drawn in ASCII when stderr is not a terminal): a title, the message over
        # one or more lines, then the flag's help or a pointer to --help
        lines = [line.strip("│ ") for line in err.getvalue().splitlines()]
        body = [line for line in lines if line.strip("─-╭╮╰╯│ ")][1:]
        ends = [i for i, line in enumerate(body) if line.startswith(("Argument help", "For full"))]
        message = " ".join(body[: ends[0] if ends else len(body)])
        raise UsageError(f"the run flags {' '.join(flags)!r} do not parse: "
                         f"{message or 'see --help'}") from None  # fmt: skip


def check_batchable(script: str, runs: list[Any], out: Path) -> None:
    """UsageError (one line) unless the sweep's runs can be one batch: before anything runs."""
    from a3c_tools import load_script

    module = load_script(script)
    runs_args = [planned_args(module, run.command(script, out / "runs" / run.run_id)[1:])
                 for run in runs]  # fmt: skip
    problem = batch_problem(script, runs_args)
    if problem is not None:
        raise UsageError(problem)
    probe(module, [resolve_run_args(copy.deepcopy(args)) for args in runs_args[:2]])


def probe(module: ModuleType, runs_args: list[Any]) -> None:
    """UsageError (one line) where the network with these flags does not run under vmap (a
    layer that branches on its data, say): one update of a batch of these runs, before any run
    folder exists."""
    runs = [BatchedRun(dataclasses.replace(args, total_timesteps=10**9)) for args in runs_args]
    try:
        BatchedA3C(module, runs, "cpu").update()
    except UsageError:
        raise
    except Exception as e:  # functorch's "Batching rule not implemented for ...", and the like
        detail = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"--backend batched cannot batch {module.AGENT.script} with these "
                         f"flags: its network does not run under vmap ({detail}); use --backend "
                         "local") from None  # fmt: skip


def resolve_run_args(args: Any) -> Any:
    """A run's Args with the defaults filled in; the batched runs compute in fp32."""
    from a3c_runtime import resolve_defaults

    args.precision = "fp32"  # (auto: the batched backend's only precision)
    return resolve_defaults(args)


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
    from a3c_tools import load_script
    from a3c_tools.run_lock import IN_USE_TEXT, run_holder

    module = load_script(script)
    allow_open_files(FILES_PER_RUN * len(todo) + 256)
    groups: dict[tuple[int, int], list[tuple[Any, BatchedRun]]] = {}
    folders: list[RunFolder] = []
    try:
        for run in todo:
            run_dir = out / "runs" / run.run_id
            args = resolve_run_args(planned_args(module, run.command(script, run_dir)[1:]))
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
                clear_run_folder(folder)
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
