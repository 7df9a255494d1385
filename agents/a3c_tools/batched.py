"""The batched backend of the sweep (`python -m a3c_tools.sweep ... --backend batched`): N
single-worker runs of a thesis script as one batched program on one device (a GPU, or the CPU),
in the manner of PureJaxRL's vmapped training.

Run i is the script's own one-worker run (`--num-workers 1`) with its seed and flags: the same
initial network (built by the script's class after seeding with the run's --seed), the same env
(Catch-v0 in torch, a3c_tools.torch_catch, seeded as the worker seeds its NumPy env), the same
action draws (the worker's NumPy generator, its uniforms drawn in blocks and uploaded), the same
rollouts, n-step returns (the script's `n_step_returns`, the runs as its K columns), loss (the
script's `a3c_loss`), gradient clipping, RMSprop statistics and annealed learning rate, and the
same evaluations (the runtime's `evaluate_network`: 50 episodes every --eval-interval steps with
the run's episode seeds). The N networks are the script's `ActorCritic`, their parameters stacked
(torch.func.stack_module_state) and called through torch.func.functional_call under vmap, the
gradients by vmap(grad(loss)). tests/test_batched.py checks that run i takes the script's actions
with its parameters to float tolerance. Only the order of floating-point sums differs. And a run
is the same run in any batch: on the CPU its checkpoint and evaluations are bit for bit the same
alone or beside any other runs (tests/test_batched_invariance.py), a run alone computing beside
a copy of itself (vmap over one run takes other kernels than over two or more), so a sweep's
restart may regroup its runs as it finds them.

Each run's folder gets what the process backend writes, written by the runtime's own code: its
lock (a3c_runtime.run_folder, taken before anything in the folder is read or changed, so a run
in use elsewhere, resumed by hand, is left alone and the sweep says "in use", as it does on the
process backend), evaluations.csv (the same rows) and TensorBoard's scalars (the eval/, charts/
and losses/ ones, every --log-interval seconds) through a3c_runtime.run_log.RunLog, a sealed
checkpoint.pt in the safe format at each --checkpoint-interval and at the end (with the worker's
generator, env and frames, so the script's own --resume continues it exactly), stdout.log with
the run's progress lines and closing line; the sweep writes results.csv. Stopped (Ctrl-C,
SIGTERM), every run is checkpointed at its last update, its closing line naming the signal, and
the next start of the sweep resumes them from those checkpoints. On CUDA the batch computes in
fp32 without TF32, with cuDNN's deterministic algorithms (`set_up_device`).

The runs of a batch act in lockstep: their rollouts end where their episodes end, together.
Every game of Catch lasts 15 steps, so runs at one step of their episodes stay together;
`run_batched` batches the runs that resume from the same global step with their balls on the
same row (`episode_row`: runs at one global step may be at different steps of their episodes,
one resumed by hand with more workers for a while), and a batch built otherwise is refused
when it is built.

What it batches: the scripts of BATCHED_SCRIPTS (FF, LSTM, LWS, SS, WW, LPQ, GLPQ) on Catch-v0
with one worker and one env per run, RMSprop, fp32; runs that differ only in PER_RUN_FLAGS. An
LSTM run carries its recurrent state across rollouts as its worker does (zeroed where an
episode ends, the learning pass replaying the rollout from its start state), and its
evaluation a state per episode as the runtime's does.
Anything else is refused in one line before anything runs (`batch_problem`, and `probe`: one
update of the network under vmap).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import os
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from a3c_runtime import (
    Checkpoint,
    RMSprop,
    RunLog,
    Shared,
    UsageError,
    WriteFailed,
    annealed_lr,
    clip_stacked,
    load_checkpoint,
    process_seed,
    save_checkpoint,
    seed_everything,
)
from a3c_runtime.evaluation import evaluation_randomness
from a3c_runtime.run_folder import LOCK_FILE, RunFolder
from a3c_runtime.run_log import logged_steps
from a3c_runtime.snapshots import arrays_of, next_mark, saved_state
from torch.func import functional_call, grad, stack_module_state, vmap

from a3c_tools.torch_catch import NumpyStateView, TorchCatchVectorEnv
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
UNIFORM_BLOCK = 256  # action uniforms drawn per run at a time
STAT_INDEX = {name: i for i, name in enumerate(Shared.STATS)}  # a worker's running totals
FILES_PER_RUN = 4  # held open by a batch: the folder's lock, evaluations.csv, events, stdout.log


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


# ------------------------------------------------------------------------------------------------
# The pieces of the worker's update, for N runs at once
# ------------------------------------------------------------------------------------------------
def network_frames(frames: torch.Tensor) -> torch.Tensor:
    """uint8 frames (..., 4, 84, 84) as float32 with each frame stack channels-last: the layout
    the scripts' networks convert their input to, so that their `obs.to(float32,
    channels_last)` is a no-op under vmap (which cannot change a layout)."""
    return frames.movedim(-3, -1).contiguous().float().movedim(-1, -3)


def sample_actions(log_probs: torch.Tensor, uniforms: torch.Tensor) -> torch.Tensor:
    """The worker's inverse-CDF sampling (a3c_ff.sample_actions) on the device, with the same
    float32 cumulative sums compared in float64 as NumPy compares them: for the same
    probabilities and uniforms, the same actions."""
    probs = log_probs.float().exp()
    cdf = probs.cumsum(dim=1)
    below = cdf.double() <= uniforms[:, None] * cdf[:, -1:].double()
    return below.sum(dim=1).clamp(max=probs.shape[1] - 1)


def lstm_cell(cell: torch.nn.LSTMCell, x: torch.Tensor, state: tuple) -> tuple:
    """nn.LSTMCell's step, torch's own formula (ATen's lstm_cell: gates = W_ih x + b_ih + W_hh h
    + b_hh, split i, f, g, o; c' = sigma(f) c + sigma(i) tanh(g); h' = sigma(o) tanh(c')) in ops
    that vmap batches: aten::lstm_cell has no batching rule. The same values to float
    rounding."""
    h, c = state
    gates = F.linear(x, cell.weight_ih, cell.bias_ih) + F.linear(h, cell.weight_hh, cell.bias_hh)
    i, f, g, o = gates.chunk(4, dim=-1)
    c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
    return torch.sigmoid(o) * torch.tanh(c), c


def vmappable(network: torch.nn.Module) -> torch.nn.Module:
    """The network with each nn.LSTMCell stepping through `lstm_cell` (its parameters, by the
    same names, are still the ones functional_call substitutes)."""
    for module in network.modules():
        if isinstance(module, torch.nn.LSTMCell):
            module.forward = functools.partial(lstm_cell, module)
    return network


class ActionUniforms:
    """Each run's worker generator (np.random.default_rng(its process seed)), drawn in blocks:
    the k-th uniform of a block is the k-th `rng.random(1)` the worker would draw. `generator(i)`
    is run i's generator where the worker's would be now, for its checkpoint."""

    def __init__(self, rngs: list[np.random.Generator], device: torch.device):
        self.rngs, self.device = rngs, device
        self.block_states: list[dict] = []
        self.block = torch.empty(0)
        self.used = UNIFORM_BLOCK

    def next(self) -> torch.Tensor:
        if self.used == UNIFORM_BLOCK:
            self.block_states = [rng.bit_generator.state for rng in self.rngs]
            draws = np.stack([rng.random(UNIFORM_BLOCK) for rng in self.rngs], axis=1)
            self.block = torch.as_tensor(draws, device=self.device)
            self.used = 0
        self.used += 1
        return self.block[self.used - 1]

    def generator(self, i: int) -> np.random.Generator:
        if not self.block_states:
            return copy.deepcopy(self.rngs[i])
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = self.block_states[i]
        rng.random(self.used)
        return rng


# ------------------------------------------------------------------------------------------------
# The runs
# ------------------------------------------------------------------------------------------------
@dataclass
class BatchedRun:
    """One run of a batch: its resolved Args (run_dir set), what it resumes from, and its run
    folder, locked (a3c_runtime.run_folder) by the caller that read the checkpoint in it; None:
    train_batched locks it."""

    args: Any
    checkpoint: Checkpoint | None = None
    folder: RunFolder | None = None


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
    env_state = arrays_of(checkpoint.workers[0][1]["env"])  # as BatchedA3C.restore reads it
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


def allow_open_files(count: int) -> None:
    """Raise this process's soft limit of open files to `count` where it is lower (up to the
    hard limit): a batch holds FILES_PER_RUN files per run open, past the common soft limit of
    1,024 at a few hundred runs."""
    try:
        import resource
    except ImportError:  # (not POSIX)
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= count:
        return
    wanted = count if hard == resource.RLIM_INFINITY else min(count, hard)
    if wanted > soft:
        resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))


class BatchedA3C:
    """N one-worker runs of a script of BATCHED_SCRIPTS in lockstep (the module docstring)."""

    def __init__(self, module: ModuleType, runs: list[BatchedRun], device: str | torch.device):
        self.module, self.agent, self.device = module, module.AGENT, torch.device(device)
        # A run alone computes as a batch of two, beside a copy of itself whose results are
        # dropped: vmap over one run takes other kernels than over two or more (a grouped
        # convolution's weight gradient, a matrix-vector product), which part in the last bits,
        # and a run must be the same run in any batch (tests/test_batched_invariance.py)
        self.shown = len(runs)
        if len(runs) == 1:
            runs = [runs[0], dataclasses.replace(runs[0], folder=None)]
        self.runs = runs
        self.args = [run.args for run in runs]
        first = self.args[0]
        self.total, self.t_max = first.total_timesteps, first.t_max
        n = len(runs)
        models, self.rngs, seeds = [], [], []
        for args in self.args:
            seed_everything(args.seed)  # as a3c_runtime.train builds the run's network
            models.append(self.agent.build_network(3, args))
            seeds.append(process_seed(args.seed, 0))  # the worker's seed
            self.rngs.append(np.random.default_rng(seeds[-1]))
        self.cpu_model = models[0]  # the evaluations' and checkpoints' network
        self.base = vmappable(copy.deepcopy(models[0]).to(self.device))
        params, buffers = stack_module_state(models)
        self.names = list(params)
        self.params = [params[k].detach().to(self.device) for k in self.names]
        # buffers stacked too: LWS's fixed centroids are drawn from each run's seed
        self.buffers = {k: b.to(self.device) for k, b in buffers.items()}
        self.saved_names = list(models[0].state_dict())  # what a checkpoint's model holds
        self.optimizer = RMSprop(
            self.params, first.rms_decay, first.optim_eps, first.rms_init, shared=False
        )  # the runtime's, a learning rate per run
        self.envs = TorchCatchVectorEnv(n, self.device)
        self.envs.reset(seed=seeds)
        # LSTM: the state each run's worker carries across rollouts, (N, 1, cells) each; () for
        # a feed-forward network
        self.state: tuple[torch.Tensor, ...] = ()
        if hasattr(self.base, "initial_state"):
            self.state = tuple(s.expand(n, *s.shape).clone().to(self.device)
                               for s in models[0].initial_state(1))  # fmt: skip
        self.step_count = 0
        self.wall_offsets = [0.0] * n
        if runs[0].checkpoint is not None:
            self.restore([run.checkpoint for run in runs])
        rows = set(self.envs.ball_row.tolist())
        if len(rows) > 1:  # (run_batched batches runs by their ball's row)
            raise ValueError(f"a batch's runs must be at the same step of their episodes (their "
                             f"balls on one row); these are on rows {sorted(rows)}")  # fmt: skip
        self.uniforms = ActionUniforms(self.rngs, self.device)
        self.eval_envs: TorchCatchVectorEnv | None = None
        # each run's running totals of Shared.STATS (RunLog's scalars), added to on the device
        self.stats = torch.zeros((n, len(Shared.STATS)), dtype=torch.float64, device=self.device)

    def restore(self, checkpoints: list[Checkpoint]) -> None:
        """Every run from its checkpoint (all at the same step): theta, the RMSprop statistics,
        the worker's generator, env and frames."""
        steps = {c.global_step for c in checkpoints}
        assert len(steps) == 1, "a batch resumes from one step"
        self.step_count = steps.pop()
        with torch.no_grad():
            for i, checkpoint in enumerate(checkpoints):
                for j, name in enumerate(self.names):
                    self.params[j][i] = checkpoint.model[name].to(self.device)
                    square_avg = checkpoint.optimizer["square_avg"][j]
                    self.optimizer.square_avg[j][i] = square_avg.to(self.device)
                for name, stacked in self.buffers.items():
                    if name in checkpoint.model:  # (LWS's fixed centroids)
                        stacked[i] = checkpoint.model[name].to(self.device)
                rng_state, env_state, _, *carried = checkpoint.workers[0]
                for stacked, saved in zip(self.state, carried[0] if carried else (), strict=True):
                    stacked[i] = saved.to(self.device)  # (LSTM: its carried state)
                self.rngs[i].bit_generator.state = rng_state["bit_generator"]
                self.envs.set_numpy_state(i, arrays_of(env_state["env"]))
                self.wall_offsets[i] = checkpoint.wall_time

    def set_progress(self) -> None:
        """GLPQ's tau schedule at this step, as its worker and evaluator set it (T / T_max, the
        same in every run), and the 1/tau its loss correction takes."""
        if hasattr(self.base, "set_progress"):
            self.base.set_progress(self.step_count / self.total)
        scale = getattr(self.base, "policy_loss_scale", None)
        self.loss_scale = scale() if scale is not None else 1.0

    def forward(
        self, params: list[torch.Tensor], buffers: dict, frames: torch.Tensor, state: tuple
    ) -> Any:
        """One run's network: log-probs and values of frames (B, 4, 84, 84); an LSTM's of
        frames (T, B, 4, 84, 84) from its state (h, c), and the state after them."""
        weights = {**dict(zip(self.names, params, strict=True)), **buffers}
        return functional_call(self.base, weights, (frames, state) if state else (frames,))

    def act(self, frames: torch.Tensor, state: tuple = ()) -> tuple:
        """Every run's forward of one step's frames (N, B, 4, 84, 84) without gradients: its
        log-probs (N, B, A), values (N, B) and (LSTM) the state after the step. In grad mode,
        though nothing requires a gradient (so no graph is built): acting shortcuts that compare
        data, as LWS's cache of its similarity weights (torch.equal), are taken only without
        it, and vmap cannot batch them; the values are the same."""
        with torch.enable_grad():
            if not state:
                return (*vmap(self.forward)(self.params, self.buffers, frames, ()), ())
            log_probs, values, state = vmap(self.forward)(
                self.params, self.buffers, frames[:, None], state
            )  # LSTM: T = 1
            return log_probs[:, 0], values[:, 0], state

    def loss(self, params, buffers, frames, actions, returns, state):
        a = self.args[0]
        if state:  # LSTM: the rollout (T = n, B = 1) replayed through time from its start state
            log_probs, values, _ = self.forward(params, buffers, frames, state)
            log_probs, values = log_probs.flatten(0, 1), values.flatten(0, 1)
        else:
            log_probs, values = self.forward(params, buffers, frames, ())
        loss, policy_loss, value_loss, entropy = self.module.a3c_loss(
            log_probs, actions, values, returns, a.ent_coef, a.vf_coef, a.value_loss_form
        )
        if hasattr(self.module, "tau_corrected_loss"):  # GLPQ: the policy loss times 1/tau
            loss = self.module.tau_corrected_loss(loss, policy_loss, entropy, self.loss_scale, a)
        return loss, (policy_loss, value_loss, entropy)

    def update(self) -> int:
        """One rollout of up to t_max steps in every run, and its update; returns its steps."""
        a, n_runs, envs = self.args[0], len(self.runs), self.envs
        self.set_progress()
        frames = torch.empty((self.t_max + 1, n_runs, 4, 84, 84), dtype=torch.uint8,
                             device=self.device)  # fmt: skip
        frames[0] = envs.stack
        actions = torch.zeros((self.t_max, n_runs), dtype=torch.int64, device=self.device)
        rewards = torch.zeros((self.t_max, n_runs), dtype=torch.float32, device=self.device)
        dones = np.zeros((self.t_max, n_runs), dtype=bool)
        rollout_state = tuple(s.clone() for s in self.state)  # (LSTM: the rollout's start)
        with torch.no_grad():
            for t in range(self.t_max):
                log_probs, _, self.state = self.act(network_frames(frames[t][:, None]), self.state)
                actions[t] = sample_actions(log_probs[:, 0], self.uniforms.next())
                obs, rewards[t], _, ended = envs.step(actions[t])
                frames[t + 1] = obs
                if ended.any():
                    # the runs' balls started on one row (checked in __init__) and fall a row per
                    # step: their episodes end together
                    if not ended.all():
                        raise RuntimeError("the runs' episodes ended at different steps")
                    dones[t] = True
                    self.add_stats(episodes=1.0, return_sum=envs.final_returns,
                                   length_sum=envs.final_lengths)  # fmt: skip
                    # LSTM: the next episode starts from the zero state
                    self.state = tuple(torch.zeros_like(s) for s in self.state)
                    break
            n = t + 1
            bootstrap = np.zeros(n_runs, dtype=np.float32)
            if not dones[n - 1].all():  # V(s_n), as the worker's learning pass computes it
                bootstrap = self.act(network_frames(frames[n][:, None]), self.state)[1][:, 0]
                bootstrap = bootstrap.float().cpu().numpy()
        done_values = np.zeros((n, n_runs), dtype=np.float32)  # (Catch never truncates)
        returns = self.module.n_step_returns(
            rewards[:n].cpu().numpy(), dones[:n], done_values, bootstrap, a.gamma
        )
        rollout = frames[:n].transpose(0, 1)  # (N, n, 4, 84, 84)
        if self.state:
            rollout = rollout[:, :, None]  # LSTM: (N, T = n, B = 1, 4, 84, 84)
        grads, (policy_loss, value_loss, entropy) = vmap(grad(self.loss, has_aux=True))(
            self.params,
            self.buffers,
            network_frames(rollout),
            actions[:n].T.contiguous(),
            torch.as_tensor(returns.T.copy(), device=self.device),
            rollout_state,
        )
        self.last_actions = actions[:n].T  # (N, n), for the equivalence tests
        grad_norm = clip_stacked(grads, a.grad_clip_mode, a.grad_clip)
        lrs = [annealed_lr(args, self.step_count) for args in self.args]
        self.optimizer.step(grads, torch.tensor(lrs, dtype=torch.float32, device=self.device))
        self.step_count += n
        self.add_stats(updates=1.0, policy_loss=policy_loss, value_loss=value_loss,
                       entropy=entropy, grad_norm=grad_norm)  # fmt: skip
        return n

    def add_stats(self, **totals: float | torch.Tensor) -> None:
        """Add to every run's running totals, by name, as a worker adds to its WorkerStats: a
        number for all runs or a tensor (N,) of each run's."""
        for name, value in totals.items():
            self.stats[:, STAT_INDEX[name]] += value

    # -- evaluations and checkpoints, per run ----------------------------------------------
    def network(self, i: int) -> dict[str, torch.Tensor]:
        """Run i's state dict: its parameters and persistent buffers (LWS's fixed centroids)."""
        stacked = {**dict(zip(self.names, self.params, strict=True)), **self.buffers}
        return {name: stacked[name][i].detach().cpu().clone() for name in self.saved_names}

    def evaluate(self) -> list[dict]:
        """Every run's evaluation of the thesis protocol at this step, as the runtime's
        `evaluate_network` plays it (its episode seeds, and its actions drawn by
        torch.multinomial with its generator from the same keys), the runs' episodes on one
        TorchCatchVectorEnv of N x --eval-episodes games and their networks in one vmapped
        forward per step; only each run's draws are made on the host, from its probabilities."""
        start, n, episodes = time.time(), len(self.runs), self.args[0].eval_episodes
        self.set_progress()
        seeds, generators = [], []
        for args in self.args:  # evaluate_network's keys
            run_seeds, generator = evaluation_randomness(args.seed, self.step_count, episodes)
            seeds, generators = seeds + run_seeds, [*generators, generator]
        if self.eval_envs is None or self.eval_envs.num_envs != n * episodes:
            self.eval_envs = TorchCatchVectorEnv(n * episodes, self.device)
        obs = self.eval_envs.reset(seed=seeds)
        greedy = torch.tensor([args.eval_greedy for args in self.args], device=self.device)
        # LSTM: a zero state per episode, as evaluate_network starts each
        state = tuple(s.new_zeros(n, episodes, s.shape[-1]) for s in self.state)
        with torch.no_grad():  # (not inference mode: the env's tensors are updated outside it)
            while True:
                frames = network_frames(obs.view(n, episodes, *obs.shape[1:]))
                log_probs, _, state = self.act(frames, state)
                probs = log_probs.exp().cpu()
                drawn = torch.stack([torch.multinomial(probs[i], 1, generator=generator)[:, 0]
                                     for i, generator in enumerate(generators)])  # fmt: skip
                actions = torch.where(greedy[:, None], log_probs.argmax(-1), drawn.to(self.device))
                obs, _, _, ended = self.eval_envs.step(actions.flatten())
                if ended.any():  # Catch's games all end at their 15th step
                    break
        scores = self.eval_envs.final_returns.view(n, episodes).cpu().numpy()
        seconds = (time.time() - start) / n
        return [{"global_step": self.step_count, "scores": scores[i].tolist(), "seconds": seconds}
                for i in range(self.shown)]  # fmt: skip

    def worker_state(self, i: int) -> tuple:
        """Run i's worker as its script's `worker_state()` gives it to a checkpoint: its
        generator, env and frames (and an LSTM's carried state)."""
        parts = (self.uniforms.generator(i), NumpyStateView(self.envs, i),
                 self.envs.stack[i : i + 1].cpu().numpy())  # fmt: skip
        if self.state:
            parts += (tuple(s[i].cpu().clone() for s in self.state),)
        return parts

    def checkpoint(self, i: int, run_dir: Path, wall_time: float) -> None:
        snapshot = {
            "model": self.network(i),
            "optimizer": {"square_avg": [s[i].cpu().clone() for s in self.optimizer.square_avg]},
            "global_step": self.step_count,
            "workers": {0: saved_state(self.worker_state(i))},
            "pending_evaluations": [],
        }
        shared = SimpleNamespace(model=self.cpu_model, global_step=lambda: self.step_count)
        save_checkpoint(run_dir / "checkpoint.pt", shared, self.args[i], wall_time,
                        self.agent.script, snapshot)  # fmt: skip


def set_up_device(device: str) -> None:
    """torch's settings for a batch on this device (the benchmarks' too, so that they time what
    the backend computes)."""
    if device == "cuda":  # fp32 as the scripts compute it: no TF32 convolutions or matmuls
        torch.backends.cudnn.allow_tf32 = False
        torch.backends.cuda.matmul.allow_tf32 = False
        # and the same run twice the same: cuDNN's deterministic algorithms, none picked by
        # timing (benchmark mode may pick another, nondeterministic one in each process)
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False
    else:  # one core, as one process-backend run uses (and no oversubscribed threads)
        torch.set_num_threads(1)


def train_batched(
    module: ModuleType,
    runs: list[BatchedRun],
    device: str = "cpu",
    should_stop: Callable[[], str | None] = lambda: None,
    log_interval: float = 30.0,
) -> list[dict]:
    """Train the runs as one batch to their --total-timesteps, writing each run's folder
    through the runtime's RunLog (evaluations.csv, TensorBoard scalars, progress lines in
    stdout.log) with the folder locked; returns each run's outcome (for the sweep's table):
    "done" or "stopped by <signal>" and its wall time. should_stop() names the signal that
    stops the batch ("SIGINT", "SIGTERM"), or None: a stop checkpoints every run at its last
    update. log_interval: seconds between the batch's console lines."""
    set_up_device(device)
    batch = BatchedA3C(module, runs, device)  # (refuses runs it cannot batch: nothing written)
    start_step = batch.step_count
    allow_open_files(FILES_PER_RUN * len(runs) + 256)
    folders, locked, logs, consoles = [], [], [], []
    try:
        for run in runs:  # the runtime's lock, taken here where the caller took none
            folder = run.folder
            if folder is None:
                folder = RunFolder(Path(run.args.run_dir))
                locked.append(folder)
            folders.append(folder)
        for i, (run, folder) in enumerate(zip(runs, folders, strict=True)):
            consoles.append(open(folder.path / "stdout.log", "a"))  # noqa: SIM115 (closed below)
            logs.append(RunLog(folder.path, run.args, batch.wall_offsets[i],
                               resumed_step=start_step, console=consoles[-1]))  # fmt: skip
        outcomes = train_logged(batch, [f.path for f in folders], logs, should_stop, log_interval)
        for log in logs:
            log.close()
        for console, outcome in zip(consoles, outcomes, strict=True):
            console.write(outcome["stdout"] + "\n")
        return outcomes
    except BaseException:
        for log in logs:
            log.close(quietly=True)
        raise
    finally:
        for console in consoles:
            console.close()
        for folder in locked:
            folder.close()


def train_logged(
    batch: BatchedA3C,
    run_dirs: list[Path],
    logs: list[RunLog],
    should_stop: Callable[[], str | None],
    log_interval: float,
) -> list[dict]:
    """train_batched's loop, each run's folder locked and its RunLog open."""
    a, start_step = batch.args[0], batch.step_count
    eval_mark, checkpoint_mark = (
        next_mark(start_step, a.eval_interval),
        next_mark(start_step, a.checkpoint_interval),
    )
    # (a resumed run's evaluation of its checkpoint's step may be logged already)
    logged = [logged_steps(log.csv_path, start_step) for log in logs]

    def evaluate_all() -> None:
        if all(batch.step_count in steps for steps in logged):
            return
        for log, steps, result in zip(logs, logged, batch.evaluate(), strict=True):
            if batch.step_count not in steps:
                log.evaluation(result)
                steps.add(batch.step_count)

    def checkpoint_all() -> None:
        for i, (run_dir, log) in enumerate(zip(run_dirs, logs, strict=True)):
            batch.checkpoint(i, run_dir, log.wall_time())

    if start_step == 0:
        evaluate_all()  # the untrained network's, as every run's first row
    last_log = last_progress = (time.time(), start_step)
    stats = batch.stats.to("cpu", copy=True)  # (a copy on the CPU too: the totals grow)
    stopped_by = None
    while batch.step_count < batch.total:
        stopped_by = should_stop()
        if stopped_by:
            break
        batch.update()
        step = batch.step_count
        if step >= eval_mark:
            if step < batch.total:  # the evaluation at T_max is the final one, below
                evaluate_all()
            eval_mark = next_mark(step, a.eval_interval)
        if step >= checkpoint_mark:
            checkpoint_all()
            checkpoint_mark = next_mark(step, a.checkpoint_interval)
        now = time.time()
        if now - last_progress[0] >= a.log_interval:  # each run's scalars, as a run logs them
            sps = (step - last_progress[1]) / (now - last_progress[0])
            new_stats = batch.stats.to("cpu", copy=True)
            for i, log in enumerate(logs):
                lr = annealed_lr(batch.args[i], step)
                log.progress(step, sps, lr, new_stats[i] - stats[i])
            last_progress, stats = (now, step), new_stats
        if now - last_log[0] >= log_interval:
            sps = (step - last_log[1]) * len(logs) / (now - last_log[0])
            print(f"batched: {len(logs)} runs at step {step:,}/{batch.total:,} | "
                  f"{sps:,.0f} run-steps/s", flush=True)  # fmt: skip
            last_log = (now, step)
    checkpoint_all()  # every run's last checkpoint, as a run's last
    if not stopped_by:
        evaluate_all()
    outcomes = []
    for run_dir, log in zip(run_dirs, logs, strict=True):
        last = log.last_eval or {"global_step": batch.step_count, "mean_return": float("nan")}
        step, score = last["global_step"], last["mean_return"]  # (a resumed run's last row too)
        label = "last eval" if stopped_by else "final eval"
        outcome = f"stopped by {stopped_by}" if stopped_by else "done"
        line = (f"{outcome}: {label} {score:.3f} at step {step:,} | batched with "
                f"{len(logs)} runs | {batch.step_count:,} steps | {run_dir}")  # fmt: skip
        outcomes.append({"outcome": outcome, "wall_time_s": log.wall_time(), "stdout": line})
    return outcomes


# ------------------------------------------------------------------------------------------------
# The sweep's batched backend
# ------------------------------------------------------------------------------------------------
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
