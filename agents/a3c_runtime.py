"""The run machinery of the A3C scripts (agents/a3c_*.py): everything they share that is not the
thesis's algorithm, written once, as CleanRL keeps its shared pieces in `cleanrl_utils`.

It starts and watches the processes (N actor-learners and one evaluator, forked; Hogwild: the
network and the optimizer statistics live in shared memory), runs the evaluation protocol
(--eval-episodes episodes sampling from pi every --eval-interval global steps, in a process that
does not stop the workers, and once more at the end), writes and reads checkpoints (atomically;
validated on load), logs to TensorBoard, evaluations.csv and the console, ends a run cleanly on
Ctrl-C or SIGTERM, plays a checkpoint's episodes (--evaluate, --render human) and checks the flags
that every script has. It also holds the library pieces every loop uses: the shared RMSprop and
Adam, gradient clipping, the learning-rate schedule (as torch.optim is to CleanRL) and the
activation replay that spares the update its forward pass (ActivationReplay).

A script gives it an `Agent` and calls `run(agent)` from its `main`:

- `Args`: a dataclass with the flags of a3c_ff.py's Args (a variant adds its own);
- `make_env(env_id, render_mode=None)`: (4, 84, 84) uint8 observations, info["episode"] at the
  end of a game;
- `network(num_actions, args)`: an nn.Module. forward(obs uint8 (B, 4, 84, 84)) -> (log-probs
  (B, A), values (B,)); a recurrent network also has `initial_state(batch)` and
  forward(obs (T, B, ...), state) -> (log-probs (T, B, A), values (T, B), state). An optional
  `set_progress(fraction)` hears the training progress T / T_max before evaluation episodes.
  The constructor raises UsageError for bad network flags; it runs before any run folder exists;
- `network_args`: the Args fields a checkpoint's network depends on (resuming with another value
  is refused);
- `worker(worker_id, shared, args, timer=None)`: the actor-learner loop. It runs while
  `shared.keep_running()` and the global step is below T_max, reads and updates `shared.params`
  with `shared.optimizer`, counts its env steps in `shared.steps[worker_id]` and its statistics
  (`Shared.STATS`) in `shared.stats[worker_id]`. `timer` (benchmarks/a3c_step_profile.py) is a
  `PhaseTimer`, None in training runs.
"""

from __future__ import annotations

import contextlib
import csv
import ctypes
import math
import os
import random
import signal
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.multiprocessing as mp
import torch.nn as nn

CHECKPOINT_FORMAT = "a3c-checkpoint-v1"  # "script" was added compatibly: older ones lack it
OBSERVATION_SHAPE = (4, 84, 84)
VALID_ENVS = "Catch-v0 or an ALE id such as BreakoutNoFrameskip-v4, PongNoFrameskip-v4"
HUMAN_EVAL_EPISODES = 5  # --evaluate --render human: a handful to watch, not the protocol's 50
EVAL_EPISODES = 50  # the thesis's evaluation protocol


class UsageError(Exception):
    """A bad flag, or a missing, corrupt or incompatible checkpoint."""


class RunFailed(RuntimeError):
    """A worker or the evaluator died; the message holds its traceback."""


class EvaluationInterrupted(Exception):
    """Ctrl-C or SIGTERM arrived while evaluation episodes were being played."""


@dataclass(frozen=True)
class Agent:
    """What a script gives the runtime (see the module docstring)."""

    script: str  # the script's file name, stored in its checkpoints
    Args: type
    make_env: Callable[..., gym.Env]
    network: Callable[[int, Any], nn.Module]
    network_args: tuple[str, ...]
    worker: Callable[..., None]
    # flags newer than some checkpoints, with the value those checkpoints' runs had where it is
    # not the flag's default (e.g. SS's --conv-layout: final before it existed)
    checkpoint_defaults: dict[str, Any] = field(default_factory=dict)

    def trained_args(self, checkpoint: dict) -> dict[str, Any]:
        """The flags a checkpoint was trained with; a flag it predates has its
        checkpoint_defaults value, else (left out here) the flag's default."""
        return {**self.checkpoint_defaults, **checkpoint["args"]}

    def build_network(self, num_actions: int, args: Any) -> nn.Module:
        # channels_last makes oneDNN's convolution backward about 2x faster on CPU
        return self.network(num_actions, args).to(memory_format=torch.channels_last)


def default_num_workers() -> int:
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
    precision = getattr(args, "precision", "fp32")  # tools may pass Args without it
    if precision == "auto":
        # bf16 pays off for batches of states, not for one (measured: results/throughput_batched):
        # the learning pass is a batch, acting is one with K = 1
        if not native_bf16():
            args.precision = "fp32"
        else:
            args.precision = "bf16" if envs_per_worker > 1 else "bf16-learn"
    elif precision in ("bf16", "bf16-learn") and not native_bf16():
        print(
            f"warning: --precision {precision} on a CPU without native bfloat16 (AVX512-BF16, "
            "AMX or ARM BF16): it is emulated and likely slower than fp32",
            file=sys.stderr,
        )
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
    return args


def probe_env(agent: Agent, env_id: str) -> int:
    """The number of actions of env_id; UsageError unless its observations are the thesis's
    stacked 84x84 frames (an id such as CartPole-v1 has none)."""
    env = agent.make_env(env_id)
    space, num_actions = env.observation_space, getattr(env.action_space, "n", None)
    env.close()
    if space.shape != OBSERVATION_SHAPE or space.dtype != np.uint8 or num_actions is None:
        raise UsageError(f"--env {env_id} gives no stacked 84x84 frames; valid: {VALID_ENVS}")
    return int(num_actions)


# ----------------------------------------------------------------------------------------------
# Library pieces of the loop: learning-rate schedule, gradient clipping, shared optimizers
# ----------------------------------------------------------------------------------------------


