"""Sweep an agent script: run it many times with sampled flags and collect one results table.

The thesis's Catch figures (6.3, 6.5-6.8, 7.1-7.7, A.1, A.2, C.1) are learning-rate sweeps: 50 to
100 runs per configuration, the learning rate log-uniform in [1e-6, 1e-2], 1M steps each, each
run scored by the mean of its final 5 evaluations. This tool runs such sweeps on one machine or
on a Ray cluster; `a3c_tools.plot_sweep` draws the thesis's figure from the results.

    python -m a3c_tools.sweep agents/a3c_ff.py --out sweeps/a3c_ff --runs 50 \\
        --total-timesteps 1000000 --sample learning-rate=loguniform:1e-6:1e-2 -- --num-workers 1
    python -m a3c_tools.plot_sweep sweeps/a3c_ff/results.csv --labels "A3C FF" --out a3c_ff.png

Everything after `--` is passed unchanged to every run (the fixed flags). Samples, one
`--sample NAME=DIST` per flag, drawn independently for each run:

    loguniform:LOW:HIGH   exp(U(ln LOW, ln HIGH)), e.g. learning-rate=loguniform:1e-6:1e-2
    uniform:LOW:HIGH      U(LOW, HIGH)
    choice:A,B,C          one of the values, each equally likely: activation=choice:relu,elu

Before anything is created, every sampled and fixed flag is checked against the script: one it
lacks is refused (exit 2) with the nearest one it has ("--sample lr: a3c_ff.py has no flag
--lr; did you mean --learning-rate?"). An agent script's flags are its Args dataclass's fields,
read by importing it (tyro's spellings: --learning-rate or --learning_rate, --no-x for a bool);
a script without a top-level Args (an argparse script) is asked for its --help, and one whose
--help fails is not checked. An agent script's runs are then checked as each run checks itself
at its start (tyro's parse, the runtime's ranges, the network's own checks, --precision tf32 off
a GPU): a run that would refuse to start refuses the sweep, in one line naming the run and its
sampled values ("run-0001 (gamma=1.09943): --gamma must be in [0, 1] (got 1.09943); nothing was
run"), exit 2, before anything is created.

Runs. Run i (run id run-0000, run-0001, ...) is `python SCRIPT FIXED SAMPLED --total-timesteps T
--seed SEED+1000*i --run-dir OUT/runs/run-000i` (no --total-timesteps when none is given: the
script's default). Its sampled values come from a generator seeded with (--seed, i) alone, so a
sweep started again, or extended with a larger --runs, draws the same values for the same runs.
Floats are written with 6 significant digits, and that string is both what the run gets and what
the table records. Run seeds are 1000 apart, so that even a script that seeded its workers with
seed + worker index would give different runs disjoint worker seeds.

Workers per run. A run's CPUs are its --num-workers (fixed or sampled). With none given, the sweep
passes --num-workers 1 (the scripts' own default is one worker per core, which would let one run
take the whole machine): on one machine, many single-worker runs side by side is the most
efficient use of the cores, with no Hogwild contention. Note that the thesis ran Catch with 12
workers per run, and the number of workers changes how a learning rate behaves; pass
`-- --num-workers 12` to match it.

Scores. A finished run's evaluations.csv gives `score`, the mean of its final 5 evaluations
(fewer when it has fewer; the one at step 0, of the untrained network, never counts unless it is
the only one), as the thesis scores a run, and `score_all`, the mean of all of its evaluations,
the one at step 0 included (the thesis's "mean score on 20 evaluations" panel).

The results table OUT/results.csv has a row per finished run: run_id, status (ok or failed),
score, score_all, evaluations, final_step, wall_time_s (a resumed run's counts its earlier
parts), seed, one column per sampled flag, flags (the run's flags, ready to paste after the
script) and error. A failed run (non-zero exit, no evaluations, or stopped by a signal the sweep
did not send) is recorded with its error (its exit, `error:` line and last meaningful stderr
line: a tyro error box's message, not its borders) and does not stop the sweep; its logs stay in
OUT/runs/<run_id>/stdout.log and stderr.log. The table is rewritten to a temporary file, flushed
to disk and renamed over the old one after each run, so it is always whole. A results.csv whose
header is not a sweep's (run_id, status, ... seed, the sampled flags, flags, error) refuses the
sweep in one line, exit 2, rather than be replaced and its rows lost; so does a sweep.json that
is not a JSON object (truncated, say).

A run in use elsewhere (its folder locked by a process training there: a run resumed by hand,
`--resume OUT/runs/<run_id>/checkpoint.pt`) is not started, not touched and not recorded: the
sweep says "in use" and picks it up when started again once that process has ended (it resumes
from the checkpoint the process left, or, finished, is scored as it is; its checkpoint is
judged, as below, only then). A row that an earlier version of this tool recorded as failed
for that reason ("... is in use by process ...") is run again too.

One sweep per folder: a sweep locks OUT/runs/sweep.lock (which holds its pid) before it reads
or writes anything else in OUT, and removes it when it ends; another sweep started into the same
OUT, even at the same instant, exits 2 naming it. A killed sweep leaves the file, unlocked: the
next sweep takes it.

Resuming. OUT/sweep.json holds the sweep's configuration (script name, samples, fixed flags,
step budget, seed). Started again with the same OUT, the sweep refuses a different configuration
(exit 2, naming what differs) and otherwise skips every run in the table (ok or failed); a run
that was in progress resumes from its checkpoint with its own flags (`--resume`, which keeps
every flag of the run; a run that had finished, its row not yet in the table, is scored as it
is), or starts again from scratch where it had written none (its run folder is deleted first).
A checkpoint in a run's folder that is not that run's (another script's, other flags or another
seed than the run's, or one that does not load safely) refuses the sweep in one line, exit 2,
before anything runs, naming the folder to move or remove. --runs, the backend and the
concurrency may change between starts, and so may the flags after `--` that send the runs' data
elsewhere (--track, --wandb-entity, --wandb-project-name): they are not the configuration, and a
run resumes with this start's (a3c_runtime.resume: never a checkpoint's). A sweep.json is
checked before any of it is used: a JSON object (nested no deeper than a parser can read, 1 MiB
at most) whose fields have their types (CONFIG_FIELDS).

Ctrl-C (SIGINT) or SIGTERM stops the sweep: no new runs start, each running run gets SIGINT (the
scripts checkpoint and exit) and is not recorded, so it resumes from its checkpoint on the next
start; exit code 130.
A second Ctrl-C (2 s or more after the first: a signal to the whole process group that also
reaches it through a campaign is one request) kills the runs at once. Were the sweep killed
outright, its runs get SIGTERM from the kernel (Linux) and stop in the same way. On Ray, the
sweep cancels its tasks: a running task stops its run with SIGINT, a queued one is dropped, and
a second Ctrl-C kills the tasks.

Backends.
- local (default): runs are subprocesses on this machine, started in order while the CPUs they
  reserve (their workers) fit in --cpus (default: the cores this process may use), and at most
  --max-concurrent at once; for uniform runs that is max(1, cores // workers per run) at once.
- ray (`--backend ray`, needs `pip install -e "./agents[ray]"`): each run is a Ray task that
  reserves num_cpus = its workers, so Ray spreads the runs over a cluster. Without --address it
  starts a local Ray instance with --cpus CPUs; `--address auto` or `--address HOST:PORT` joins
  a running cluster (`ray start --head` on one node, `ray start --address HOST:PORT` on the
  others). Every node needs the repository at the same path with the packages installed. The
  task returns the run's evaluations.csv and log tails, which the sweep writes into its own
  OUT/runs/<run_id>/ when the run ran on another node, so OUT need not be a shared file system.
  A task whose node dies is retried by Ray (3 times, its default), from scratch.
- batched (`--backend batched`, `--device cpu|cuda`): the runs as one batched program on one
  device (a3c_runtime.batched): run i is the script's own one-worker run with its seed and flags
  (tests/test_batched.py), the same run in any batch (tests/test_batched_invariance.py), its
  folder gets what a run writes (evaluations.csv, TensorBoard scalars, checkpoint.pt,
  stdout.log), locked as a run locks it (a run in use elsewhere is left alone, as above). It
  runs a3c_ff.py, a3c_lstm.py, a3c_lws.py, a3c_ss.py, a3c_ww.py, a3c_lpq.py and a3c_glpq.py
  (a3c_runtime.batchable) on Catch-v0 with one worker; the runs may differ in their seed,
  learning rate, weight and bias init; anything else it cannot batch is refused in one line
  (exit 2) before anything runs. Ctrl-C or SIGTERM checkpoints every run at its last update
  (its stdout.log names the signal); the next start resumes them.

Exit codes: 0 when every run is in the table and at least one is ok, 1 when every run failed,
2 for bad arguments, a mismatched configuration or an OUT whose sweep.json or results.csv is not
a sweep's, 3 when a run was in use elsewhere (the others are recorded; start the sweep again
once it is free), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import ast
import concurrent.futures
import contextlib
import copy
import csv
import ctypes
import dataclasses
import difflib
import functools
import importlib.util
import io
import itertools
import json
import math
import os
import random
import re
import reprlib
import shlex
import signal
import subprocess
import sys
import time
import typing
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from a3c_tools import load_script, parsed_flags, run_main, tool_parser, tyro_message
from a3c_tools.run_lock import IN_USE_TEXT, clear_run_folder, run_holder

SCORE_LAST = 5  # the thesis scores a run by the mean of its final 5 evaluations
SEED_STRIDE = 1000  # run i gets seed + SEED_STRIDE * i
TABLE_NAME = "results.csv"
CONFIG_NAME = "sweep.json"
RUNS_DIR = "runs"
FIXED_COLUMNS = [
    "run_id",
    "status",
    "score",
    "score_all",
    "evaluations",
    "final_step",
    "wall_time_s",
    "seed",
]
TRAILING_COLUMNS = ["flags", "error"]
# flags the sweep sets itself for each run
RESERVED_FLAGS = {"total-timesteps", "seed", "run-dir", "runs-root", "resume", "evaluate"}
# the flags that send a run's data elsewhere (a3c_runtime.resume.ELSEWHERE: W&B tracking, its
# entity and project): a command line's alone, never taken from a file someone hands on (a
# sweep.json, a campaign's plan, a checkpoint), and no part of a sweep's configuration
ELSEWHERE_FLAGS = ("track", "no-track", "wandb-entity", "wandb-project-name")
ELSEWHERE_VALUED = ("wandb-entity", "wandb-project-name")  # each followed by its value
STOP_GRACE_S = 30.0  # how long a run may take to checkpoint and exit after SIGINT
TAIL_CHARS = 4000
RAY_MISSING = '--backend ray needs Ray: pip install -e "./agents[ray]" (or pip install ray)'
IN_USE_EXIT = 3


class UsageError(Exception):
    """Bad arguments, or an output folder holding a sweep with another configuration."""


# ------------------------------------------------------------------------------------------------
# Sampling
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sample:
    """One sampled flag: `name=kind:...` with kind loguniform, uniform or choice."""

    name: str
    kind: str
    low: float = 0.0
    high: float = 0.0
    choices: tuple[str, ...] = ()

    def draw(self, u: float) -> str:
        """The flag's value for a uniform draw u in [0, 1), as the run gets it."""
        if self.kind == "choice":
            return self.choices[min(int(u * len(self.choices)), len(self.choices) - 1)]
        if self.kind == "loguniform":
            value = math.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))
        else:
            value = self.low + u * (self.high - self.low)
        return format(value, ".6g")

    def spec(self) -> str:
        if self.kind == "choice":
            return f"{self.name}=choice:{','.join(self.choices)}"
        return f"{self.name}={self.kind}:{self.low!r}:{self.high!r}"


