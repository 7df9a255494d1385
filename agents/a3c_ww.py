# A3C WW ("what and where"): A3C FF whose second convolution's maps go partly through ReLU
# (what) and partly through a spatial softmax (where). Thesis "Deep Reinforcement Learning of
# Video Games", section 6.2.1; the rest is a copy of a3c_ff.py: `diff agents/a3c_ff.py
# agents/a3c_ww.py` shows the network and its flags. Default: the text's reading (A3C FF's
# convolutions, 6.4); --conv-layout final gives the thesis code's final 5x5/3, 3x3/2 network.
#
# Processes: the main process owns the shared (global) network and optimizer statistics, logs,
# checkpoints and watches the others; N workers act and learn Hogwild-style (no locks); one
# evaluator process plays the evaluation episodes without stopping the workers.
import csv
import math
import os
import random
import signal
import sys
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.multiprocessing as mp
import torch.nn as nn
import torch.nn.functional as F
import tyro

CHECKPOINT_FORMAT = "a3c-checkpoint-v1"


class UsageError(Exception):
    """A bad flag, or a missing, corrupt or incompatible checkpoint."""


def default_num_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


@dataclass
class Args:
    exp_name: str = os.path.basename(__file__)[: -len(".py")]
    """the name of this experiment (part of the run name)"""
    seed: int = 1
    """seed of the experiment: of the initial network and, with its index, of each process"""
    env: str = "Catch-v0"
    """the Gymnasium id: Catch-v0 or an ALE id such as BreakoutNoFrameskip-v4"""
    total_timesteps: int | None = None
    """total global env steps T_max (default: 1e6 for Catch, 1e8 for ALE ids)"""
    num_workers: int = default_num_workers()
    """the number of actor-learner processes (default: the number of CPU cores)"""
    time_limit: float | None = None
    """stop training after this many seconds of wall time, as if T_max was reached"""

    # Algorithm (thesis Table 5.1)
    learning_rate: float = 7e-4
    """the learning rate eta"""
    anneal_lr: bool = True
    """anneal the learning rate linearly to 0 at T_max (by the shared global step)"""
    t_max: int = 20
    """the rollout length: steps per update, fewer when the episode ends"""
    gamma: float = 0.99
    """the discount factor gamma"""
    ent_coef: float = 0.01
    """the entropy factor beta"""
    vf_coef: float = 0.5
    """the value loss factor lambda_V (thesis 6.4.1); the value loss is vf_coef * 0.5 * (G - V)^2"""

    # Optimizer (thesis 2.2.3, 5.2.2, A.1.2)
    optimizer: Literal["rmsprop", "adam"] = "rmsprop"
    """the shared optimizer; its statistics live in shared memory and are updated without locks"""
    rms_decay: float = 0.99
    """RMSprop decay rho of the mean square"""
    adam_beta1: float = 0.9
    """Adam's first-moment decay beta1"""
    adam_beta2: float = 0.99
    """Adam's second-moment decay beta2 (thesis A.1.2 says 0.99; the thesis's runs used 0.999)"""
    optim_eps: float = 0.1
    """the optimizer epsilon, inside the square root: g / sqrt(ms + eps)"""
    grad_clip_mode: Literal["norm", "value", "global-norm", "none"] = "norm"
    """gradient clipping: per-tensor norm, per-value, global norm (thesis 6.3.1), or none"""
    grad_clip: float | None = None
    """the clipping bound (default: 40 for norm and value, c_g = 25 for global-norm)"""

    # Network (thesis 5.2.1 and chapter 6)
    activation: Literal["relu", "elu"] = "relu"
    """the hidden-layer activation (thesis 6.3.2)"""
    weight_init: Literal["torch", "he", "uniform-sqrt3"] = "torch"
    """weights: torch U(+-1/sqrt(fan_in)); he: truncated normal std sqrt(2/fan_in);
    uniform-sqrt3: U(+-sqrt(3)/sqrt(fan_in)) (thesis 6.3.3)"""
    bias_init: float | None = None
    """a constant for every bias (thesis A.1.3 uses 0.01); default: U(+-1/sqrt(fan_in)) for
    torch init, 0 for the other weight inits"""
    scale_obs: bool | None = None
    """divide frames by 255; default: yes for ALE, no for Catch (the thesis fed Catch 0..255)"""

    # Spatial softmax (thesis 6.2)
    conv_layout: Literal["ff", "final"] = "ff"
    """the convolutions: ff = A3C FF's conv 32 8x8/4, conv 64 4x4/2 (84 -> 20 -> 9; the thesis
    text, 6.4, and most likely the Figure 6.5 runs); final = the thesis code's final conv 32
    5x5/3, conv 64 3x3/2 (84 -> 27 -> 13)"""
    ss_temperature: Literal["per-map", "global"] = "per-map"
    """the softmax temperature: one tau_k per map (the text's A3C SS TT) or one global tau (the
    text's A3C SS GT TT). As run (the thesis code inverted a flag): Figure 6.5's WW = global;
    Figure 6.9's WW = per-map with --ss-initial-temperature 1"""
    ss_trainable_temperature: bool = True
    """train the temperature by gradient descent; else it stays at its initial value"""
    ss_initial_temperature: float = 0.6
    """the temperature's initial value"""
    ww_where_maps: int = 32
    """of the second convolution's 64 maps, how many go through the spatial softmax (where);
    the others go through the activation and are flattened (what)"""

    # Evaluation, logging, checkpoints
    eval_interval: int | None = None
    """global steps between evaluations (default: 50,000 for Catch, 1,000,000 for ALE)"""
    eval_episodes: int = 50
    """episodes per evaluation, sampling actions from pi"""
    checkpoint_interval: int | None = None
    """global steps between checkpoints (default: the evaluation interval); also at the end"""
    log_interval: float = 5.0
    """seconds between console progress lines and TensorBoard scalars"""
    runs_root: str = "runs"
    """the folder that gets a new run folder runs_root/<run_name>"""
    run_dir: str | None = None
    """the run folder, instead of runs_root/<run_name> (with --resume: the checkpoint's)"""
    resume: str | None = None
    """a checkpoint.pt to continue training from (network, optimizer statistics, global step)"""
    capture_video: bool = False
    """record evaluation episodes (one per evaluation) to <run_dir>/videos"""
    evaluate: str | None = None
    """play --eval-episodes episodes with the network of this checkpoint, print the scores, exit"""
    render: Literal["none", "human"] = "none"
    """with --evaluate: 'human' shows the episodes in a window"""


