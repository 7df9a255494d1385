"""The flags every script has: env-dependent defaults, the checks that turn a bad value into a
one-line UsageError, --precision, and the schema of a checkpoint's flags (`Flags`: each a
scalar, the counts and sizes within what the project offers a machine), to which the command
line holds a run's own flags too."""

from __future__ import annotations

import functools
import importlib.util
import math
import os
import sys
from typing import Annotated, Any

import gymnasium as gym
import numpy as np
import torch
import tyro
from pydantic import AfterValidator, ConfigDict, Field, ValidationError

from .catch_state import MAX_ENVS, Strict

OBSERVATION_SHAPE = (4, 84, 84)
VALID_ENVS = "Catch-v0 or an ALE id such as BreakoutNoFrameskip-v4, PongNoFrameskip-v4"
EVAL_EPISODES = 50  # the thesis's evaluation protocol
MAX_STEP = 10**13  # a run's steps, and a checkpoint's
MAX_WORKERS = 1024


class UsageError(Exception):
    """A bad flag, or a missing, corrupt or incompatible checkpoint: exit 2 with one line."""


def flag_value(value: Any) -> Any:
    """A flag's value: a bool, a whole number of 64 bits, a finite number, a string, None."""
    if value is None or isinstance(value, bool) or (isinstance(value, str) and len(value) < 4096):
        return value
    if isinstance(value, int) and -(1 << 63) <= value < 1 << 63:
        return value
    if isinstance(value, float) and math.isfinite(value):
        return value
    raise ValueError("not a bool, a 64-bit whole number, a finite number, a short string or null")


def within(low: int, high: int) -> Any:
    """A count or size a checkpoint's flags may ask of this machine (None: a flag newer than
    the checkpoint, which gets its default)."""
    return Annotated[int, Field(ge=low, le=high)] | None


class Flags(Strict):
    """A checkpoint's flags (the run's Args), each a scalar (their types are the script's, its
    gate checks them); the counts and sizes within what the project offers this machine."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]{0,63}$")],
                             Annotated[Any, AfterValidator(flag_value)]]  # fmt: skip
    num_workers: within(1, MAX_WORKERS) = None  # processes
    envs_per_worker: within(1, MAX_ENVS) = None
    eval_episodes: within(1, 10_000) = None  # envs, one per episode
    t_max: within(1, 100_000) = None
    total_timesteps: within(1, MAX_STEP) = None
    eval_interval: within(1, MAX_STEP) = None
    checkpoint_interval: within(1, MAX_STEP) = None
    lstm_cells: within(1, 16_384) = None  # the scripts' own network sizes
    prototypes_per_action: within(1, 4096) = None
    lws_kcps: within(1, 4096) = None
    lws_second_layer_maps: within(1, 4096) = None
    ww_where_maps: within(0, 4096) = None


def default_num_workers() -> int:
    """One actor-learner per core this process may use."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def native_bf16() -> bool:
    """Whether this CPU computes bfloat16 natively (x86 AVX512-BF16 or AMX-BF16, ARM BF16 or
    SVE-BF16); elsewhere torch emulates it, slower than fp32."""
    try:
        capabilities = torch.cpu.get_capabilities()
    except (AttributeError, RuntimeError):  # an older torch, or cpuinfo failed
        return False
    return any(capabilities.get(k, False) for k in ("avx512_bf16", "amx_bf16", "bf16", "sve_bf16"))