def parse_sample(text: str) -> Sample:
    """Parse `NAME=loguniform:LOW:HIGH`, `NAME=uniform:LOW:HIGH` or `NAME=choice:A,B,...`."""
    name, sep, dist = text.partition("=")
    name = name.strip().lstrip("-")
    kind, _, rest = dist.partition(":")
    usage = (
        f"--sample {text!r}: expected NAME=loguniform:LOW:HIGH, NAME=uniform:LOW:HIGH or "
        "NAME=choice:A,B,..."
    )
    if not sep or not name or kind not in ("loguniform", "uniform", "choice"):
        raise UsageError(usage)
    if name in RESERVED_FLAGS:
        raise UsageError(f"--sample {text!r}: the sweep sets --{name} itself")
    if kind == "choice":
        choices = tuple(c for c in rest.split(",") if c)
        if not choices:
            raise UsageError(usage)
        return Sample(name, kind, choices=choices)
    try:
        low, high = (float(v) for v in rest.split(":"))
    except ValueError:
        raise UsageError(usage) from None
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise UsageError(f"--sample {text!r}: need finite LOW < HIGH")
    if kind == "loguniform" and low <= 0:
        raise UsageError(f"--sample {text!r}: loguniform needs LOW > 0")
    return Sample(name, kind, low, high)


def sample_values(samples: list[Sample], sweep_seed: int, index: int) -> dict[str, str]:
    """Run `index`'s sampled flag values. Python's random() stream is guaranteed stable across
    versions for a given seed, so a restarted sweep draws exactly the same values."""
    rng = random.Random(f"sweep-{sweep_seed}-run-{index}")
    return {sample.name: sample.draw(rng.random()) for sample in samples}


def flag_value(flags: list[str], name: str) -> str | None:
    """The last value given to --name in flags (`--name V` or `--name=V`), else None."""
    value = None
    for i, flag in enumerate(flags):
        if flag == f"--{name}" and i + 1 < len(flags):
            value = flags[i + 1]
        elif flag.startswith(f"--{name}="):
            value = flag.split("=", 1)[1]
    return value


# ------------------------------------------------------------------------------------------------
# The script's flags: a flag it lacks is refused before any run starts
# ------------------------------------------------------------------------------------------------
HELP_TIMEOUT_S = 60.0