def autocast_contexts(precision: str) -> tuple[torch.autocast, torch.autocast]:
    """The CPU autocast contexts of a worker's (acting, learning) forward passes for a resolved
    --precision: fp32 neither, bf16 both, bf16-learn the learning pass only."""
    if precision not in ("fp32", "bf16", "bf16-learn"):
        raise ValueError(f"unresolved --precision {precision!r}: fp32, bf16 or bf16-learn")
    return (
        torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"),
        torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision != "fp32"),
    )


class ActivationReplay:
    """Reuse the acting passes' layer outputs in the learning pass over the same rollout.

    Acting and learning run the same synced network theta' on the same states (Algorithm 1), so
    every Conv2d and Linear output of the learning forward was already computed while acting,
    one step at a time. `ActivationReplay(model)` turns the model's Conv2d and Linear
    layers into recording ones, in place (same parameters, names and state_dict): forwards inside
    `recording()` keep each layer's output, and the learning forward inside `replaying()` takes
    them back instead of computing them again; only rows that acting never saw (the bootstrap
    state s_n) are computed. The backward is each layer's own (aten.convolution_backward; two
    matmuls for Linear), so the gradients are those of recomputing the forward, up to float
    rounding: the same algorithm with about a third of the learning pass's FLOPs saved.
    Everything else in a network (activations, LSTM cells, softmaxes, prototypes) is recomputed
    from the replayed outputs as before. Outside the two contexts the layers are plain.

    The learning forward must call each layer on the rollout's rows in acting order (step-major,
    as the workers flatten obs_buf; a Conv2d's inputs batched, a Linear's rows its leading
    dimensions), once per forward; a forward that is not a step of the
    rollout (V(s_last) of a truncated episode) runs inside `paused()`. Leaving `replaying()`
    checks that every recorded row was taken back. Under --precision bf16-learn the replayed
    outputs are acting's fp32 ones and the backward runs in bf16."""

    # False makes the contexts no-ops, every layer plain: benchmarks/a3c_throughput.py --replay
    # off sets it (before the workers fork) to measure what the replay saves
    enabled = True

    def __init__(self, model: nn.Module) -> None:
        self.mode: str | None = None  # "record", "replay" or None (plain layers)
        self.layers: list[_ReplayedConv2d | _ReplayedLinear] = []
        for layer in model.modules():
            replayed = {nn.Conv2d: _ReplayedConv2d, nn.Linear: _ReplayedLinear}.get(type(layer))
            if replayed is _ReplayedConv2d and (
                not isinstance(layer.padding, tuple) or layer.padding_mode != "zeros"
            ):
                replayed = None  # "same"/"valid" or non-zero padding: computed as before
            if replayed is not None:
                layer.__class__ = replayed  # a subclass: only forward changes
                layer.replay, layer.recorded, layer.count, layer.cursor = self, None, 0, 0
                self.layers.append(layer)

    @contextlib.contextmanager
    def recording(self) -> Iterator[None]:
        """The acting forwards of one rollout: each layer keeps its outputs."""
        for layer in self.layers:
            layer.count = 0
        self.mode = "record" if self.enabled else None
        try:
            yield
        finally:
            self.mode = None

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """A forward inside recording() that is not a step of the rollout."""
        mode, self.mode = self.mode, None
        try:
            yield
        finally:
            self.mode = mode

    @contextlib.contextmanager
    def replaying(self) -> Iterator[None]:
        """The learning forward over the rollout: the recorded outputs come back in order."""
        for layer in self.layers:
            layer.cursor = 0
        self.mode = "replay" if self.enabled else None
        try:
            yield
            for layer in self.layers:
                if layer.cursor != layer.count:
                    raise RuntimeError(
                        f"ActivationReplay: {layer.count - layer.cursor} recorded rows of "
                        f"{layer} were not replayed; the learning forward must take the acting "
                        "rows in order"
                    )
        finally:
            self.mode = None
            for layer in self.layers:
                layer.count = 0