def resolve_defaults(args: Any) -> Any:
    """Fill the env-dependent defaults and reject bad numbers with a clear message."""
    from catch_env.wrappers import is_atari

    try:
        atari = is_atari(args.env)  # registers the ALE ids first
    except ImportError as e:
        raise UsageError(str(e)) from e
    except gym.error.Error as e:
        raise UsageError(f"unknown --env {args.env!r}; valid: {VALID_ENVS}") from e
    if getattr(args, "terminal_on_life_loss", False) and not atari:  # tools may omit it
        raise UsageError(f"--terminal-on-life-loss needs an ALE id (lives); --env is {args.env}")
    if args.total_timesteps is None:
        args.total_timesteps = 100_000_000 if atari else 1_000_000
    if args.eval_interval is None:
        args.eval_interval = 1_000_000 if atari else 50_000
    if args.eval_episodes is None:
        args.eval_episodes = EVAL_EPISODES
    if args.checkpoint_interval is None:
        args.checkpoint_interval = args.eval_interval
    if args.grad_clip is None:
        args.grad_clip = 25.0 if args.grad_clip_mode == "global-norm" else 40.0
    if args.scale_obs is None:
        args.scale_obs = atari
    envs_per_worker = getattr(args, "envs_per_worker", 1)  # tools may pass Args without it
    args.precision = resolve_precision(getattr(args, "precision", "fp32"), envs_per_worker)
    rms_init = getattr(args, "rms_init", 0.0)  # tools may pass Args without it
    checks = {
        "--total-timesteps": (args.total_timesteps, args.total_timesteps > 0, "> 0"),
        "--num-workers": (args.num_workers, args.num_workers >= 1, ">= 1"),
        "--envs-per-worker": (envs_per_worker, envs_per_worker >= 1, ">= 1"),
        "--learning-rate": (args.learning_rate, args.learning_rate >= 0, ">= 0"),
        "--t-max": (args.t_max, args.t_max >= 1, ">= 1"),
        "--gamma": (args.gamma, 0 <= args.gamma <= 1, "in [0, 1]"),
        "--ent-coef": (args.ent_coef, args.ent_coef >= 0, ">= 0"),
        "--vf-coef": (args.vf_coef, args.vf_coef >= 0, ">= 0"),
        "--rms-decay": (args.rms_decay, 0 <= args.rms_decay < 1, "in [0, 1)"),
        "--adam-beta1": (args.adam_beta1, 0 <= args.adam_beta1 < 1, "in [0, 1)"),
        "--adam-beta2": (args.adam_beta2, 0 <= args.adam_beta2 < 1, "in [0, 1)"),
        "--optim-eps": (args.optim_eps, args.optim_eps > 0, "> 0"),
        "--rms-init": (rms_init, rms_init >= 0, ">= 0"),
        "--grad-clip": (args.grad_clip, args.grad_clip > 0, "> 0"),
        "--eval-interval": (args.eval_interval, args.eval_interval > 0, "> 0"),
        "--eval-episodes": (args.eval_episodes, args.eval_episodes >= 1, ">= 1"),
        "--checkpoint-interval": (args.checkpoint_interval, args.checkpoint_interval > 0, "> 0"),
        "--log-interval": (args.log_interval, args.log_interval > 0, "> 0"),
    }
    if args.time_limit is not None:
        checks["--time-limit"] = (args.time_limit, args.time_limit > 0, "> 0")
    for flag, (value, ok, rule) in checks.items():
        if not (ok and math.isfinite(value)):
            raise UsageError(f"{flag} must be {rule} (got {value})")
    # (a resumed run's folder is its checkpoint's: a name from before this check still resumes)
    exp_name = "" if getattr(args, "resume", None) else getattr(args, "exp_name", "")
    if any(sep and sep in exp_name for sep in ("/", os.sep, os.altsep)):
        raise UsageError(
            f"--exp-name {exp_name!r} holds a path separator: it is one part of the run "
            "folder's name (<env>__<exp-name>__<seed>__<time>); --run-dir names a folder"
        )
    check_memory(args.num_workers, envs_per_worker, args.t_max)
    check_within_checkpoint_bounds(args)
    if getattr(args, "track", False) and importlib.util.find_spec("wandb") is None:
        raise UsageError("--track needs wandb: pip install -e './agents[wandb]'")
    return args


def check_within_checkpoint_bounds(args: Any) -> None:
    """UsageError unless the flags' counts and sizes are within what a checkpoint may hold
    (Flags, above: the bounds the gate applies to someone else's file): a
    run the command line accepts writes checkpoints that it, and anyone, can resume."""
    try:
        Flags.model_validate({k: getattr(args, k) for k in Flags.model_fields if hasattr(args, k)})
    except ValidationError as e:
        error = e.errors()[0]
        flag = "--" + str(error["loc"][0]).replace("_", "-")
        rule = error["msg"].removeprefix("Input should be ")
        raise UsageError(f"{flag} must be {rule} (got {error['input']}): the most a checkpoint "
                         "holds") from None  # fmt: skip