def split_elsewhere(flags: list[str]) -> tuple[list[str], list[str]]:
    """(the flags without those that send data elsewhere, ELSEWHERE_FLAGS; those, with their
    values), each in its order."""
    kept, elsewhere = [], []
    words = iter(flags)
    for word in words:
        flagged = isinstance(word, str) and word.startswith("--")  # a plan's may be of any type
        name = word[2:].split("=", 1)[0].replace("_", "-") if flagged else ""
        if name not in ELSEWHERE_FLAGS:
            kept.append(word)
            continue
        elsewhere.append(word)
        if name in ELSEWHERE_VALUED and "=" not in word:
            elsewhere.extend(itertools.islice(words, 1))  # its value
    return kept, elsewhere


def script_flags(script: Path) -> dict[str, str] | None:
    """The flags `script` accepts, each spelling mapped to the one its --help shows, or None
    when they cannot be told. An agent script (one that defines `Args` at its top level and
    runs only under a `__main__` guard, seen without running it) is loaded as a module and its
    Args dataclass read as tyro turns it into flags: field learning_rate is --learning-rate or
    --learning_rate, a bool field also has --no-x. Any other script (an argparse one, such as
    the tests' fake agent) is run with --help, and every --flag its help text names counts."""
    args_type = agent_args(script)
    if args_type is not None:
        return _dataclass_flags(args_type)
    try:
        result = subprocess.run(
            [sys.executable, str(script), "--help"],
            capture_output=True,
            text=True,
            errors="replace",
            timeout=HELP_TIMEOUT_S,
            stdin=subprocess.DEVNULL,
            env={**os.environ, "COLUMNS": "200"},  # fewer wrapped lines
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    names = set(re.findall(r"(?<![\w-])--([A-Za-z0-9](?:[\w-]*\w)?)", result.stdout))
    if result.returncode != 0 or not names - {"help"}:
        return None
    return {name: name for name in names}


def agent_args(script: Path) -> type | None:
    """The Args dataclass of an agent script (one that defines Args at its top level and runs
    only under a `__main__` guard, loaded as a module), or None for any other script, one that
    cannot be imported, or one whose file name another loaded script already has."""
    if not _importable_agent(script):
        return None
    with contextlib.suppress(Exception):  # it cannot be imported
        module = load_script(script)
        # load_script keeps one module per file name: make sure it is this file
        same = Path(getattr(module, "__file__", "")).resolve() == script.resolve()
        if same and dataclasses.is_dataclass(getattr(module, "Args", None)):
            return module.Args
    return None


def _importable_agent(script: Path) -> bool:
    """Whether the script defines (or imports) Args at its top level and runs only under
    `if __name__ == "__main__":`, so that importing it runs nothing."""
    try:
        tree = ast.parse(script.read_bytes())
    except (SyntaxError, ValueError):
        return False
    args = guarded = False
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            args = args or node.name == "Args"
        elif isinstance(node, ast.ImportFrom):
            args = args or any((a.asname or a.name) == "Args" for a in node.names)
        elif isinstance(node, ast.If):
            names = {n.id for n in ast.walk(node.test) if isinstance(n, ast.Name)}
            guarded = guarded or "__name__" in names
    return args and guarded


def _dataclass_flags(args_type: type) -> dict[str, str]:
    try:
        hints = typing.get_type_hints(args_type)
    except Exception:  # an annotation that does not resolve: no --no-x flags then
        hints = {}
    flags = {}
    for field in dataclasses.fields(args_type):
        names = [field.name.replace("_", "-")]
        if hints.get(field.name) is bool:  # not `bool | None`, which tyro gives no --no-x
            names.append(f"no-{names[0]}")
        for name in names:
            flags[name] = name
            flags[name.replace("-", "_")] = name
    return flags


def check_flags(
    script: Path,
    samples: list[Sample],
    fixed: list[str],
    total_timesteps: int | None,
    fixed_from: str = "after `--`",
) -> None:
    """UsageError for the first sampled, fixed (after `--`, or where fixed_from says) or
    sweep-passed flag that the script does not have, naming the nearest one it has. A script
    whose flags cannot be told is not checked (a note says so)."""
    flags = script_flags(script)
    if flags is None:
        print(f"note: {script.name}'s flags are unknown (its --help failed); not checked")
        return
    given = [(f"--sample {sample.name}", sample.name) for sample in samples]
    given += [(fixed_from, t[2:].split("=", 1)[0]) for t in fixed if t.startswith("--")]
    for where, name in given:
        if name and name not in flags:
            raise UsageError(f"{where}: {script.name} has no flag --{name}; {_hint(name, flags)}")
    passed = ["run-dir", "seed"]  # as plan_runs passes them
    if total_timesteps is not None:
        passed.append("total-timesteps")
    if "num-workers" not in {name.replace("_", "-") for _, name in given}:
        passed.append("num-workers")
    for name in passed:
        if name not in flags:
            raise UsageError(
                f"{script.name} has no flag --{name}, which the sweep passes to every run"
            )


def _hint(name: str, flags: dict[str, str]) -> str:
    """'did you mean --x?' for the flag nearest name, else the list of the script's flags."""
    choices = sorted(set(flags.values()) - RESERVED_FLAGS - {"help"})
    wanted = name.replace("_", "-")
    # an abbreviation of the words first (lr: learning-rate), then the nearest spelling
    initials = [c for c in choices if "".join(w[0] for w in c.split("-") if w) == wanted]
    near = initials or difflib.get_close_matches(wanted, choices, n=1, cutoff=0.6)
    if near:
        return f"did you mean --{near[0]}?"
    return "its flags: " + ", ".join(f"--{c}" for c in choices)


# ------------------------------------------------------------------------------------------------
# Runs and their scores
# ------------------------------------------------------------------------------------------------
@dataclass
class Run:
    index: int
    seed: int
    sampled: dict[str, str]
    flags: list[str]  # everything after the script except --run-dir
    workers: int

    @property
    def run_id(self) -> str:
        return f"run-{self.index:04d}"

    def command(self, script: str, run_dir: Path) -> list[str]:
        """The run's command line, without the interpreter."""
        return [script, *self.flags, "--run-dir", str(run_dir)]


def plan_runs(config: dict, runs: int) -> list[Run]:
    """The runs of a sweep, 0..runs-1, from its configuration alone."""
    samples = [parse_sample(s) for s in config["samples"]]
    fixed = list(config["fixed_flags"])
    planned = []
    for index in range(runs):
        sampled = sample_values(samples, config["seed"], index)
        flags = [*fixed]
        for name, value in sampled.items():
            flags += [f"--{name}", value]
        if flag_value(flags, "num-workers") is None and flag_value(flags, "num_workers") is None:
            flags += ["--num-workers", "1"]
        if config["total_timesteps"] is not None:
            flags += ["--total-timesteps", str(config["total_timesteps"])]
        seed = config["seed"] + SEED_STRIDE * index
        flags += ["--seed", str(seed)]
        workers_text = flag_value(flags, "num-workers") or flag_value(flags, "num_workers")
        try:
            workers = max(1, int(workers_text))
        except ValueError:
            workers = 1  # the script will reject it; the run is recorded as failed
        planned.append(Run(index, seed, sampled, flags, workers))
    return planned


def score_evaluations(text: str) -> dict:
    """Score an evaluations.csv (columns global_step, ..., mean_return): `score` is the mean of
    the final 5 evaluations' mean returns, leaving out step 0's unless it is the only one,
    `score_all` the mean of all of them. Raises ValueError when it holds no evaluation."""
    rows = list(csv.DictReader(io.StringIO(text)))
    if not rows or "mean_return" not in rows[0]:
        raise ValueError("evaluations.csv holds no evaluation")
    returns = [float(row["mean_return"]) for row in rows]
    trained = [r for r, row in zip(returns, rows, strict=True) if row.get("global_step") != "0"]
    final = (trained or returns)[-SCORE_LAST:]  # the untrained network's score never counts
    return {
        "score": sum(final) / len(final),
        "score_all": sum(returns) / len(returns),
        "evaluations": len(returns),
        "final_step": rows[-1].get("global_step", ""),
        "clock_s": float(rows[-1].get("wall_time_s") or 0.0),
    }


ERROR_CHARS = 500  # the longest error the table records


def describe_failure(returncode: int, stderr: str) -> str:
    """One line for the table: the exit, the script's `error:` line and the error's last
    meaningful line (a box's message, as tyro frames its errors, not the box)."""
    if returncode < 0:
        exit_text = f"killed by {signal.Signals(-returncode).name}"
    else:
        exit_text = f"exit code {returncode}"
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    parts = [exit_text]
    if errors:
        parts.append(errors[-1])
    last = tyro_message(stderr)
    if last and last not in parts:
        parts.append(last)
    text = ": ".join(parts)
    # cut between characters (a str is cut by code point), and say that it was cut
    return text if len(text) <= ERROR_CHARS else text[: ERROR_CHARS - 1] + "…"


def execute_run(
    command: list[str], run_dir: str, stop_level: Callable[[], int] = lambda: 0
) -> dict:
    """Run one agent script in a fresh run folder and wait for it (a thread of the local
    backend, or a Ray task). stop_level() > 0 asks the run to stop (SIGINT: the scripts
    checkpoint and exit), > 1 to die now (SIGKILL); a Ray cancel raises KeyboardInterrupt here
    and is a stop too. Returns what the sweep needs to score or describe it."""
    run_path = Path(run_dir)
    holder = run_holder(run_path)
    if holder is not None:  # resumed by hand, say: neither started nor touched, nor recorded
        return {"returncode": None, "interrupted": False, "in_use": holder, "wall_time_s": 0.0}
    checkpoint = run_path / "checkpoint.pt"
    if checkpoint.is_file():  # interrupted in an earlier sweep: the run goes on with its flags,
        # its data sent where this command says (--resume takes that from the command line only)
        command = [command[0], "--resume", str(checkpoint), *split_elsewhere(command[1:])[1]]
    else:  # a partial run that wrote no checkpoint starts again
        clear_run_folder(run_path)
    start = time.time()
    interrupted = False
    with open(run_path / "stdout.log", "ab") as out, open(run_path / "stderr.log", "ab") as err:
        own_err = err.seek(0, os.SEEK_END)  # the log holds the run's earlier attempts too
        process = subprocess.Popen(
            [sys.executable, *command],
            stdout=out,
            stderr=err,
            stdin=subprocess.DEVNULL,
            start_new_session=True,  # a terminal's Ctrl-C reaches the sweep only; it forwards it
            preexec_fn=functools.partial(_prepare_child, autogroup_nice()),
        )
        deadline = None
        try:
            while process.poll() is None:
                level = stop_level()
                if level > 0 and not interrupted:
                    interrupted = True
                    _signal_group(process, signal.SIGINT)
                    deadline = time.time() + STOP_GRACE_S
                if interrupted and (level > 1 or time.time() > deadline):
                    _signal_group(process, signal.SIGKILL)
                    process.wait()
                    break
                time.sleep(0.1)
        except BaseException:  # KeyboardInterrupt from a Ray cancel, or anything else
            interrupted = True
            _signal_group(process, signal.SIGINT)
            with contextlib.suppress(BaseException):  # a second interrupt: kill below
                process.wait(STOP_GRACE_S)
            if process.poll() is None:
                _signal_group(process, signal.SIGKILL)
                process.wait()
    evaluations = run_path / "evaluations.csv"
    result = {
        "returncode": process.returncode,
        "interrupted": interrupted,
        "in_use": None,
        "wall_time_s": time.time() - start,
        "stdout_tail": _tail(run_path / "stdout.log"),
        "stderr_tail": _tail(run_path / "stderr.log"),
        "evaluations_csv": evaluations.read_text() if evaluations.exists() else None,
    }
    if process.returncode == 2 and IN_USE_TEXT in _read_from(run_path / "stderr.log", own_err):
        # another process took the folder between the check above and this run's start
        result["in_use"] = run_holder(run_path) or "?"
    return result


def _read_from(path: Path, offset: int) -> str:
    """What a file holds past offset (what this attempt of a run wrote to its log)."""
    with open(path, "rb") as f:
        f.seek(offset)
        return f.read().decode(errors="replace")


def _tail(path: Path) -> str:
    """The file's last TAIL_CHARS bytes, from a character's start: the bytes of a UTF-8
    character the seek cut into are dropped, not decoded as a replacement character."""
    with open(path, "rb") as f:
        offset = max(0, path.stat().st_size - TAIL_CHARS)
        f.seek(offset)
        data = f.read()
    if offset > 0:  # started mid-file: skip UTF-8 continuation bytes
        start = 0
        while start < min(len(data), 3) and data[start] & 0xC0 == 0x80:
            start += 1
        data = data[start:]
    return data.decode(errors="replace")


def _signal_group(process: subprocess.Popen, signum: int) -> None:
    """Signal the run's process group (its main process and workers) while the main process is
    not yet reaped, so that the group id still names it."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signum)


AUTOGROUP = Path("/proc/self/autogroup")


def autogroup_nice() -> int | None:
    """The nice of this process's autogroup (Linux with sched_autogroup), else None. A session
    of its own is an autogroup of its own, which the kernel ranks by that nice and not by its
    processes' own nice: a run started in a new session would otherwise take its share of the
    CPU at nice 0, however the sweep was niced."""
    try:
        return int(AUTOGROUP.read_text().split("nice")[1])
    except (OSError, IndexError, ValueError):
        return None


def _prepare_child(autogroup: int | None = None) -> None:
    """In the child, before exec (after setsid): unblock every signal (a Ray worker runs tasks
    with SIGINT blocked, and exec keeps the mask, so the run would never see the sweep's
    SIGINT); on Linux ask for SIGTERM when the thread that started it dies (PR_SET_PDEATHSIG),
    so that a killed sweep leaves no runs behind; and give the run's new autogroup the sweep's
    autogroup nice, so that a niced campaign stays niced."""
    signal.pthread_sigmask(signal.SIG_SETMASK, set())
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # 1: PR_SET_PDEATHSIG
    if autogroup is not None:
        with contextlib.suppress(OSError):
            AUTOGROUP.write_text(str(autogroup))


def result_row(run: Run, result: dict) -> dict | None:
    """The table row of a run that ended, or None when the sweep stopped it or it was in use
    elsewhere (either way it runs on the next start)."""
    if result["interrupted"] or result.get("in_use"):
        return None
    row = {
        "run_id": run.run_id,
        "status": "ok",
        "score": "",
        "score_all": "",
        "evaluations": "",
        "final_step": "",
        "wall_time_s": round(result["wall_time_s"], 2),
        "seed": run.seed,
        **run.sampled,
        "flags": shlex.join(run.flags),
        "error": "",
    }
    stdout_lines = [line for line in result["stdout_tail"].splitlines() if line.strip()]
    error = None
    if result["returncode"] != 0:
        error = describe_failure(result["returncode"], result["stderr_tail"])
    elif stdout_lines and stdout_lines[-1].startswith("stopped by"):
        error = f"stopped before its step budget: {stdout_lines[-1]}"[:500]
    elif result["evaluations_csv"] is None:
        error = "exit code 0 but no evaluations.csv"
    else:
        try:
            scores = score_evaluations(result["evaluations_csv"])
            # a resumed run's own clock counts its earlier parts; this process saw only the last
            row["wall_time_s"] = round(max(result["wall_time_s"], scores.pop("clock_s")), 2)
            row.update(scores)
        except (ValueError, KeyError) as e:
            error = f"bad evaluations.csv: {e}"
    if error is not None:
        row["status"], row["error"] = "failed", error
    return row


# ------------------------------------------------------------------------------------------------
# The output folder: sweep.json and results.csv
# ------------------------------------------------------------------------------------------------
def write_config(out: Path, config: dict) -> None:
    """Write out/sweep.json where there is none yet (config_mismatch has checked the one there);
    only with the folder's lock held, so that two sweeps never both find it missing."""
    if not (out / CONFIG_NAME).exists():
        out.mkdir(parents=True, exist_ok=True)
        _write_atomically(out / CONFIG_NAME, json.dumps(config, indent=2) + "\n")


def config_mismatch(out: Path, config: dict) -> str | None:
    """Why out cannot hold a sweep of this configuration (its sweep.json holds another), or
    None (the same one, or none yet). It only reads: a check before anything is created."""
    path = out / CONFIG_NAME
    if not path.exists():
        return None
    stored = read_config(path)
    differ = [key for key in config if not same_setting(key, stored.get(key), config[key])]
    if not differ:
        return None
    details = "; ".join(f"{k}: {stored.get(k)!r} there, {config[k]!r} now" for k in differ)
    return (
        f"{out} holds a sweep with another configuration ({details}); "
        "use another --out, or the same arguments to resume it"
    )


def same_setting(key: str, stored: typing.Any, now: typing.Any) -> bool:
    """Whether a sweep.json's setting is the same as a start's: the fixed flags without those
    that send the data elsewhere (split_elsewhere), which are each start's own."""
    if key == "fixed_flags" and isinstance(stored, list):
        return split_elsewhere(stored)[0] == split_elsewhere(now)[0]
    return stored == now


CONFIG_MAX_BYTES = 1 << 20  # a sweep's configuration is some hundred bytes
CONFIG_FIELDS = {  # each field of a sweep.json (configuration()), and what it must be
    "script": ("a string", lambda v: isinstance(v, str)),
    "samples": ("a list of strings", lambda v: isinstance(v, list)
                and all(isinstance(s, str) for s in v)),
    "fixed_flags": ("a list of strings", lambda v: isinstance(v, list)
                    and all(isinstance(s, str) for s in v)),
    "total_timesteps": ("a whole number >= 1 or null",
                        lambda v: v is None or (type(v) is int and v >= 1)),
    "seed": ("a whole number", lambda v: type(v) is int),
    "score": ("a string", lambda v: isinstance(v, str)),
}  # fmt: skip


def read_config(path: Path, required: tuple[str, ...] = ()) -> dict:
    """A sweep.json's configuration: a JSON object whose fields (CONFIG_FIELDS) have their
    types, with each field of `required` there (those its reader uses). UsageError, in one line,
    for any other file (a truncated one, another tool's, one nested too deep to parse or larger
    than any configuration), as nothing then says which sweep the folder holds."""
    try:
        with open(path, "rb") as f:
            data = f.read(CONFIG_MAX_BYTES + 1)
    except OSError as e:
        stored, reason = None, e.strerror
    else:
        stored, reason = parsed_config(data, required)
    if reason is not None:
        raise UsageError(
            f"{path} is not a sweep's configuration ({reason}); nothing was run: move it away, "
            "or use another --out"
        )
    return stored


def parsed_config(data: bytes, required: tuple[str, ...]) -> tuple[dict | None, str | None]:
    """(a sweep.json's configuration, None), or (None, what is wrong with it): see read_config."""
    if len(data) > CONFIG_MAX_BYTES:
        return None, f"more than {CONFIG_MAX_BYTES:,} bytes"
    try:
        stored = json.loads(data)
    except ValueError as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        return None, f"not JSON: {e}"
    except RecursionError:  # arrays or objects nested past the parser's depth
        return None, "JSON nested too deep to read"
    if not isinstance(stored, dict):
        return None, f"a JSON {type(stored).__name__}, not an object"
    for name in required:
        if name not in stored:
            return None, f"it has no {name!r}"
    for name, (kind, valid) in CONFIG_FIELDS.items():
        if name in stored and not valid(stored[name]):
            return None, f"its {name!r} is {reprlib.repr(stored[name])}, not {kind}"
    return stored, None


LOCK_NAME = "sweep.lock"


@contextlib.contextmanager
def lock_folder(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on out/runs/sweep.lock while the block runs, so that two sweeps
    cannot write the same folder (no-op where fcntl is missing); UsageError naming the sweep
    that holds it. The lock file holds its holder's pid and is removed when the block ends; a
    killed sweep leaves it behind, unlocked, and the next sweep takes it. It lives in runs/,
    which the repository's .gitignore leaves out, with the run folders."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    made = [d for d in (out, out / RUNS_DIR) if not d.exists()]
    (out / RUNS_DIR).mkdir(parents=True, exist_ok=True)
    path = out / RUNS_DIR / LOCK_NAME
    while True:
        # not truncated on open: the file holds the pid of the sweep that may hold it
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _lock_holder(fd)
            os.close(fd)
            by = f"another sweep (pid {holder})" if holder else "another sweep"
            raise UsageError(
                f"{out} is held by {by} ({path}); wait for it to end, or use another --out"
            ) from None
        # a sweep that ended between our open and our flock removed the file we locked: the
        # lock is the file now at the path, so take that one
        with contextlib.suppress(FileNotFoundError):
            if os.stat(path).st_ino == os.fstat(fd).st_ino:
                break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):  # while still locked: a sweep that opened
            os.unlink(path)  # it meanwhile finds it gone (above) and takes a fresh one
        os.close(fd)
        for folder in reversed(made):  # a refused start leaves no folder it made, if empty
            with contextlib.suppress(OSError):
                folder.rmdir()


def _lock_holder(fd: int) -> str:
    """The pid in a lock file another sweep holds; its holder writes it just after locking, so
    give it a moment."""
    for _ in range(20):
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
        if holder:
            return holder
        time.sleep(0.01)
    return ""


class ResultsTable:
    """out/results.csv: one row per finished run, always whole on disk."""

    def __init__(self, path: Path, sampled_names: list[str]):
        self.path = path
        self.columns = [*FIXED_COLUMNS, *sampled_names, *TRAILING_COLUMNS]
        self.header: list[str] | None = None  # the file's, None when there is none yet
        self.rows: dict[str, dict] = {}
        if not path.exists():
            return
        try:
            with open(path, newline="") as f:
                reader = csv.DictReader(f)
                self.header = reader.fieldnames
                rows = list(reader)
        except (OSError, UnicodeDecodeError, csv.Error) as e:
            raise UsageError(f"{path} cannot be read ({e}); nothing was run") from None
        head, tail = len(FIXED_COLUMNS), len(TRAILING_COLUMNS)
        header = self.header or []
        if self.header is not None and (
            header[:head] != FIXED_COLUMNS or header[-tail:] != TRAILING_COLUMNS
        ):
            shown = ",".join(header)
            raise UsageError(
                f"{path} is not a sweep's results table (its header: "
                f"{shown[:120] + '...' if len(shown) > 120 else shown}; a sweep's is "
                f"{','.join(FIXED_COLUMNS)},<the sampled flags>,{','.join(TRAILING_COLUMNS)}); "
                "nothing was run or replaced: move it away, or use another --out"
            )
        for row in rows:
            if row.get("status") == "failed" and IN_USE_TEXT in (row.get("error") or ""):
                continue  # in use elsewhere when an older sweep ran it: not a failure, run it
            if row.get("status") in ("ok", "failed"):
                self.rows[row["run_id"]] = row

    def check_columns(self) -> None:
        """UsageError when the file's sampled columns are not this sweep's (rewriting it would
        lose theirs)."""
        if self.header is not None and self.header != self.columns:
            raise UsageError(
                f"{self.path}'s columns are {','.join(self.header)}, not this sweep's "
                f"{','.join(self.columns)}; nothing was run or replaced: move it away, or use "
                "another --out"
            )

    def finished(self, run_id: str) -> bool:
        return run_id in self.rows

    def add(self, row: dict) -> None:
        self.rows[row["run_id"]] = row
        text = io.StringIO()
        writer = csv.DictWriter(text, self.columns, extrasaction="ignore", lineterminator="\n")
        writer.writeheader()
        for run_id in sorted(self.rows):
            writer.writerow(self.rows[run_id])
        _write_atomically(self.path, text.getvalue())


def _write_atomically(path: Path, text: str) -> None:
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # never another process's temp file
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


# ------------------------------------------------------------------------------------------------
# Backends
# ------------------------------------------------------------------------------------------------
class StopRequests:
    """Counts SIGINT/SIGTERM: 1 = stop the runs cleanly, 2 = kill them. A second signal within
    SAME_STOP_S of the first is the same request: a SIGTERM to the whole process group (a
    session's or a service's end) reaches the sweep twice at once, directly and passed on by a
    campaign, and must not kill runs that are writing their checkpoints."""

    SAME_STOP_S = 2.0

    def __init__(self) -> None:
        self.level = 0
        self.first = 0.0  # time.monotonic() of the first request
        self.signal_name: str | None = None  # the first request's signal ("SIGINT", "SIGTERM")
        self.previous = {}

    def __enter__(self) -> StopRequests:
        for signum in (signal.SIGINT, signal.SIGTERM):
            self.previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)

    def _handle(self, signum, _frame) -> None:
        now = time.monotonic()
        if self.level == 1 and now - self.first < self.SAME_STOP_S:
            return
        self.level += 1
        name = signal.Signals(signum).name
        if self.level == 1:
            self.first, self.signal_name = now, name
            print(
                f"{name}: stopping the running runs (started again, the sweep resumes them from "
                "their checkpoints); again to kill them",
                flush=True,
            )
        else:
            print(f"{name}: killing the running runs", flush=True)


