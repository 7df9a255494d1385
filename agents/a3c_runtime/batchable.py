"""Which runs the batched trainer (a3c_runtime.batched) takes as one batch: the scripts of
BATCHED_SCRIPTS (FF, LSTM, LWS, SS, WW, LPQ, GLPQ) on Catch-v0 with one worker and one env per
run, RMSprop, runs that differ only in PER_RUN_FLAGS (their --precision the batch's: fp32 by
default; bf16, bf16-learn, and tf32 on a GPU, opt in). `batch_problem` says why others are
not, in one line; the trainer refuses them, and the sweep before anything runs."""

from __future__ import annotations

import os
from typing import Any

from .flags import resolve_defaults

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


def resolve_run_args(args: Any) -> Any:
    """A run's Args with the defaults filled in; --precision auto is fp32 in a batch."""
    if args.precision == "auto":  # the batched runs' default: fp32, the thesis's
        args.precision = "fp32"
    return resolve_defaults(args)