class _Recording:
    """What ActivationReplay adds to a Conv2d or Linear: the outputs' rows (a Linear's leading
    dimensions flattened), kept in a buffer that doubles when full and lives across rollouts."""

    replay: ActivationReplay
    recorded: torch.Tensor | None
    count: int  # rows recorded in this rollout
    cursor: int  # rows taken back by the replay so far

    def compute(self, x: torch.Tensor) -> torch.Tensor:
        """The layer's own forward."""
        return super().forward(x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mode = self.replay.mode
        if mode is None:
            return super().forward(x)
        if mode == "replay":
            return _Replay.apply(x, self.weight, self.bias, self)
        y = super().forward(x)
        rows = y if y.dim() == 2 or isinstance(self, nn.Conv2d) else y.reshape(-1, y.shape[-1])
        end = self.count + len(rows)
        if self.recorded is None or end > len(self.recorded):
            self.grow(rows, end)
        self.recorded[self.count : end] = rows  # a copy: y may get an in-place activation
        self.count = end
        return y

    def grow(self, rows: torch.Tensor, end: int) -> None:
        old = self.recorded
        capacity = max(end, 2 * len(old)) if old is not None else end
        self.recorded = torch.empty_like(rows[:1]).expand(capacity, *rows.shape[1:]).clone()
        if old is not None:
            self.recorded[: self.count] = old[: self.count]

    def take(self, rows: int) -> torch.Tensor | None:
        """The next `rows` recorded rows (fewer where the recording ends; None if none)."""
        if self.cursor >= self.count:
            return None
        taken = self.recorded[self.cursor : min(self.cursor + rows, self.count)]
        self.cursor += len(taken)
        return taken


class _ReplayedConv2d(_Recording, nn.Conv2d):
    pass


class _ReplayedLinear(_Recording, nn.Linear):
    pass


class _Replay(torch.autograd.Function):
    """y = layer(x) from the recorded rows (computing only the rest); backward as the layer's."""

    @staticmethod
    def forward(ctx, x, weight, bias, layer):  # noqa: ANN001, ANN205 (autograd's signature)
        conv = isinstance(layer, nn.Conv2d)
        rows = x.shape[0] if conv else x.numel() // x.shape[-1]
        taken = layer.take(rows)
        done = 0 if taken is None else len(taken)
        if done < rows:  # rows acting never saw (s_n): computed here, in acting's precision
            rest_x = x[done:] if conv else x.reshape(rows, -1)[done:]
            acting_fp32 = layer.recorded is not None and layer.recorded.dtype == torch.float32
            # bf16-learn acts in fp32: computing s_n in fp32 too keeps every forward value
            # acting's, and autocast does not convert a whole weight matrix for one row
            no_autocast = torch.autocast("cpu", enabled=False)
            with no_autocast if acting_fp32 else contextlib.nullcontext():
                rest = layer.compute(rest_x.float() if acting_fp32 else rest_x)
            y = rest if taken is None else torch.cat([taken, rest.to(taken.dtype)])
        else:
            y = taken.clone()  # a fresh tensor: the caller may modify it in place
        ctx.save_for_backward(x, weight)
        ctx.layer, ctx.has_bias = layer, bias is not None
        # the backward's precision: the learning pass's (bf16 under autocast), as autocast's is
        autocast = torch.is_autocast_enabled("cpu")
        ctx.dtype = torch.get_autocast_dtype("cpu") if autocast else y.dtype
        if conv or x.dim() == 2:
            return y
        return y.view(*x.shape[:-1], y.shape[-1]).clone()  # autograd forbids returning a view

    @staticmethod
    def backward(ctx, grad):  # noqa: ANN001, ANN205
        x, weight = ctx.saved_tensors
        layer = ctx.layer
        need_x, need_w, need_b = ctx.needs_input_grad[:3]
        need_b = need_b and ctx.has_bias
        dtype = ctx.dtype
        grad, xc, wc = grad.to(dtype), x.to(dtype), weight.to(dtype)
        if isinstance(layer, nn.Conv2d):
            grad_x, grad_w, grad_b = torch.ops.aten.convolution_backward(
                grad, xc, wc, [wc.shape[0]] if ctx.has_bias else None,
                list(layer.stride), list(layer.padding), list(layer.dilation), False, [0, 0],
                layer.groups, [need_x, need_w, need_b],
            )  # fmt: skip
        else:
            grad2, x2 = grad.reshape(-1, grad.shape[-1]), xc.reshape(-1, xc.shape[-1])
            grad_x = (grad2 @ wc).view(x.shape) if need_x else None
            grad_w = grad2.t() @ x2 if need_w else None
            grad_b = grad2.sum(0) if need_b else None
        return (
            None if grad_x is None else grad_x.to(x.dtype),
            None if grad_w is None else grad_w.to(weight.dtype),
            None if grad_b is None else grad_b.to(weight.dtype),
            None,
        )


def annealed_lr(args: Any, global_step: int) -> float:
    """The learning rate at global_step: annealed linearly to 0 at T_max (thesis Table 5.1)."""
    if not args.anneal_lr:
        return args.learning_rate
    return args.learning_rate * max(0.0, 1.0 - global_step / args.total_timesteps)


def clip_gradients(grads: list[torch.Tensor], mode: str, bound: float) -> float:
    """Clip in place (thesis 6.3.1); returns the global norm before clipping."""
    norms = torch.stack(torch._foreach_norm(grads))
    global_norm = torch.linalg.vector_norm(norms)
    # scale only when a bound is exceeded: a pass over 1.3M gradients saved in most updates
    if mode == "norm" and bool((norms > bound).any()):
        torch._foreach_mul_(grads, (bound / (norms + 1e-6)).clamp_(max=1.0).unbind())
    elif mode == "value":
        torch._foreach_clamp_min_(grads, -bound)
        torch._foreach_clamp_max_(grads, bound)
    elif mode == "global-norm" and global_norm > bound:
        torch._foreach_mul_(grads, torch.clamp(bound / (global_norm + 1e-6), max=1.0))
    return global_norm.item()


class SharedRMSprop:
    """RMSprop with the mean square shared by all workers (thesis 2.2.3, 5.2.2):
    ms <- rho * ms + (1 - rho) * g^2;  theta <- theta - lr * g / sqrt(ms + eps), from
    ms = `initial` (0 in the thesis's code; TensorFlow's RMSPropOptimizer starts at 1)."""

    def __init__(self, params: list[torch.Tensor], decay: float, eps: float, initial: float = 0.0):
        self.params, self.decay, self.eps = params, decay, eps
        self.square_avg = [torch.full_like(p, initial).share_memory_() for p in params]

    @torch.no_grad()
    def step(self, grads: list[torch.Tensor], lr: float) -> None:
        torch._foreach_mul_(self.square_avg, self.decay)
        torch._foreach_addcmul_(self.square_avg, grads, grads, value=1.0 - self.decay)
        # g * (ms + eps)^-0.5: on CPU faster than sqrt and a division, and pow_(-0.5) than
        # rsqrt_ (same values, about half the time in torch 2.13's foreach kernels)
        inv_rms = torch._foreach_add(self.square_avg, self.eps)
        torch._foreach_pow_(inv_rms, -0.5)
        torch._foreach_addcmul_(self.params, grads, inv_rms, value=-lr)

    def state_dict(self) -> dict:
        return {"square_avg": [s.clone() for s in self.square_avg]}

    @torch.no_grad()
    def load_state_dict(self, state: dict) -> None:
        torch._foreach_copy_(self.square_avg, state["square_avg"])


class SharedAdam:
    """Adam with shared moments and step count (thesis A.1.2, eqs. A.1-A.5; eps inside the root)."""

    def __init__(self, params: list[torch.Tensor], beta1: float, beta2: float, eps: float):
        self.params, self.beta1, self.beta2, self.eps = params, beta1, beta2, eps
        self.exp_avg = [torch.zeros_like(p).share_memory_() for p in params]
        self.exp_avg_sq = [torch.zeros_like(p).share_memory_() for p in params]
        self.step_count = torch.zeros(1, dtype=torch.float64).share_memory_()

    @torch.no_grad()
    def step(self, grads: list[torch.Tensor], lr: float) -> None:
        self.step_count += 1  # not atomic: Hogwild, like the moments
        t = self.step_count.item()
        torch._foreach_lerp_(self.exp_avg, grads, 1.0 - self.beta1)
        torch._foreach_mul_(self.exp_avg_sq, self.beta2)
        torch._foreach_addcmul_(self.exp_avg_sq, grads, grads, value=1.0 - self.beta2)
        inv_rms = torch._foreach_div(self.exp_avg_sq, 1.0 - self.beta2**t)
        torch._foreach_add_(inv_rms, self.eps)
        torch._foreach_pow_(inv_rms, -0.5)  # as SharedRMSprop's
        torch._foreach_addcmul_(
            self.params, self.exp_avg, inv_rms, value=-lr / (1.0 - self.beta1**t)
        )

    def state_dict(self) -> dict:
        return {
            "exp_avg": [m.clone() for m in self.exp_avg],
            "exp_avg_sq": [v.clone() for v in self.exp_avg_sq],
            "step_count": self.step_count.clone(),
        }

    @torch.no_grad()
    def load_state_dict(self, state: dict) -> None:
        torch._foreach_copy_(self.exp_avg, state["exp_avg"])
        torch._foreach_copy_(self.exp_avg_sq, state["exp_avg_sq"])
        self.step_count.copy_(state["step_count"])


def make_optimizer(params: list[torch.Tensor], args: Any) -> SharedRMSprop | SharedAdam:
    if args.optimizer == "adam":
        return SharedAdam(params, args.adam_beta1, args.adam_beta2, args.optim_eps)
    return SharedRMSprop(params, args.rms_decay, args.optim_eps, getattr(args, "rms_init", 0.0))


# ----------------------------------------------------------------------------------------------
# What the processes share, and their entry point
# ----------------------------------------------------------------------------------------------

_stop_requested = False  # set by SIGTERM in a worker or the evaluator, by a signal in the main
_main_pid: int | None = None  # in a forked process: the main process, whose death ends this one


class Shared:
    """Everything the workers share: the global network, optimizer statistics, counters."""

    STATS = ("episodes", "return_sum", "length_sum", "updates", "policy_loss", "value_loss",
             "entropy", "grad_norm")  # fmt: skip

    def __init__(self, model: nn.Module, args: Any, ctx: Any):
        self.model = model
        self.model.share_memory()
        self.params = list(self.model.parameters())
        self.optimizer = make_optimizer(self.params, args)
        # one step counter per worker, written only by its worker: lock-free and exact
        self.steps = torch.zeros(args.num_workers, dtype=torch.int64).share_memory_()
        self.base_step = torch.zeros(1, dtype=torch.int64).share_memory_()  # from --resume
        self.stats = torch.zeros(args.num_workers, len(self.STATS), dtype=torch.float64)
        self.stats.share_memory_()
        self.stop = ctx.Event()  # the workers stop after their rollout, the evaluator after its

    def global_step(self) -> int:
        return int(self.steps.sum()) + int(self.base_step)

    def keep_running(self) -> bool:
        """False once the run is stopping: the stop event, SIGTERM, or the main process gone."""
        if _stop_requested or self.stop.is_set():
            return False
        return _main_pid is None or os.getppid() == _main_pid


class PhaseTimer:
    """Times the phases of a worker's loop (benchmarks/a3c_step_profile.py): `lap(phase)` adds the
    time since the previous lap to the phase; `timed_env(env)` counts env.step time apart, which
    `lap("act")` splits off into "env step" (the rest is "act forward")."""

    PHASES = ("sync", "act forward", "env step", "learn forward", "backward", "clip", "optimizer")

    def __init__(self) -> None:
        self.spent = dict.fromkeys(self.PHASES, 0.0)
        self.env_seconds = 0.0
        self.last = time.perf_counter()

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        if phase == "act":
            self.spent["env step"] += self.env_seconds
            self.spent["act forward"] += now - self.last - self.env_seconds
            self.env_seconds = 0.0
        else:
            self.spent[phase] += now - self.last
        self.last = now

    def timed_env(self, env: gym.Env | gym.vector.VectorEnv) -> gym.Env | gym.vector.VectorEnv:
        """Wrap the worker's env so that its steps count apart; the clock restarts here, so
        that building the envs (16 emulators take seconds) is not counted as a phase."""
        timer = self
        self.last = time.perf_counter()
        base = gym.vector.VectorWrapper if isinstance(env, gym.vector.VectorEnv) else gym.Wrapper

        class TimedStep(base):
            def step(self, action):
                start = time.perf_counter()
                result = self.env.step(action)
                timer.env_seconds += time.perf_counter() - start
                return result

        return TimedStep(env)


def process_seed(seed: int, index: int) -> int:
    """Seed of process `index` (workers 0..N-1, then the evaluator); unlike seed + index, runs
    with neighbouring --seed values share no worker's random streams."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


# False leaves glibc's malloc as it is in the workers: benchmarks/a3c_throughput.py and
# a3c_step_profile.py --default-malloc set it, to measure what keeping freed memory saves
KEEP_FREED_MEMORY = True


def configure_process() -> None:
    """What every worker and evaluator process sets first: one torch thread, denormals flushed,
    and glibc's malloc told to keep freed memory. Without the last, a worker's multi-megabyte
    tensors (the FC layer's bf16 copy and gradient, 2.7 and 5.3 MB) may each come from a fresh
    mmap and pay a page fault per 4 KB page on every update: measured on A3C FF at K = 1, 23-40
    faults per env step in most processes and about 1 in others, depending on where glibc's heap
    happens to end; with it, about 1 in every process (benchmarks/a3c_step_profile.py prints the
    faults per step). On the 2-core development VM the 2-worker steps/s did not change
    measurably (results/throughput_batched/catch_malloc_ab_*.txt)."""
    torch.set_num_threads(1)
    torch.set_flush_denormal(True)  # decayed RMSprop statistics must not turn into slow denormals
    if not KEEP_FREED_MEMORY:
        return
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc (macOS, Windows): nothing to set
        return
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's malloc.h
    mallopt(m_mmap_threshold, 32 << 20)  # glibc's maximum: blocks up to 32 MB from the heap
    mallopt(m_trim_threshold, 1 << 30)  # and the heap not handed back to the system


def run_process(name: str, errors: Any, target: Callable[..., None], *target_args: Any) -> None:
    """Process entry: one torch thread; leave SIGINT to the main process (the terminal sends it
    to the whole group); SIGTERM ends the loop; an exception goes to `errors` as (name, trace)."""
    global _main_pid

    def on_sigterm(_signum, _frame):
        global _stop_requested
        _stop_requested = True

    _main_pid = os.getppid()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, on_sigterm)
    configure_process()
    try:
        target(*target_args)
    except BaseException:
        errors.put((name, traceback.format_exc()))
        sys.exit(1)


# ----------------------------------------------------------------------------------------------
# Evaluation
# ----------------------------------------------------------------------------------------------


def play_episodes(
    model: nn.Module, envs: list[gym.Env], seeds: list[int] | None = None
) -> np.ndarray:
    """Play one episode in each env in lock-step with one batched forward per step, sampling
    actions from pi; returns the raw game scores. A recurrent network (initial_state) carries a
    state row per running episode. Raises EvaluationInterrupted on Ctrl-C or SIGTERM."""
    observations = [env.reset(seed=None if seeds is None else seeds[i])[0] for i, env in
                    enumerate(envs)]  # fmt: skip
    scores = np.zeros(len(envs))
    running = list(range(len(envs)))
    recurrent = hasattr(model, "initial_state")
    state = model.initial_state(len(envs)) if recurrent else None
    with torch.inference_mode():
        while running:
            if _stop_requested:
                raise EvaluationInterrupted
            batch = torch.from_numpy(np.stack([observations[i] for i in running]))
            if recurrent:
                log_probs, _, state = model(batch[None], state)  # one step (T=1)
                log_probs = log_probs[0]
            else:
                log_probs, _ = model(batch)
            chosen = torch.multinomial(log_probs.exp(), 1).squeeze(1).tolist()
            still_running = []
            for i, action in zip(running, chosen, strict=True):
                observations[i], _, terminated, truncated, info = envs[i].step(action)
                if terminated or truncated:
                    scores[i] = float(info["episode"]["r"])
                else:
                    still_running.append(i)
            if recurrent:  # keep the state rows of the episodes still running
                state = tuple(s[[running.index(i) for i in still_running]] for s in state)
            running = still_running
    return scores


def make_eval_envs(
    agent: Agent, args: Any, video_dir: str | None, prefix: str = "rl-video"
) -> list[gym.Env]:
    """--eval-episodes envs; with a video_dir the first records every episode it plays."""
    envs = []
    for i in range(args.eval_episodes):
        if video_dir and i == 0:
            env = agent.make_env(args.env, render_mode="rgb_array")
            env = gym.wrappers.RecordVideo(
                env, video_dir, episode_trigger=lambda _: True, name_prefix=prefix
            )
        else:
            env = agent.make_env(args.env)
        envs.append(env)
    return envs


def evaluate_network(
    model: nn.Module, envs: list[gym.Env], rng: np.random.Generator, global_step: int, args: Any
) -> dict:
    """One evaluation of the thesis protocol: an episode per env, sampling from pi."""
    if hasattr(model, "set_progress"):  # e.g. GLPQ's temperature schedule
        model.set_progress(global_step / args.total_timesteps)
    start = time.time()
    scores = play_episodes(model, envs, rng.integers(2**31, size=len(envs)).tolist())
    return {"global_step": global_step, "scores": scores.tolist(), "seconds": time.time() - start}


def evaluator(
    agent: Agent,
    shared: Shared,
    args: Any,
    start_step: int,
    initial_params: list[torch.Tensor],
    run_dir: str,
    evaluations: Any,
) -> None:
    """Evaluate a snapshot of the global network every eval_interval global steps until the run
    stops; a fresh run's step 0 uses initial_params, copied before the workers started."""
    seed = process_seed(args.seed, args.num_workers)
    seed_everything(seed)
    rng = np.random.default_rng(seed)
    envs = make_eval_envs(
        agent, args, os.path.join(run_dir, "videos") if args.capture_video else None
    )
    model = agent.build_network(envs[0].action_space.n, args)
    params = list(model.parameters())
    try:
        if start_step == 0:
            with torch.no_grad():
                torch._foreach_copy_(params, initial_params)
            evaluations.put(evaluate_network(model, envs, rng, 0, args))
        next_eval = (start_step // args.eval_interval + 1) * args.eval_interval
        while shared.keep_running():
            global_step = shared.global_step()
            if next_eval <= global_step < args.total_timesteps:
                with torch.no_grad():
                    torch._foreach_copy_(params, shared.params)
                evaluations.put(evaluate_network(model, envs, rng, global_step, args))
                next_eval = (global_step // args.eval_interval + 1) * args.eval_interval
            else:
                time.sleep(0.05)
    except EvaluationInterrupted:
        pass
    for env in envs:
        env.close()


# ----------------------------------------------------------------------------------------------
# Checkpoints
# ----------------------------------------------------------------------------------------------


def save_checkpoint(
    path: Path, shared: Shared, args: Any, wall_time: float, script: str = ""
) -> None:
    """Write atomically (temp file + rename) so that a crash never leaves a corrupt checkpoint."""
    checkpoint = {
        "format": CHECKPOINT_FORMAT,
        "script": script,
        "network": type(shared.model).__name__,
        "model": {k: v.detach().clone() for k, v in shared.model.state_dict().items()},
        "optimizer": shared.optimizer.state_dict(),
        "optimizer_name": args.optimizer,
        "global_step": shared.global_step(),
        "wall_time": wall_time,
        "args": asdict(args),
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(checkpoint, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str, agent: Agent) -> dict:
    """Load a checkpoint of this script, or raise UsageError saying what is wrong with it."""
    if not os.path.isfile(path):
        raise UsageError(f"checkpoint {path!r} does not exist")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:
        raise UsageError(f"checkpoint {path!r} is corrupt or not a torch file: {e}") from e
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise UsageError(f"{path!r} is not a checkpoint written by this script")
    script = checkpoint.get("script")  # absent before it was stored
    if script and script != agent.script:
        raise UsageError(
            f"checkpoint {path!r} was written by {script}, not {agent.script}: "
            f"use python agents/{script}"
        )
    # (every script's network class is ActorCritic, so the stored "network" name tells nothing;
    # the script name above, or the tensors' shapes in load_network, refuse another's checkpoint)
    return checkpoint


def load_network(model: nn.Module, checkpoint: dict, path: str) -> None:
    """Load the checkpoint's weights; a mismatch is a one-line UsageError."""
    try:
        result = model.load_state_dict(checkpoint["model"], strict=False)
    except RuntimeError as e:  # a tensor of another shape: name the first one
        lines = [line.strip() for line in str(e).splitlines() if "size mismatch" in line]
        detail = lines[0] if lines else str(e).strip().splitlines()[-1]
        raise UsageError(f"checkpoint {path!r} does not fit this network: {detail}") from e
    problems = [f"{kind}: {', '.join(keys[:4])}" + (" ..." if len(keys) > 4 else "")
                for kind, keys in (("missing", result.missing_keys),
                                   ("unexpected", result.unexpected_keys)) if keys]  # fmt: skip
    if problems:
        raise UsageError(
            f"checkpoint {path!r} does not fit this network (is it another script's?): "
            + "; ".join(problems)
        )


def restore(shared: Shared, checkpoint: dict, args: Any, path: str, agent: Agent) -> None:
    for key in agent.network_args:
        # a flag newer than the checkpoint: see Agent.trained_args (a network that differs all
        # the same fails to load below, with a one-line message)
        trained = agent.trained_args(checkpoint).get(
            key, agent.Args.__dataclass_fields__[key].default
        )
        if trained != getattr(args, key):
            raise UsageError(
                f"checkpoint {path!r} was trained with --{key.replace('_', '-')} "
                f"{trained}, not {getattr(args, key)}"
            )
    if checkpoint["optimizer_name"] != args.optimizer:
        raise UsageError(
            f"checkpoint {path!r} holds {checkpoint['optimizer_name']} statistics; "
            f"pass --optimizer {checkpoint['optimizer_name']}"
        )
    load_network(shared.model, checkpoint, path)
    try:
        shared.optimizer.load_state_dict(checkpoint["optimizer"])
    except (RuntimeError, KeyError) as e:
        first_line = str(e).strip().splitlines()[0]
        raise UsageError(f"checkpoint {path!r} does not fit this network: {first_line}") from e
    shared.base_step[0] = checkpoint["global_step"]


# ----------------------------------------------------------------------------------------------
# Logging
# ----------------------------------------------------------------------------------------------

CSV_COLUMNS = ["global_step", "wall_time_s", "mean_return", "std_return", "episodes"]


def format_seconds(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m{secs:02d}s" if hours else f"{minutes}m{secs:02d}s"


def describe_exit(exitcode: int) -> str:
    if exitcode < 0:
        return f"was killed by {signal.Signals(-exitcode).name}"
    return f"exited with code {exitcode}"


def last_evaluation(csv_path: Path) -> dict | None:
    """The last row of an evaluations.csv (numbers parsed), or None."""
    if not csv_path.exists():
        return None
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None
    row = rows[-1]
    return {"global_step": int(row["global_step"]), "mean_return": float(row["mean_return"])}


class RunLog:
    """The main process's outputs: TensorBoard scalars, evaluations.csv and the console."""

    def __init__(self, run_dir: Path, args: Any, wall_offset: float):
        from torch.utils.tensorboard import SummaryWriter

        self.args, self.start, self.wall_offset = args, time.time(), wall_offset
        self.writer = SummaryWriter(str(run_dir))
        self.writer.add_text(
            "hyperparameters",
            "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items()),
        )
        csv_path = run_dir / "evaluations.csv"
        self.last_eval = last_evaluation(csv_path)  # a resumed run's, until its next one
        new_csv = not csv_path.exists()
        self.csv_file = open(csv_path, "a", newline="")  # noqa: SIM115 (open for the whole run)
        self.csv = csv.writer(self.csv_file)
        if new_csv:
            self.csv.writerow(CSV_COLUMNS)
        self.recent_return = float("nan")
        self.eval_seconds = 0.0

    def wall_time(self) -> float:
        """Seconds of training, including those before --resume."""
        return self.wall_offset + time.time() - self.start

    def evaluation(self, result: dict) -> None:
        scores = np.asarray(result["scores"])
        row = {"global_step": result["global_step"], "wall_time_s": round(self.wall_time(), 2),
               "mean_return": float(scores.mean()), "std_return": float(scores.std()),
               "episodes": len(scores)}  # fmt: skip
        self.csv.writerow(row.values())
        self.csv_file.flush()
        self.writer.add_scalar("eval/mean_return", row["mean_return"], row["global_step"])
        self.writer.add_scalar("eval/std_return", row["std_return"], row["global_step"])
        self.last_eval = row
        self.eval_seconds += result["seconds"]

    def progress(self, global_step: int, sps: float, lr: float, stats_delta: torch.Tensor) -> None:
        """Log the scalars of the last interval; stats_delta holds Shared.STATS summed."""
        self.writer.add_scalar("charts/SPS", sps, global_step)
        self.writer.add_scalar("charts/learning_rate", lr, global_step)
        episodes, return_sum, length_sum, updates = stats_delta[:4].tolist()
        if episodes > 0:
            self.recent_return = return_sum / episodes
            self.writer.add_scalar("charts/episodic_return", self.recent_return, global_step)
            self.writer.add_scalar("charts/episodic_length", length_sum / episodes, global_step)
        if updates > 0:
            for key, total in zip(Shared.STATS[4:], stats_delta[4:].tolist(), strict=True):
                self.writer.add_scalar(f"losses/{key}", total / updates, global_step)
        total_steps = self.args.total_timesteps
        eta = (total_steps - global_step) / sps if sps > 0 else float("inf")
        last = self.last_eval
        print(
            f"step {global_step:,}/{total_steps:,} ({100 * global_step / total_steps:.1f}%) | "
            f"SPS {sps:,.0f} | return {self.recent_return:.3f} | eval "
            + (f"{last['mean_return']:.3f} @ {last['global_step']:,}" if last else "-")
            + f" | ETA {format_seconds(max(0.0, eta))}",
            flush=True,
        )

    def close(self) -> None:
        self.writer.close()
        self.csv_file.close()


# ----------------------------------------------------------------------------------------------
# Training: start the processes, watch them, log, checkpoint, stop
# ----------------------------------------------------------------------------------------------


def train(agent: Agent, args: Any) -> dict:
    """Run A3C; returns the summary. Raises UsageError for a bad checkpoint, flag or env, before
    a run folder exists, and RunFailed when a worker or the evaluator dies."""
    global _stop_requested
    torch.set_num_threads(1)  # before any torch op, so that forking the workers is safe
    checkpoint = load_checkpoint(args.resume, agent) if args.resume else None
    seed_everything(args.seed)
    num_actions = probe_env(agent, args.env)
    ctx = mp.get_context("fork")  # fast start, and works when a script is loaded by path
    # the network is built here, before the run folder: its constructor rejects bad flags
    shared = Shared(agent.build_network(num_actions, args), args, ctx)
    if checkpoint is not None:
        restore(shared, checkpoint, args, args.resume, agent)
    start_step = shared.global_step()
    # the evaluator's step-0 network: copied before any worker can update the shared one
    initial_params = [p.detach().clone() for p in shared.params]

    run_name = f"{args.env}__{args.exp_name}__{args.seed}__{int(time.time())}"
    if args.run_dir:
        run_dir = Path(args.run_dir)
    elif checkpoint is not None:
        run_dir = Path(args.resume).resolve().parent
    else:
        run_dir = Path(args.runs_root) / run_name
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"

    stop_signal: list[str] = []

    def on_signal(signum, _frame):
        global _stop_requested
        _stop_requested = True  # also ends the final evaluation's episodes
        stop_signal.append(signal.Signals(signum).name)

    previous_handlers = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    errors, evaluations = ctx.SimpleQueue(), ctx.SimpleQueue()
    processes = {
        f"worker {i}": ctx.Process(
            target=run_process,
            args=(f"worker {i}", errors, agent.worker, i, shared, args),
            daemon=True,
        )
        for i in range(args.num_workers)
    }
    processes["evaluator"] = ctx.Process(
        target=run_process,
        args=("evaluator", errors, evaluator, agent, shared, args, start_step, initial_params,
              str(run_dir), evaluations),
        daemon=True,
    )  # fmt: skip
    for process in processes.values():
        process.start()
    workers = [p for name, p in processes.items() if name != "evaluator"]
    if checkpoint is not None:
        print(f"resuming run {run_dir.name} at step {start_step:,} -> {run_dir}", flush=True)
    else:
        print(f"run {run_name} -> {run_dir}", flush=True)
    print("pids: " + ", ".join(f"{n} {p.pid}" for n, p in processes.items()), flush=True)
    # after the fork: the TensorBoard writer thread must not be forked
    log = RunLog(run_dir, args, checkpoint["wall_time"] if checkpoint else 0.0)
    failures: list[str] = []

    def drain() -> None:
        """The one place that reads the processes' queues."""
        while not errors.empty():
            name, trace = errors.get()
            failures.append(f"{name} failed:\n{trace}")
        while not evaluations.empty():
            log.evaluation(evaluations.get())

    outcome = None
    steady_start = None  # (time, step) once every worker has finished a rollout, for the SPS
    last_log = (time.time(), start_step, shared.stats.clone())
    next_checkpoint = (start_step // args.checkpoint_interval + 1) * args.checkpoint_interval
    try:
        while outcome is None and not failures:
            time.sleep(0.1)
            # exit codes before the step: a worker that ended normally saw step >= T_max
            exitcodes = {name: p.exitcode for name, p in processes.items()}
            now, global_step = time.time(), shared.global_step()
            if steady_start is None and bool((shared.steps > 0).all()):
                steady_start = (now, global_step)
            drain()
            if stop_signal:
                outcome = f"stopped by {stop_signal[0]}"
                break
            for name, code in exitcodes.items():
                # exit 0 is only expected of a worker that reached T_max
                early = name == "evaluator" or global_step < args.total_timesteps
                if not failures and code is not None and (code != 0 or early):
                    failures.append(f"{name} (pid {processes[name].pid}) {describe_exit(code)}")
            if not failures and all(p.exitcode == 0 for p in workers):
                outcome = "done"
            elif args.time_limit is not None and now - log.start >= args.time_limit:
                outcome = "time limit"
            if global_step >= next_checkpoint:
                save_checkpoint(checkpoint_path, shared, args, log.wall_time(), agent.script)
                next_checkpoint = (
                    global_step // args.checkpoint_interval + 1
                ) * args.checkpoint_interval
            if now - last_log[0] >= args.log_interval:
                stats = shared.stats.clone()
                sps = (global_step - last_log[1]) / (now - last_log[0])
                log.progress(
                    global_step, sps, annealed_lr(args, global_step), (stats - last_log[2]).sum(0)
                )
                last_log = (now, global_step, stats)
    finally:
        shared.stop.set()  # the workers finish their rollout, the evaluator its evaluation
        finished = outcome in ("done", "time limit") and not failures
        if not finished:
            processes["evaluator"].terminate()  # SIGTERM: it drops the evaluation it plays
        deadline = time.time() + 10
        for name, process in processes.items():
            if name == "evaluator" and finished:
                while process.is_alive() and not stop_signal:  # a running evaluation completes
                    process.join(0.1)
                if stop_signal:  # unless a signal came: it drops that evaluation
                    process.terminate()
            process.join(max(0.1, deadline - time.time()))
            if process.is_alive():
                process.kill()
                process.join(1)
    end_time = time.time()
    global_step = shared.global_step()
    drain()
    if stop_signal and outcome in ("done", "time limit"):
        outcome = f"stopped by {stop_signal[0]} in the final evaluation"
    elif processes["evaluator"].exitcode not in (0, None) and finished and not failures:
        failures.append(f"evaluator {describe_exit(processes['evaluator'].exitcode)}")

    if not failures:
        save_checkpoint(checkpoint_path, shared, args, log.wall_time(), agent.script)
        if outcome in ("done", "time limit"):
            # the final evaluation, of the network after the last update, here in the main process
            video_dir = str(run_dir / "videos") if args.capture_video else None
            envs = make_eval_envs(agent, args, video_dir, prefix="final")
            rng = np.random.default_rng(process_seed(args.seed, args.num_workers + 1))
            try:
                log.evaluation(evaluate_network(shared.model, envs, rng, global_step, args))
            except EvaluationInterrupted:
                outcome = f"stopped by {stop_signal[0]} in the final evaluation"
            for env in envs:
                env.close()
    for s, handler in previous_handlers.items():
        signal.signal(s, handler)
    _stop_requested = False
    log.close()
    if failures:
        raise RunFailed("\n".join(failures))

    start_time, start_of_sps = steady_start or (log.start, start_step)
    sps = (global_step - start_of_sps) / max(end_time - start_time, 1e-9)
    last = log.last_eval
    summary = {
        "outcome": outcome,
        "run_dir": str(run_dir),
        "global_step": global_step,
        "final_eval": last["mean_return"] if last else float("nan"),
        "final_eval_step": last["global_step"] if last else None,
        "wall_time_s": time.time() - log.start,
        "eval_time_s": log.eval_seconds,
        "sps": sps,
    }
    eval_text = (
        f"final eval {last['mean_return']:.3f} at step {last['global_step']:,}"
        if last
        else "no evaluation"
    )
    print(
        f"{outcome}: {eval_text} | wall time {format_seconds(summary['wall_time_s'])} "
        f"(evaluations {format_seconds(log.eval_seconds)}) | SPS {sps:,.0f} | "
        f"{global_step:,} steps | {run_dir}",
        flush=True,
    )
    return summary


def evaluation_episodes(args: Any) -> int:
    """--evaluate's episodes: --eval-episodes, else a handful to watch with --render human and
    the protocol's 50 otherwise."""
    if args.eval_episodes is not None:
        return args.eval_episodes
    return HUMAN_EVAL_EPISODES if args.render == "human" else EVAL_EPISODES


def evaluate(agent: Agent, args: Any) -> np.ndarray:
    """Play episodes with a checkpoint's network, print each score and the mean."""
    checkpoint = load_checkpoint(args.evaluate, agent)
    try:
        trained = agent.Args(**agent.trained_args(checkpoint))
    except TypeError as e:
        raise UsageError(
            f"checkpoint {args.evaluate!r} has other flags than this script: {e}"
        ) from e
    episodes = evaluation_episodes(args)
    if episodes < 1:
        raise UsageError(f"--eval-episodes must be >= 1 (got {episodes})")
    seed_everything(args.seed)
    num_actions = probe_env(agent, trained.env)
    env = agent.make_env(
        trained.env, render_mode="rgb_array" if args.capture_video else
        ("human" if args.render == "human" else None)
    )  # fmt: skip
    if args.capture_video:
        video_dir = os.path.join(os.path.dirname(args.evaluate), "videos-evaluate")
        env = gym.wrappers.RecordVideo(env, video_dir, episode_trigger=lambda _: True)
    model = agent.network(num_actions, trained)
    load_network(model, checkpoint, args.evaluate)
    if hasattr(model, "set_progress"):  # e.g. GLPQ's temperature schedule
        model.set_progress(checkpoint["global_step"] / trained.total_timesteps)
    scores = []
    try:
        for episode in range(episodes):
            seed = args.seed + episode
            scores.append(play_episodes(model, [env], [seed])[0])
            print(f"episode {episode + 1}: score {scores[-1]:g}", flush=True)
    except KeyboardInterrupt:  # Ctrl-C: the episodes played so far still count
        print(f"stopped by SIGINT after {len(scores)} episodes", flush=True)
    env.close()
    if not scores:
        return np.asarray(scores)
    print(
        f"{trained.env}, step {checkpoint['global_step']:,}: mean score {np.mean(scores):.3f} "
        f"+- {np.std(scores):.3f} over {len(scores)} episodes",
        flush=True,
    )
    return np.asarray(scores)


def run(agent: Agent) -> int:
    """The command line: train, or --evaluate a checkpoint. Exit codes: 0 ok, 1 a process died,
    2 bad usage (a one-line message, nothing created)."""
    import tyro

    args = tyro.cli(agent.Args)
    import catch_env  # noqa: F401  (registers Catch-v0 and the ALE ids)

    try:
        if args.evaluate:
            evaluate(agent, args)
            return 0
        train(agent, resolve_defaults(args))
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except RunFailed as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0