def run_local(
    script: str,
    todo: list[Run],
    out: Path,
    record: Callable,
    cpus: int,
    max_concurrent: int | None,
    stop: StopRequests,
) -> None:
    """Run the runs as subprocesses, in order, while their workers fit in `cpus`."""
    pending = list(todo)
    running: dict[concurrent.futures.Future, Run] = {}
    # threads only wait on their subprocess; each lives as long as the pool (PDEATHSIG is tied
    # to the thread that started the child)
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, len(todo))) as pool:
        while pending or running:
            while pending and stop.level == 0:
                used = sum(run.workers for run in running.values())
                full = max_concurrent is not None and len(running) >= max_concurrent
                if running and (full or used + pending[0].workers > cpus):
                    break
                run = pending.pop(0)
                command = run.command(script, out / RUNS_DIR / run.run_id)
                future = pool.submit(
                    execute_run, command, str(out / RUNS_DIR / run.run_id), lambda: stop.level
                )
                running[future] = run
            if stop.level > 0:
                pending.clear()
            done, _ = concurrent.futures.wait(
                running, timeout=0.2, return_when=concurrent.futures.FIRST_COMPLETED
            )
            for future in done:
                record(running.pop(future), future.result())


def run_ray(
    script: str,
    todo: list[Run],
    out: Path,
    record: Callable,
    cpus: int | None,
    address: str | None,
    stop: StopRequests,
) -> None:
    """Run each run as a Ray task that reserves num_cpus = its workers."""
    try:
        import ray
    except ImportError:
        raise UsageError(RAY_MISSING) from None
    if __name__ != "__main__":  # imported (tests): ship this module's code to the workers
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    if address:
        ray.init(address=address, log_to_driver=False)
    else:
        ray.init(num_cpus=cpus, log_to_driver=False)
    try:
        available = ray.cluster_resources().get("CPU", 0)
        largest = max(run.workers for run in todo)
        if largest > available:
            raise UsageError(f"a run needs {largest} CPUs; the Ray cluster has {available:g}")
        print(f"ray: {available:g} CPUs in the cluster", flush=True)
        task = ray.remote(execute_run)  # Ray retries a task whose node died, from scratch
        script = str(Path(script).resolve())
        refs = {}
        for run in todo:
            run_dir = str((out / RUNS_DIR / run.run_id).resolve())
            ref = task.options(num_cpus=run.workers, name=run.run_id).remote(
                run.command(script, Path(run_dir)), run_dir
            )
            refs[ref] = run
        cancelled = 0
        while refs:
            if stop.level > cancelled:
                # level 1: KeyboardInterrupt in the running tasks (execute_run stops its run with
                # SIGINT) and queued tasks dropped; level 2: the tasks' workers are killed
                cancelled = stop.level
                for ref in refs:
                    ray.cancel(ref, force=cancelled > 1)
            done, _ = ray.wait(list(refs), num_returns=1, timeout=0.2)
            for ref in done:
                run = refs.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.RayError as e:
                    result = {
                        "returncode": 1,
                        "interrupted": stop.level > 0,
                        "wall_time_s": 0.0,
                        "stdout_tail": "",
                        "stderr_tail": f"error: ray: {e}",
                        "evaluations_csv": None,
                    }
                record(run, result)
    finally:
        ray.shutdown()