def check_memory(num_workers: int, envs_per_worker: int, t_max: int) -> None:
    """UsageError, before anything is created, when the workers' rollout buffers and their
    envs' frames alone would not fit in the memory available: (t_max + 1) x K stacked frames
    per worker, and per env its frame stack and the vector env's frames (Catch's
    CatchVectorEnv; an ALE env holds more). The network's activations come on top."""
    from catch_env.catch import VECTOR_FRAMES_PER_ENV, available_memory, format_bytes

    available = available_memory()
    if available is None:
        return
    stack, height, width = OBSERVATION_SHAPE
    frames_per_env = stack * (t_max + 1) + stack + VECTOR_FRAMES_PER_ENV
    needed = num_workers * envs_per_worker * frames_per_env * height * width
    if needed > available:
        raise UsageError(
            f"--envs-per-worker {envs_per_worker:,} x --num-workers {num_workers} needs at least "
            f"{format_bytes(needed)} (the rollout buffers of --t-max {t_max} and the envs' "
            f"frames), more than the {format_bytes(available)} of memory available"
        )


def resolve_precision(precision: str, envs_per_worker: int) -> str:
    """--precision auto: fp32 with K = 1, the thesis's algorithm, on every CPU, so that the
    default run is the same computation everywhere (and the thesis's: it ran fp32); with K > 1
    envs per worker (the fast setting), bf16 on a CPU with native bf16, where a batch computes
    faster in bf16 (results/throughput_batched), and fp32 elsewhere."""
    if precision == "auto":
        return "bf16" if envs_per_worker > 1 and native_bf16() else "fp32"
    if precision in ("bf16", "bf16-learn") and not native_bf16():
        print(
            f"warning: --precision {precision} on a CPU without native bfloat16 (AVX512-BF16, "
            "AMX or ARM BF16): it is emulated and likely slower than fp32",
            file=sys.stderr,
        )
    return precision


def autocast_contexts(
    precision: str, device_type: str = "cpu"
) -> tuple[torch.autocast, torch.autocast]:
    """The autocast contexts of (acting, learning) forward passes on device_type (a worker's:
    the CPU) for a resolved --precision: fp32 and tf32 neither (TF32 is a GPU's setting, made
    by the batched backend), bf16 both, bf16-learn the learning pass only."""
    if precision not in ("fp32", "bf16", "bf16-learn", "tf32"):
        raise ValueError(f"unresolved --precision {precision!r}: fp32, bf16, bf16-learn or tf32")
    return (
        torch.autocast(device_type, dtype=torch.bfloat16, enabled=precision == "bf16"),
        torch.autocast(device_type, dtype=torch.bfloat16, enabled=precision.startswith("bf16")),
    )


def refuse_tf32(precision: str) -> None:
    """UsageError for --precision tf32 on the scripts' own (process) backend: TF32 is a GPU's,
    and the workers compute on the CPU."""
    if precision == "tf32":
        raise UsageError(
            "--precision tf32 is a GPU's: the sweep's batched backend takes it (python -m "
            "a3c_tools.sweep SCRIPT ... --backend batched --device cuda -- --precision tf32); a "
            "script's own run computes on the CPU: valid there: auto, fp32, bf16, bf16-learn"
        )


@functools.lru_cache(maxsize=64)  # (a checkpoint's gate asks it of each checkpoint a tool reads)
def probe_env(make_env: Any, env_id: str) -> int:
    """The number of actions of env_id; UsageError unless its observations are the thesis's
    stacked 84x84 frames (an id such as CartPole-v1 has none)."""
    env = make_env(env_id)
    space, num_actions = env.observation_space, getattr(env.action_space, "n", None)
    env.close()
    if space.shape != OBSERVATION_SHAPE or space.dtype != np.uint8 or num_actions is None:
        raise UsageError(f"--env {env_id} gives no stacked 84x84 frames; valid: {VALID_ENVS}")
    return int(num_actions)


def default_text(text: str) -> Any:
    """For a flag whose default is filled in from others (None in Args, resolve_defaults):
    `Annotated[int | None, default_text("...")]` makes --help show this text as its default,
    once, instead of None."""
    return tyro.conf.arg(help_behavior_hint=f"(default: {text})")