def resolve_defaults(args: Args) -> Args:
    """Fill the env-dependent defaults and reject bad numbers with a clear message."""
    from catch_env.wrappers import is_atari

    try:
        atari = is_atari(args.env)  # registers the ALE ids first
    except ImportError as e:
        raise UsageError(str(e)) from e
    except gym.error.Error as e:
        raise UsageError(
            f"unknown --env {args.env!r}; valid: Catch-v0 or an ALE id such as "
            "BreakoutNoFrameskip-v4, PongNoFrameskip-v4, BeamRiderNoFrameskip-v4"
        ) from e
    if args.total_timesteps is None:
        args.total_timesteps = 100_000_000 if atari else 1_000_000
    if args.eval_interval is None:
        args.eval_interval = 1_000_000 if atari else 50_000
    if args.checkpoint_interval is None:
        args.checkpoint_interval = args.eval_interval
    if args.grad_clip is None:
        args.grad_clip = 25.0 if args.grad_clip_mode == "global-norm" else 40.0
    if args.scale_obs is None:
        args.scale_obs = atari
    checks = {
        "--total-timesteps": (args.total_timesteps, args.total_timesteps > 0, "> 0"),
        "--num-workers": (args.num_workers, args.num_workers >= 1, ">= 1"),
        "--learning-rate": (args.learning_rate, args.learning_rate >= 0, ">= 0"),
        "--t-max": (args.t_max, args.t_max >= 1, ">= 1"),
        "--gamma": (args.gamma, 0 <= args.gamma <= 1, "in [0, 1]"),
        "--ent-coef": (args.ent_coef, args.ent_coef >= 0, ">= 0"),
        "--vf-coef": (args.vf_coef, args.vf_coef >= 0, ">= 0"),
        "--rms-decay": (args.rms_decay, 0 <= args.rms_decay < 1, "in [0, 1)"),
        "--adam-beta1": (args.adam_beta1, 0 <= args.adam_beta1 < 1, "in [0, 1)"),
        "--adam-beta2": (args.adam_beta2, 0 <= args.adam_beta2 < 1, "in [0, 1)"),
        "--optim-eps": (args.optim_eps, args.optim_eps > 0, "> 0"),
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


def make_env(env_id: str, *, render_mode: str | None = None, video_dir: str | None = None):
    """The thesis preprocessing from catch_env.wrappers: 4 stacked 84x84 uint8 frames, Atari
    action repeat 4 and reward clipping; info["episode"]["r"] is the raw game score."""
    from catch_env.wrappers import make_env as make_wrapped_env

    env = make_wrapped_env(env_id, render_mode="rgb_array" if video_dir else render_mode)
    if video_dir:
        env = gym.wrappers.RecordVideo(env, video_dir, episode_trigger=lambda _: True)
    return env


# ----------------------------------------------------------------------------------------------
# The network. Variants (LWS, SS, WW, LSTM, LPQ, GLPQ) replace this class and NETWORK_ARGS.
# Contract: forward(obs uint8 (B, 4, 84, 84)) -> (log-probabilities (B, A), values (B,)).
# ----------------------------------------------------------------------------------------------
# args a checkpoint's network depends on; the initial temperature too, since a fixed one is a
# buffer that every process builds from it
NETWORK_ARGS = ("env", "activation", "scale_obs", "conv_layout", "ss_temperature",
                "ss_trainable_temperature", "ss_initial_temperature", "ww_where_maps")  # fmt: skip


class SpatialSoftmax(nn.Module):
    """Spatial softmax (thesis 6.2, eqs. 6.3 and 6.4; Levine et al. 2016). Per map k a softmax
    over positions, psi(F_k)_ij = exp(F_kij / tau_k) / sum_uv exp(F_kuv / tau_k), and its
    expected coordinates Y_2k = sum_ij psi_ij x_j, Y_2k+1 = sum_ij psi_ij y_i, with x_j (column)
    and y_i (row, downwards) evenly spaced in [-0.5, 0.5]. (B, K, H, W) -> (B, 2K)."""

    def __init__(self, maps: int, size: int, args: Args):
        super().__init__()
        if not (args.ss_initial_temperature > 0 and math.isfinite(args.ss_initial_temperature)):
            raise UsageError(
                f"--ss-initial-temperature must be > 0 (got {args.ss_initial_temperature})"
            )
        axis = torch.linspace(-0.5, 0.5, size)
        x, y = torch.meshgrid(axis, axis, indexing="xy")  # x[i, j] = axis[j], y[i, j] = axis[i]
        self.register_buffer("coordinates", torch.stack([x, y], -1).view(-1, 2), persistent=False)
        shape = (maps, 1) if args.ss_temperature == "per-map" else (1, 1)
        temperature = torch.full(shape, args.ss_initial_temperature)
        if args.ss_trainable_temperature:
            self.temperature = nn.Parameter(temperature)
        else:
            self.register_buffer("temperature", temperature)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        softmax = torch.softmax(features.flatten(2) / self.temperature, dim=-1)  # (B, K, H*W)
        return (softmax @ self.coordinates).flatten(1)  # (B, K, 2) -> x_1, y_1, x_2, y_2, ...


class ActorCritic(nn.Module):
    """A3C WW (thesis 6.2.1, 6.4): conv 32 ReLU, conv 64; of its 64 maps, 32 go through ReLU and
    are flattened (what, 32 * n * n values) and 32 through a spatial softmax (where, 2 * 32
    coordinates); both feed FC 256, then the softmax policy and linear value. The convolutions
    (--conv-layout): ff (default; 6.4: "The FF and WW architectures have two convolution layers
    with the same kernel size (8x8 and 4x4) and strides", and most likely the Figure 6.5 runs',
    see thesis-notes.md "As run") 8x8/4 and 4x4/2, n = 9; final (the thesis code's final
    network) 5x5/3 and 3x3/2, n = 13."""

    def __init__(self, num_actions: int, args: Args):
        super().__init__()
        if not 0 <= args.ww_where_maps <= 64:
            raise UsageError(f"--ww-where-maps must be in [0, 64] (got {args.ww_where_maps})")
        activation = {"relu": nn.ReLU, "elu": nn.ELU}[args.activation]
        self.what_maps = 64 - args.ww_where_maps
        # (kernel, stride) of each convolution: 84 -> 20 -> 9 (ff) or 84 -> 27 -> 13 (final)
        (k1, s1), (k2, s2) = {"ff": ((8, 4), (4, 2)), "final": ((5, 3), (3, 2))}[args.conv_layout]
        size = ((84 - k1) // s1 + 1 - k2) // s2 + 1  # the second convolution's output size
        self.convs = nn.Sequential(
            nn.Conv2d(4, 32, k1, stride=s1),
            activation(inplace=True),  # fewer allocations, same gradients
            nn.Conv2d(32, 64, k2, stride=s2),  # each branch applies its own nonlinearity
        )
        self.what = nn.Sequential(activation(), nn.Flatten())  # not in place: a slice of maps
        self.where = SpatialSoftmax(args.ww_where_maps, size, args)
        self.fc = nn.Sequential(
            nn.Linear(self.what_maps * size * size + 2 * args.ww_where_maps, 256),
            activation(inplace=True),
        )
        self.policy = nn.Linear(256, num_actions)
        self.value = nn.Linear(256, 1)
        self.obs_scale = 1.0 / 255.0 if args.scale_obs else 1.0
        init_parameters(self, args.weight_init, args.bias_init)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # channels_last makes oneDNN's convolution backward about 2x faster on CPU
        x = obs.to(dtype=torch.float32, memory_format=torch.channels_last)
        if self.obs_scale != 1.0:
            x = x * self.obs_scale
        maps = self.convs(x)
        what, where = maps[:, : self.what_maps], maps[:, self.what_maps :]
        hidden = self.fc(torch.cat([self.what(what), self.where(where)], dim=1))
        return F.log_softmax(self.policy(hidden), dim=-1), self.value(hidden).squeeze(-1)


# ----------------------------------------------------------------------------------------------


def init_parameters(model: nn.Module, weight_init: str, bias_init: float | None) -> None:
    """Initialise every Conv2d/Linear layer with the thesis 6.3.3 scheme; biases per A.1.3."""
    for layer in model.modules():
        if not isinstance(layer, (nn.Conv2d, nn.Linear)):
            continue
        fan_in = layer.weight[0].numel()
        if weight_init == "he":
            std = math.sqrt(2.0 / fan_in)
            nn.init.trunc_normal_(layer.weight, std=std, a=-2 * std, b=2 * std)
        elif weight_init == "uniform-sqrt3":
            bound = math.sqrt(3.0 / fan_in)
            nn.init.uniform_(layer.weight, -bound, bound)
        # "torch": keep PyTorch's default, which is Torch7's U(-1/sqrt(fan_in), 1/sqrt(fan_in))
        if bias_init is not None:
            nn.init.constant_(layer.bias, bias_init)
        elif weight_init != "torch":
            nn.init.zeros_(layer.bias)


def annealed_lr(args: Args, global_step: int) -> float:
    if not args.anneal_lr:
        return args.learning_rate
    return args.learning_rate * max(0.0, 1.0 - global_step / args.total_timesteps)


def sample_action(probs: list[float], u: float) -> int:
    """Inverse-CDF sampling with u ~ U[0, 1): a few microseconds for one state, unlike
    torch.multinomial's per-call overhead."""
    u *= sum(probs)
    for action, p in enumerate(probs):
        u -= p
        if u < 0.0:
            return action
    return len(probs) - 1


def n_step_returns(rewards: np.ndarray, bootstrap_value: float, gamma: float) -> np.ndarray:
    """G_i = r_i + gamma * G_{i+1}, starting from G = V(s_last), or 0 after a terminal state."""
    returns = np.empty(len(rewards), dtype=np.float32)
    g = bootstrap_value
    for i in range(len(rewards) - 1, -1, -1):
        g = rewards[i] + gamma * g
        returns[i] = g
    return returns


def a3c_loss(
    log_probs: torch.Tensor,
    actions: torch.Tensor,
    values: torch.Tensor,
    returns: torch.Tensor,
    ent_coef: float,
    vf_coef: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The A3C loss summed over the rollout (Algorithm 1): policy gradient with the advantage
    not back-propagated, minus beta * entropy, plus lambda_V * 0.5 * (G - V)^2.
    Returns (loss, policy_loss, value_loss, entropy), the last three before their factors."""
    advantages = returns - values
    policy_loss = -(log_probs.gather(1, actions[:, None]).squeeze(1) * advantages.detach()).sum()
    entropy = -(log_probs.exp() * log_probs).sum()
    value_loss = 0.5 * advantages.pow(2).sum()
    return policy_loss - ent_coef * entropy + vf_coef * value_loss, policy_loss, value_loss, entropy


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
    ms <- rho * ms + (1 - rho) * g^2;  theta <- theta - lr * g / sqrt(ms + eps)."""

    def __init__(self, params: list[torch.Tensor], decay: float, eps: float):
        self.params, self.decay, self.eps = params, decay, eps
        self.square_avg = [torch.zeros_like(p).share_memory_() for p in params]

    @torch.no_grad()
    def step(self, grads: list[torch.Tensor], lr: float) -> None:
        torch._foreach_mul_(self.square_avg, self.decay)
        torch._foreach_addcmul_(self.square_avg, grads, grads, value=1.0 - self.decay)
        # g * rsqrt(ms + eps): on CPU about 2x faster than sqrt and a division
        inv_rms = torch._foreach_add(self.square_avg, self.eps)
        torch._foreach_rsqrt_(inv_rms)
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
        torch._foreach_rsqrt_(inv_rms)
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


def make_optimizer(params: list[torch.Tensor], args: Args) -> SharedRMSprop | SharedAdam:
    if args.optimizer == "adam":
        return SharedAdam(params, args.adam_beta1, args.adam_beta2, args.optim_eps)
    return SharedRMSprop(params, args.rms_decay, args.optim_eps)


class Shared:
    """Everything the processes share: the global network, optimizer statistics, counters."""

    STATS = ("episodes", "return_sum", "length_sum", "updates", "policy_loss", "value_loss",
             "entropy", "grad_norm")  # fmt: skip

    def __init__(self, args: Args, num_actions: int, ctx):
        self.model = ActorCritic(num_actions, args).to(memory_format=torch.channels_last)
        self.model.share_memory()
        self.params = list(self.model.parameters())
        self.optimizer = make_optimizer(self.params, args)
        # one step counter per worker, written only by its worker: lock-free and exact
        self.steps = torch.zeros(args.num_workers, dtype=torch.int64).share_memory_()
        self.base_step = torch.zeros(1, dtype=torch.int64).share_memory_()  # from --resume
        self.stats = torch.zeros(args.num_workers, len(self.STATS), dtype=torch.float64)
        self.stats.share_memory_()
        self.ready = torch.zeros(args.num_workers, dtype=torch.int64).share_memory_()
        self.evaluator_ready = ctx.Event()  # the workers start once it has the initial network
        self.stop = ctx.Event()  # tells the workers to stop after their rollout
        self.final_eval = ctx.Event()  # training finished: the evaluator plays the last one
        self.stop_evaluator = ctx.Event()  # interrupted or failed: no final evaluation
        self.errors = ctx.SimpleQueue()  # (process name, traceback)
        self.evaluations = ctx.SimpleQueue()  # dicts from the evaluator

    def global_step(self) -> int:
        return int(self.steps.sum()) + int(self.base_step)


def process_seed(seed: int, index: int) -> int:
    """Seed of process `index` (workers 0..N-1, then the evaluator); unlike seed + index, runs
    with neighbouring --seed values share no worker's random streams."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)


terminate_requested = False  # set by SIGTERM in a worker or the evaluator


def run_process(name: str, shared: Shared, target, *target_args) -> None:
    """Process entry: one torch thread; leave SIGINT to the main process (the terminal sends it
    to the whole group); SIGTERM ends the loop; any exception is reported to the main process."""

    def on_sigterm(_signum, _frame):
        global terminate_requested
        terminate_requested = True

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, on_sigterm)
    torch.set_num_threads(1)
    torch.set_flush_denormal(True)  # decayed RMSprop statistics must not turn into slow denormals
    try:
        target(*target_args)
    except BaseException:
        shared.errors.put((name, traceback.format_exc()))
        sys.exit(1)


def worker(worker_id: int, shared: Shared, args: Args, parent_pid: int) -> None:
    """One actor-learner (Algorithm 1): sync, act t_max steps, one batched update, repeat."""
    seed = process_seed(args.seed, worker_id)
    seed_everything(seed)
    rng = random.Random(seed)
    env = make_env(args.env)
    model = ActorCritic(env.action_space.n, args).to(memory_format=torch.channels_last)
    params = list(model.parameters())
    # the frames of the rollout, channels-last like the network's input (see ActorCritic)
    obs_buf = torch.zeros((args.t_max + 1, *env.observation_space.shape), dtype=torch.uint8)
    obs_buf = obs_buf.contiguous(memory_format=torch.channels_last)
    actions = np.zeros(args.t_max, dtype=np.int64)  # NumPy: cheaper to write one by one
    rewards = np.zeros(args.t_max, dtype=np.float32)
    stats = torch.zeros(len(Shared.STATS), dtype=torch.float64)
    obs, _ = env.reset(seed=seed)
    obs_buf[0].copy_(torch.from_numpy(obs))
    while not shared.evaluator_ready.wait(0.1):  # so that the first evaluation sees step 0
        if terminate_requested or shared.stop.is_set() or os.getppid() != parent_pid:
            return
    shared.ready[worker_id] = 1

    while not (terminate_requested or shared.stop.is_set()) and os.getppid() == parent_pid:
        global_step = shared.global_step()
        if global_step >= args.total_timesteps:
            break
        with torch.no_grad():
            torch._foreach_copy_(params, shared.params)  # theta' <- theta
        # act with the synced local network until t_max steps or the episode ends
        terminated = truncated = False
        with torch.inference_mode():
            for t in range(args.t_max):
                log_probs, _ = model(obs_buf[t : t + 1])
                action = sample_action(log_probs[0].exp().tolist(), rng.random())
                obs, reward, terminated, truncated, info = env.step(action)
                actions[t], rewards[t] = action, reward
                obs_buf[t + 1].copy_(torch.from_numpy(obs))
                if terminated or truncated:
                    stats[0] += 1
                    stats[1] += float(info["episode"]["r"])
                    stats[2] += int(info["episode"]["l"])
                    break
        n = t + 1
        # one batched forward/backward over the rollout; row n gives V(s_last) to bootstrap from
        log_probs, values = model(obs_buf[: n if terminated else n + 1])
        bootstrap = 0.0 if terminated else float(values[n])
        returns = torch.from_numpy(n_step_returns(rewards[:n], bootstrap, args.gamma))
        loss, policy_loss, value_loss, entropy = a3c_loss(
            log_probs[:n],
            torch.from_numpy(actions[:n]),
            values[:n],
            returns,
            args.ent_coef,
            args.vf_coef,
        )
        grads = torch.autograd.grad(loss, params)
        grad_norm = clip_gradients(grads, args.grad_clip_mode, args.grad_clip)
        shared.optimizer.step(grads, annealed_lr(args, global_step))

        shared.steps[worker_id] += n
        stats[3] += 1
        # Python floats: adding the loss tensors themselves would chain every rollout's autograd
        # graph onto stats, a memory leak
        stats[4:8] += torch.tensor(
            [policy_loss.item(), value_loss.item(), entropy.item(), grad_norm]
        )
        shared.stats[worker_id].copy_(stats)
        if terminated or truncated:
            obs, _ = env.reset()
            obs_buf[0].copy_(torch.from_numpy(obs))
        else:
            obs_buf[0].copy_(obs_buf[n])
    env.close()


def play_episodes(
    model: nn.Module, envs: list[gym.Env], seeds: list[int] | None = None
) -> np.ndarray:
    """Play one episode in each env in lock-step with one batched forward per step, sampling
    actions from pi; returns the raw game scores."""
    observations = [env.reset(seed=None if seeds is None else seeds[i])[0] for i, env in
                    enumerate(envs)]  # fmt: skip
    scores = np.zeros(len(envs))
    running = list(range(len(envs)))
    with torch.inference_mode():
        while running:
            batch = torch.from_numpy(np.stack([observations[i] for i in running]))
            log_probs, _ = model(batch)
            chosen = torch.multinomial(log_probs.exp(), 1).squeeze(1).tolist()
            still_running = []
            for i, action in zip(running, chosen, strict=True):
                observations[i], _, terminated, truncated, info = envs[i].step(action)
                if terminated or truncated:
                    scores[i] = float(info["episode"]["r"])
                else:
                    still_running.append(i)
            running = still_running
    return scores


def evaluator(shared: Shared, args: Args, run_dir: str, parent_pid: int) -> None:
    """Evaluate a snapshot of the global network every eval_interval global steps (thesis
    protocol: 50 episodes sampling from pi) and once more when training ends."""
    seed = process_seed(args.seed, args.num_workers)
    seed_everything(seed)
    rng = np.random.default_rng(seed)
    video_dir = os.path.join(run_dir, "videos") if args.capture_video else None
    envs = [make_env(args.env, video_dir=video_dir if i == 0 else None)
            for i in range(args.eval_episodes)]  # fmt: skip
    model = ActorCritic(envs[0].action_space.n, args).to(memory_format=torch.channels_last)
    params = list(model.parameters())
    start_step = shared.global_step()  # the workers wait for evaluator_ready
    next_eval = (
        0 if start_step == 0 else (start_step // args.eval_interval + 1) * args.eval_interval
    )
    if next_eval > 0:
        shared.evaluator_ready.set()
    while not terminate_requested and os.getppid() == parent_pid:
        final = shared.final_eval.is_set()
        global_step = shared.global_step()
        if final or (global_step >= next_eval and global_step < args.total_timesteps):
            with torch.no_grad():
                torch._foreach_copy_(params, shared.params)
            shared.evaluator_ready.set()  # the initial network is copied: the workers may start
            start = time.time()
            scores = play_episodes(model, envs, rng.integers(2**31, size=len(envs)).tolist())
            shared.evaluations.put(
                {"global_step": global_step, "scores": scores.tolist(), "final": final,
                 "seconds": time.time() - start}
            )  # fmt: skip
            if final:
                break
            next_eval = (global_step // args.eval_interval + 1) * args.eval_interval
        elif shared.stop_evaluator.is_set():
            break
        else:
            time.sleep(0.05)
    for env in envs:
        env.close()


def save_checkpoint(path: Path, shared: Shared, args: Args, wall_time: float) -> None:
    """Write atomically (temp file + rename) so that a crash never leaves a corrupt checkpoint."""
    checkpoint = {
        "format": CHECKPOINT_FORMAT,
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


def load_checkpoint(path: str) -> dict:
    """Load a checkpoint of this script, or raise UsageError saying what is wrong with it."""
    if not os.path.isfile(path):
        raise UsageError(f"checkpoint {path!r} does not exist")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:
        raise UsageError(f"checkpoint {path!r} is corrupt or not a torch file: {e}") from e
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise UsageError(f"{path!r} is not a checkpoint written by this script")
    if checkpoint["network"] != ActorCritic.__name__:
        raise UsageError(
            f"checkpoint {path!r} holds a {checkpoint['network']} network, "
            f"this script builds {ActorCritic.__name__}"
        )
    return checkpoint


def restore(shared: Shared, checkpoint: dict, args: Args, path: str) -> None:
    for key in NETWORK_ARGS:
        # a flag newer than the checkpoint counts as its default (a network that differs all the
        # same fails to load below, with a one-line message)
        trained = checkpoint["args"].get(key, Args.__dataclass_fields__[key].default)
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
    try:
        shared.model.load_state_dict(checkpoint["model"])
        shared.optimizer.load_state_dict(checkpoint["optimizer"])
    except (RuntimeError, KeyError) as e:
        raise UsageError(f"checkpoint {path!r} does not fit this network: {e}") from e
    shared.base_step[0] = checkpoint["global_step"]


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


class RunLog:
    """The main process's outputs: TensorBoard scalars, evaluations.csv and the console."""

    def __init__(self, run_dir: Path, args: Args, wall_offset: float):
        from torch.utils.tensorboard import SummaryWriter

        self.args, self.start, self.wall_offset = args, time.time(), wall_offset
        self.writer = SummaryWriter(str(run_dir))
        self.writer.add_text(
            "hyperparameters",
            "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items()),
        )
        csv_path = run_dir / "evaluations.csv"
        new_csv = not csv_path.exists()
        self.csv_file = open(csv_path, "a", newline="")  # noqa: SIM115 (open for the whole run)
        self.csv = csv.writer(self.csv_file)
        if new_csv:
            self.csv.writerow(
                ["global_step", "wall_time_s", "mean_return", "std_return", "episodes"]
            )
        self.last_eval: dict | None = None
        self.recent_return = float("nan")

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


def train(args: Args) -> dict:
    """Run A3C; returns the summary. Raises UsageError for a bad checkpoint and RuntimeError
    when a worker or the evaluator dies."""
    torch.set_num_threads(1)  # before any torch op, so that forking the workers is safe
    checkpoint = load_checkpoint(args.resume) if args.resume else None
    run_name = f"{args.env}__{args.exp_name}__{args.seed}__{int(time.time())}"
    if args.run_dir:
        run_dir = Path(args.run_dir)
    elif checkpoint is not None:
        run_dir = Path(args.resume).resolve().parent
    else:
        run_dir = Path(args.runs_root) / run_name
    run_dir.mkdir(parents=True, exist_ok=True)
    checkpoint_path = run_dir / "checkpoint.pt"

    seed_everything(args.seed)
    probe = make_env(args.env)
    num_actions = probe.action_space.n
    probe.close()
    ctx = mp.get_context("fork")  # fast start, and works when this file is loaded by path
    shared = Shared(args, num_actions, ctx)
    if checkpoint is not None:
        restore(shared, checkpoint, args, args.resume)
    start_step = shared.global_step()

    stop_signal: list[str] = []
    previous_handlers = {
        s: signal.signal(s, lambda signum, _: stop_signal.append(signal.Signals(signum).name))
        for s in (signal.SIGINT, signal.SIGTERM)
    }
    processes = {
        f"worker {i}": ctx.Process(
            target=run_process,
            args=(f"worker {i}", shared, worker, i, shared, args, os.getpid()),
            daemon=True,
        )
        for i in range(args.num_workers)
    }
    processes["evaluator"] = ctx.Process(
        target=run_process,
        args=("evaluator", shared, evaluator, shared, args, str(run_dir), os.getpid()),
        daemon=True,
    )
    for process in processes.values():
        process.start()
    workers = [p for name, p in processes.items() if name != "evaluator"]
    print(f"run {run_name} -> {run_dir}", flush=True)
    print("pids: " + ", ".join(f"{n} {p.pid}" for n, p in processes.items()), flush=True)
    # after the fork: the TensorBoard writer thread must not be forked
    log = RunLog(run_dir, args, checkpoint["wall_time"] if checkpoint else 0.0)

    failure = outcome = None
    steady_start = None  # (time, step) once every worker is ready, for the SPS
    last_log = (time.time(), start_step, shared.stats.clone())
    next_checkpoint = (start_step // args.checkpoint_interval + 1) * args.checkpoint_interval
    try:
        while outcome is None and failure is None:
            time.sleep(0.1)
            # exit codes before the step: a worker that ended normally saw step >= T_max
            exitcodes = {name: p.exitcode for name, p in processes.items()}
            now, global_step = time.time(), shared.global_step()
            if steady_start is None and bool(shared.ready.all()):
                steady_start = (now, global_step)
            while not shared.errors.empty():
                name, trace = shared.errors.get()
                failure = f"{name} failed:\n{trace}"
            while not shared.evaluations.empty():
                log.evaluation(shared.evaluations.get())
            if stop_signal:
                outcome = f"stopped by {stop_signal[0]}"
                break
            for name, code in exitcodes.items():
                # exit 0 is only expected of a worker that reached T_max
                early = name == "evaluator" or global_step < args.total_timesteps
                if failure is None and code is not None and (code != 0 or early):
                    failure = f"{name} (pid {processes[name].pid}) {describe_exit(code)}"
            if failure is None and all(p.exitcode == 0 for p in workers):
                outcome = "done"
            elif args.time_limit is not None and now - log.start >= args.time_limit:
                outcome = "time limit"
            if global_step >= next_checkpoint:
                save_checkpoint(checkpoint_path, shared, args, log.wall_time())
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
        shared.stop.set()  # the workers finish their rollout and exit
        if outcome not in ("done", "time limit") or failure is not None:
            shared.stop_evaluator.set()
        deadline = time.time() + 10
        for name, process in processes.items():
            if name != "evaluator" or shared.stop_evaluator.is_set():
                process.join(max(0.1, deadline - time.time()))
                if process.is_alive():
                    process.terminate()
                    process.join(1)
    end_time = time.time()
    global_step = shared.global_step()

    if failure is None:
        save_checkpoint(checkpoint_path, shared, args, log.wall_time())
        if outcome in ("done", "time limit"):
            # the final evaluation, of the network after the last update
            shared.final_eval.set()
            evaluator_process = processes["evaluator"]
            while evaluator_process.is_alive() and not stop_signal:
                evaluator_process.join(0.1)
                while not shared.evaluations.empty():
                    log.evaluation(shared.evaluations.get())
            if stop_signal:
                evaluator_process.terminate()
                outcome = f"stopped by {stop_signal[0]} in the final evaluation"
            elif evaluator_process.exitcode != 0:
                failure = f"evaluator {describe_exit(evaluator_process.exitcode)}"
            while not shared.evaluations.empty():
                log.evaluation(shared.evaluations.get())
    while not shared.errors.empty():
        name, trace = shared.errors.get()
        failure = f"{failure or name + ' failed'}:\n{trace}"
    for s, handler in previous_handlers.items():
        signal.signal(s, handler)
    log.close()
    if failure is not None:
        raise RuntimeError(failure)

    start_time, start_of_sps = steady_start or (log.start, start_step)
    sps = (global_step - start_of_sps) / max(end_time - start_time, 1e-9)
    last = log.last_eval
    summary = {
        "outcome": outcome,
        "run_dir": str(run_dir),
        "global_step": global_step,
        "final_eval": last["mean_return"] if last else float("nan"),
        "final_eval_step": last["global_step"] if last else None,
        "wall_time_s": end_time - log.start,
        "sps": sps,
    }
    eval_text = (
        f"final eval {last['mean_return']:.3f} at step {last['global_step']:,}"
        if last
        else "no evaluation"
    )
    print(
        f"{outcome}: {eval_text} | wall time {format_seconds(summary['wall_time_s'])} | "
        f"SPS {sps:,.0f} | {global_step:,} steps | {run_dir}",
        flush=True,
    )
    return summary


def evaluate(args: Args) -> np.ndarray:
    """Play episodes with a checkpoint's network, print each score and the mean."""
    checkpoint = load_checkpoint(args.evaluate)
    try:
        trained = Args(**checkpoint["args"])
    except TypeError as e:
        raise UsageError(
            f"checkpoint {args.evaluate!r} has other flags than this script: {e}"
        ) from e
    seed_everything(args.seed)
    video_dir = os.path.join(os.path.dirname(args.evaluate), "videos-evaluate")
    env = make_env(
        trained.env,
        render_mode="human" if args.render == "human" else None,
        video_dir=video_dir if args.capture_video else None,
    )
    model = ActorCritic(env.action_space.n, trained)
    try:
        model.load_state_dict(checkpoint["model"])
    except RuntimeError as e:
        raise UsageError(f"checkpoint {args.evaluate!r} does not fit this network: {e}") from e
    scores = []
    for episode in range(args.eval_episodes):
        seed = args.seed + episode
        scores.append(play_episodes(model, [env], [seed])[0])
        print(f"episode {episode + 1}: score {scores[-1]:g}", flush=True)
    env.close()
    print(
        f"{trained.env}, step {checkpoint['global_step']:,}: mean score {np.mean(scores):.3f} "
        f"+- {np.std(scores):.3f} over {len(scores)} episodes",
        flush=True,
    )
    return np.asarray(scores)


def main() -> int:
    args = tyro.cli(Args)
    import catch_env  # noqa: F401  (registers Catch-v0 and the ALE ids)

    try:
        if args.evaluate:
            evaluate(args)
            return 0
        train(resolve_defaults(args))
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