def _copy_back(run_dir: Path, result: dict) -> None:
    """Keep the files of a run that ran on another node: evaluations.csv and the log tails."""
    if result.get("interrupted") or result.get("in_use"):
        return
    run_dir.mkdir(parents=True, exist_ok=True)
    if result["evaluations_csv"] is not None and not (run_dir / "evaluations.csv").exists():
        (run_dir / "evaluations.csv").write_text(result["evaluations_csv"])
    for name in ("stdout", "stderr"):
        if not (run_dir / f"{name}.log").exists():
            (run_dir / f"{name}.log").write_text(result[f"{name}_tail"])


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def cpu_count() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """The sweep's own arguments, and the fixed flags after `--`."""
    if "--" in argv:
        split = argv.index("--")
        argv, fixed = argv[:split], argv[split + 1 :]
    else:
        fixed = []
    parser = tool_parser(
        "sweep",
        "Run an agent script many times with sampled flags; collect a results table.",
        epilog="Flags after `--` go unchanged to every run. See the module docstring for more.",
    )
    parser.add_argument("script", help="the agent script, e.g. agents/a3c_ff.py")
    parser.add_argument("--out", required=True, help="the sweep's output folder")
    parser.add_argument("--runs", type=int, default=50, help="number of runs (default 50)")
    parser.add_argument(
        "--total-timesteps",
        type=int,
        default=None,
        help="each run's step budget (default: the script's)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=1,
        help="the sweep seed: sampled values and run seeds derive from it",
    )
    parser.add_argument(
        "--sample",
        action="append",
        default=[],
        metavar="NAME=DIST",
        help="a sampled flag: NAME=loguniform:LOW:HIGH, NAME=uniform:LOW:HIGH or "
        "NAME=choice:A,B,...; repeat for more flags",
    )
    parser.add_argument(
        "--backend",
        choices=["local", "ray", "batched"],
        default="local",
        help="local: a process per run (default); ray: a Ray task per run; batched: the runs "
        "as one program on --device (FF, LWS, SS, WW, LPQ, GLPQ on Catch-v0, one worker per run)",
    )
    parser.add_argument(
        "--device",
        default="cpu",
        help="with --backend batched: the torch device of the batch, cpu or cuda (default cpu)",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="with --backend ray: a running cluster ('auto' or HOST:PORT)",
    )
    parser.add_argument(
        "--cpus",
        type=int,
        default=None,
        help="CPUs to fill (local backend, or the local Ray instance); "
        "default: this machine's cores",
    )
    parser.add_argument(
        "--max-concurrent",
        type=int,
        default=None,
        help="local backend: at most this many runs at once (default: as many as "
        "fit in --cpus, i.e. max(1, cores // workers per run))",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print the runs' command lines and exit"
    )
    return parser.parse_args(argv), fixed


def main(argv: list[str] | None = None) -> int:
    args, fixed = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        return sweep(args, fixed)
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


def sweep(args: argparse.Namespace, fixed: list[str]) -> int:
    if not Path(args.script).is_file():
        raise UsageError(f"script {args.script!r} does not exist")
    if args.runs < 1:
        raise UsageError(f"--runs must be >= 1 (got {args.runs})")
    if args.total_timesteps is not None and args.total_timesteps < 1:
        raise UsageError(f"--total-timesteps must be >= 1 (got {args.total_timesteps})")
    if args.address and args.backend != "ray":
        raise UsageError("--address needs --backend ray")
    if args.device != "cpu" and args.backend != "batched":
        raise UsageError("--device needs --backend batched")
    if args.device not in ("cpu", "cuda"):
        raise UsageError(f"--device must be cpu or cuda (got {args.device!r})")
    for value, flag in ((args.cpus, "--cpus"), (args.max_concurrent, "--max-concurrent")):
        if value is not None and value < 1:
            raise UsageError(f"{flag} must be >= 1 (got {value})")
    for name in RESERVED_FLAGS:
        if flag_value(fixed, name) is not None or flag_value(fixed, name.replace("-", "_")):
            raise UsageError(f"do not pass --{name} after `--`: the sweep sets it for each run")
    samples = [parse_sample(s) for s in args.sample]
    names = [s.name for s in samples]
    if len(set(names)) != len(names):
        raise UsageError(f"a flag is sampled twice: {names}")
    # every check of the arguments comes before the folder is touched: a refused start leaves
    # nothing behind, and the same --out takes the corrected command
    check_flags(Path(args.script), samples, fixed, args.total_timesteps)
    if args.backend == "ray" and importlib.util.find_spec("ray") is None:
        raise UsageError(RAY_MISSING)
    config = configuration(args, fixed)
    runs = plan_runs(config, args.runs)
    out = Path(args.out)
    runs_args = checked_run_args(args.script, runs, out, args.backend)
    if args.backend == "batched":
        check_batched(args, runs_args)
    if args.dry_run:
        for run in runs:
            print(shlex.join(["python", *run.command(args.script, out / RUNS_DIR / run.run_id)]))
        return 0
    with lock_folder(out):  # first: nothing in the folder is read or written without it
        mismatch = config_mismatch(out, config)
        if mismatch:
            raise UsageError(mismatch)
        # a run folder holding a checkpoint that is not its run's refuses the sweep, as it is
        table = ResultsTable(out / TABLE_NAME, names)
        table.check_columns()
        for run in (run for run in runs if not table.finished(run.run_id)):
            if run_holder(out / RUNS_DIR / run.run_id) is not None:
                continue  # in use elsewhere: not touched, its checkpoint judged once it is free
            problem = foreign_checkpoint(args.script, run, out / RUNS_DIR / run.run_id)
            if problem is not None:
                raise UsageError(problem)
        write_config(out, config)
        return run_sweep(args, out, runs, names)


def checked_run_args(script: str, runs: list[Run], out: Path, backend: str) -> list | None:
    """Each run's Args as its command line gives them (unresolved), for an agent script (None for
    any other: its flags are checked by name only, check_flags). UsageError, in one line naming
    the run and its sampled values, for a run that would refuse its own start: a value tyro
    rejects, a number out of range (the runtime's resolve_defaults), a flag its network refuses
    (a network built for each set of flags), --precision tf32 off a GPU."""
    args_type = agent_args(Path(script))
    if args_type is None:
        return None
    agent = getattr(load_script(Path(script)), "AGENT", None)
    runs_args, networks_built = [], set()
    for run in runs:
        sampled = " ".join(f"{k}={v}" for k, v in run.sampled.items())
        where = f"{run.run_id}" + (f" ({sampled})" if sampled else "")
        try:
            flags = run.command(script, out / RUNS_DIR / run.run_id)[1:]
            runs_args.append(parsed_flags(args_type, flags))
        except ValueError as e:
            raise UsageError(f"{where}: {str(e).rstrip('.')}; nothing was run") from None
        if agent is not None:
            check_run_start(agent, copy.deepcopy(runs_args[-1]), backend, networks_built, where)
    return runs_args


def check_run_start(
    agent: typing.Any, args: typing.Any, backend: str, built: set, where: str
) -> None:
    """UsageError where a run with these (unresolved) Args would refuse its start, as the
    runtime's train checks them before it creates anything."""
    from a3c_runtime import UsageError as RunUsageError
    from a3c_runtime.flags import probe_env, refuse_tf32, resolve_defaults

    try:
        resolved = resolve_defaults(args)
        if backend != "batched":  # (a batch on a GPU takes tf32: check_batched)
            refuse_tf32(resolved.precision)
        # (a network's checks read its flags, never its seed or folder)
        key = repr({k: v for k, v in vars(resolved).items() if k not in ("seed", "run_dir")})
        if key not in built:
            agent.build_network(probe_env(agent.make_env, resolved.env), resolved)
            built.add(key)
    except RunUsageError as e:
        raise UsageError(f"{where}: {e}; nothing was run") from None


def check_batched(args: argparse.Namespace, runs_args: list | None) -> None:
    """--backend batched: UsageError, before anything runs, for runs it cannot batch (another
    script, env or optimizer, several workers, flags that differ between runs other than the
    seed and the learning rate...) or a --device this machine lacks."""
    from a3c_runtime import UsageError as RunUsageError

    from a3c_tools.batched import check_batchable

    if args.device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise UsageError("--device cuda: torch sees no CUDA device here; use --device cpu")
    try:
        check_batchable(args.script, runs_args, args.device)
    except RunUsageError as e:
        raise UsageError(str(e)) from None


def configuration(args: argparse.Namespace, fixed: list[str]) -> dict:
    """The sweep's configuration, as OUT/sweep.json holds it: what its runs depend on."""
    return {
        "script": Path(args.script).name,
        "samples": [parse_sample(s).spec() for s in args.sample],
        "fixed_flags": fixed,
        "total_timesteps": args.total_timesteps,
        "seed": args.seed,
        "score": f"mean of the final {SCORE_LAST} evaluations",
    }


def foreign_checkpoint(script: str, run: Run, run_dir: Path) -> str | None:
    """Why the checkpoint in a run's folder is not that run's to resume (another script's, or
    other flags or another seed than the run's; or one that does not load safely), or None:
    none there, the run's own, or a script without the agents' Args (nothing to compare)."""
    path = run_dir / "checkpoint.pt"
    if not path.is_file() or agent_args(Path(script)) is None:
        return None
    agent = getattr(load_script(Path(script)), "AGENT", None)
    if agent is None:
        return None
    import tyro
    from a3c_runtime import UsageError as RunUsageError
    from a3c_runtime import load_checkpoint, resolve_defaults
    from a3c_runtime.checkpoint_file import OlderFormat
    from a3c_runtime.resume import differing_flags

    try:
        checkpoint = load_checkpoint(str(path), agent)
        given = tyro.cli(agent.Args, args=run.command(script, run_dir)[1:])
        # --precision auto resolves by the CPU: a run continued on another host is still its own
        skip = ("precision",) if getattr(given, "precision", None) == "auto" else ()
        planned = resolve_defaults(given)
    except OlderFormat as e:  # (the run's own, perhaps, from before the format changed)
        return (f"{e}; nothing was run: start the sweep again once it is converted, to resume "
                f"{run.run_id}, or move or remove {run_dir} to start that run afresh")  # fmt: skip
    except RunUsageError as e:
        reason = str(e)
    else:
        differ = differing_flags(agent, checkpoint, planned, skip)
        if not differ:
            return None
        reason = "it holds a run with " + "; ".join(differ[:4]) + (" ..." if differ[4:] else "")
    return (
        f"{path} is not {run.run_id}'s to resume ({reason}); nothing was run: move or remove "
        f"{run_dir} for the sweep to start that run afresh"
    )


def run_sweep(args: argparse.Namespace, out: Path, runs: list[Run], names: list[str]) -> int:
    """Run the runs that are not in out's table yet and record them; the folder is locked."""
    table = ResultsTable(out / TABLE_NAME, names)
    todo = [run for run in runs if not table.finished(run.run_id)]
    cpus = args.cpus or cpu_count()
    print(
        f"sweep {args.script}: {len(runs)} runs, {len(runs) - len(todo)} already in "
        f"{out / TABLE_NAME}, {len(todo)} to run ({args.backend} backend)",
        flush=True,
    )
    finished = [0]
    in_use: list[str] = []

    def record(run: Run, result: dict) -> None:
        _copy_back(out / RUNS_DIR / run.run_id, result)
        if result.get("in_use"):
            in_use.append(run.run_id)
            print(
                f"[-/{len(todo)}] {run.run_id} in use: {out / RUNS_DIR / run.run_id} is held by "
                f"process {result['in_use']} (a run or resume training there); not started, "
                "it runs when the sweep is started again once that process has ended",
                flush=True,
            )
            return
        row = result_row(run, result)
        if row is None:
            return
        table.add(row)
        finished[0] += 1
        sampled = " ".join(f"{k}={v}" for k, v in run.sampled.items())
        outcome = f"score {row['score']:.3f}" if row["status"] == "ok" else row["error"]
        print(
            f"[{finished[0]}/{len(todo)}] {run.run_id} {row['status']} {sampled} | {outcome} | "
            f"{row['wall_time_s']:.0f}s",
            flush=True,
        )

    with StopRequests() as stop:
        if todo and args.backend == "local":
            run_local(args.script, todo, out, record, cpus, args.max_concurrent, stop)
        elif todo and args.backend == "batched":
            from a3c_tools.batched import run_batched

            stopped_by = lambda: stop.signal_name if stop.level > 0 else None  # noqa: E731
            run_batched(args.script, todo, out, record, stopped_by, args.device)
        elif todo:
            run_ray(args.script, todo, out, record, args.cpus, args.address, stop)
    if stop.level > 0:
        print(f"interrupted: {finished[0]} runs recorded; start again to finish", flush=True)
        return 130
    statuses = [table.rows[run.run_id]["status"] for run in runs if run.run_id in table.rows]
    ok = statuses.count("ok")
    if in_use:
        print(
            f"not done: {ok} ok, {len(statuses) - ok} failed, {len(in_use)} in use elsewhere "
            f"({', '.join(in_use)}) -> {out / TABLE_NAME}; start the sweep again once they are "
            "free",
            flush=True,
        )
        return IN_USE_EXIT
    print(f"done: {ok} ok, {len(statuses) - ok} failed -> {out / TABLE_NAME}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    run_main(main)
