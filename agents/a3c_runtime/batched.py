"""N one-worker runs of a thesis script as one program on one device (a GPU, or the CPU), in the
manner of PureJaxRL's vmapped training: the sweep's `--backend batched` (a3c_tools.batched).

Run i is the script's own one-worker run (`--num-workers 1`) with its seed and flags, and a run
is the same run in any batch (tests/test_batched.py, tests/test_batched_invariance.py). What a
run does is the code the worker and the runtime run: the script's network, `n_step_returns`,
`a3c_loss` (and GLPQ's `tau_corrected_loss`); the runtime's `sample_actions`, `clip_stacked`,
`RMSprop` and `annealed_lr`; its evaluations are the runtime's `evaluate_network` of the run's
network, its marks the runtime's `MarkClock`, its logs `RunLog`, its checkpoints and worker
state `save_checkpoint`, `saved_state` and `restored_state`. What is only this module's is the
stacking: the N networks' parameters stacked (torch.func.stack_module_state) and called under
vmap, the gradients by vmap(grad(loss)); each run's generator drawn in blocks
(`ActionUniforms`); the runs' games on one torch Catch (catch_env.torch_catch) in lockstep
(every game of Catch lasts 15 steps: the runs of a batch start with their balls on one row,
checked here); and the loop that evaluates, checkpoints and logs each run at its marks.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import torch
from torch.func import functional_call, grad, stack_module_state, vmap

from catch_env.torch_catch import NumpyStateView, TorchCatchVectorEnv

from .batchable import batch_problem
from .checkpoints import Checkpoint, restore, save_checkpoint
from .evaluation import evaluate_network, make_eval_envs
from .flags import UsageError, autocast_contexts
from .hogwild import (
    RMSprop,
    WorkerStats,
    annealed_lr,
    clip_stacked,
    process_seed,
    sample_actions,
    seed_everything,
)
from .run_folder import RunFolder
from .run_log import RunLog, logged_steps, summarize
from .snapshots import MarkClock, restored_state, saved_state
from .stacked_convs import matmul_convs

UNIFORM_BLOCK = 256  # action uniforms drawn per run at a time
FILES_PER_RUN = 4  # held open by a batch: the folder's lock, evaluations.csv, events, stdout.log
# how the stacked runs' convolutions are computed: "grouped", torch's convolution under vmap (a
# grouped convolution, the runs its groups), the default; "matmul", a3c_runtime.stacked_convs
# (one bmm for all runs, where cuDNN runs a grouped convolution as a kernel per run), slower on
# the CPU and unmeasured on a GPU (results/batched_throughput): an option until it earns its place
CONV_FORMS = ("grouped", "matmul")


def network_frames(frames: torch.Tensor) -> torch.Tensor:
    """uint8 frames (..., 4, 84, 84) as float32, each stack channels-last: the layout the
    scripts' networks convert their input to, so that it is a no-op under vmap (which cannot
    change a layout)."""
    return frames.movedim(-3, -1).contiguous().float().movedim(-1, -3)


class ActionUniforms:
    """Each run's worker generator (np.random.default_rng(its process seed)) drawn in blocks: the
    k-th uniform of a block is the k-th `rng.random(1)` the worker would draw. `generator(i)`
    is run i's generator where the worker's would be now, for its checkpoint."""

    def __init__(self, rngs: list[np.random.Generator], device: torch.device):
        self.rngs, self.device = rngs, device
        self.block_states: list[dict] = []
        self.block, self.used = torch.empty(0), UNIFORM_BLOCK

    def next(self) -> torch.Tensor:
        if self.used == UNIFORM_BLOCK:
            self.block_states = [rng.bit_generator.state for rng in self.rngs]
            draws = np.stack([rng.random(UNIFORM_BLOCK) for rng in self.rngs], axis=1)
            self.block, self.used = torch.as_tensor(draws, device=self.device), 0
        self.used += 1
        return self.block[self.used - 1]

    def generator(self, i: int) -> np.random.Generator:
        if not self.block_states:
            return copy.deepcopy(self.rngs[i])
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = self.block_states[i]
        rng.random(self.used)
        return rng


@dataclass
class BatchedRun:
    """One run of a batch: its resolved Args (run_dir set), the checkpoint it resumes from, and
    its run folder, locked by the caller that read that checkpoint (None: train_batched locks
    it)."""

    args: Any
    checkpoint: Checkpoint | None = None
    folder: RunFolder | None = None


class BatchedA3C:
    """N one-worker runs of a script in lockstep (the module docstring)."""

    def __init__(
        self,
        module: ModuleType,
        runs: list[BatchedRun],
        device: str | torch.device,
        conv_form: str = "grouped",
    ):
        self.module, self.agent, self.device = module, module.AGENT, torch.device(device)
        if conv_form not in CONV_FORMS:
            raise ValueError(f"conv_form {conv_form!r}; valid: {', '.join(CONV_FORMS)}")
        self.precision = runs[0].args.precision  # (the batch's: batch_problem)
        if self.precision == "tf32" and self.device.type != "cuda":
            raise UsageError("--precision tf32 is a GPU's: it needs --device cuda")
        # the worker's autocast of its acting and learning passes, on the batch's device
        self.act_precision, self.learn_precision = autocast_contexts(
            self.precision, self.device.type
        )
        if (problem := batch_problem(self.agent.script, [run.args for run in runs])) is not None:
            raise UsageError(problem)
        # a run alone computes beside a copy of itself whose results are dropped: vmap over one
        # run takes other kernels than over two or more, which part in the last bits
        self.shown = len(runs)
        if len(runs) == 1:
            runs = [runs[0], dataclasses.replace(runs[0], folder=None)]
        self.runs, self.args = runs, [run.args for run in runs]
        self.total, n = self.args[0].total_timesteps, len(runs)
        a, models, square_avgs = self.args[0], [], []
        for run in runs:  # each run's network and statistics, as a3c_runtime.train makes them
            seed_everything(run.args.seed)
            models.append(self.agent.build_network(3, run.args))
            optimizer = RMSprop(list(models[-1].parameters()), a.rms_decay, a.optim_eps,
                                a.rms_init, shared=False)  # fmt: skip
            if run.checkpoint is not None:  # (the flags its network depends on checked)
                state = SimpleNamespace(model=models[-1], optimizer=optimizer, base_step=[0])
                restore(state, run.checkpoint, run.args, run.checkpoint.path, self.agent)
            square_avgs.append(optimizer.square_avg)
        seeds = [process_seed(args.seed, 0) for args in self.args]  # the workers'
        self.rngs = [np.random.default_rng(seed) for seed in seeds]
        self.base = copy.deepcopy(models[0]).to(self.device)  # called with each run's weights
        self.conv_form = conv_form
        if conv_form == "matmul":
            matmul_convs(self.base)
        # each run's --learning-rate, in float64 as annealed_lr computes with it
        self.learning_rates = torch.tensor([args.learning_rate for args in self.args],
                                           dtype=torch.float64, device=self.device)  # fmt: skip
        self.eval_model = copy.deepcopy(models[0]).to(self.device)  # a run's, for its evaluation
        params, buffers = stack_module_state(models)
        self.names = list(params)
        self.params = [params[k].detach().to(self.device) for k in self.names]
        self.buffers = {k: b.to(self.device) for k, b in buffers.items()}  # (LWS's centroids)
        self.saved_names = list(models[0].state_dict())  # what a checkpoint's model holds
        self.optimizer = RMSprop(self.params, a.rms_decay, a.optim_eps, a.rms_init, shared=False)
        for j, stacked in enumerate(self.optimizer.square_avg):
            stacked.copy_(torch.stack([run_avgs[j] for run_avgs in square_avgs]))
        self.envs = TorchCatchVectorEnv(n, self.device)
        self.envs.reset(seed=seeds)
        # LSTM: the state each run's worker carries across rollouts, (N, 1, cells) each
        self.state: tuple[torch.Tensor, ...] = ()
        if hasattr(self.base, "initial_state"):
            self.state = tuple(s.expand(n, *s.shape).clone().to(self.device)
                               for s in models[0].initial_state(1))  # fmt: skip
        self.step_count, self.wall_offsets = 0, [0.0] * n
        if runs[0].checkpoint is not None:
            self.restore([run.checkpoint for run in runs])
        if len(rows := set(self.envs.ball_row.tolist())) > 1:
            raise ValueError(f"a batch's runs must be at the same step of their episodes (their "
                             f"balls on one row); these are on rows {sorted(rows)}")  # fmt: skip
        self.uniforms = ActionUniforms(self.rngs, self.device)
        self.eval_envs: list | None = None
        # each run's running totals of Shared.STATS (RunLog's scalars)
        shape = (n, len(WorkerStats.INDEX))
        self.stats = torch.zeros(shape, dtype=torch.float64, device=self.device)

    def restore(self, checkpoints: list[Checkpoint]) -> None:
        """Every run's worker from its checkpoint (all at one step; theta and the statistics
        are restored by the runtime's `restore` in __init__): its generator, env (and LSTM
        state), as a worker restores its own."""
        (self.step_count,) = {c.global_step for c in checkpoints}
        for i, checkpoint in enumerate(checkpoints):
            fresh = (self.rngs[i], NumpyStateView(self.envs, i), None, self.state)
            parts = restored_state(checkpoint.workers[0], fresh[: 3 + bool(self.state)])
            for stacked, saved in zip(self.state, parts[3] if self.state else (), strict=True):
                stacked[i] = saved
            self.wall_offsets[i] = checkpoint.wall_time

    def set_progress(self) -> None:
        """GLPQ's tau schedule at this step, as its worker and evaluator set it, and the 1/tau
        of its loss correction."""
        if hasattr(self.base, "set_progress"):
            self.base.set_progress(self.step_count / self.total)
        scale = getattr(self.base, "policy_loss_scale", None)
        self.loss_scale = scale() if scale is not None else 1.0

    def forward(self, params: list, buffers: dict, frames: torch.Tensor, state: tuple) -> Any:
        """One run's network, its parameters substituted: (log-probs, values[, state])."""
        weights = {**dict(zip(self.names, params, strict=True)), **buffers}
        return functional_call(self.base, weights, (frames, state) if state else (frames,))

    def act(self, frames: torch.Tensor, state: tuple = (), precision: Any = None) -> tuple:
        """Every run's forward of frames (N, B, 4, 84, 84): log-probs (N, B, A), values (N, B)
        and (LSTM) the state after the step, under the acting pass's autocast (or `precision`'s).
        In grad mode, though nothing requires a gradient: acting shortcuts that compare data
        (LWS's cache, torch.equal) are taken only without it, and vmap cannot batch them; the
        values are the same."""
        with torch.enable_grad(), precision or self.act_precision:
            if not state:
                return (*vmap(self.forward)(self.params, self.buffers, frames, ()), ())
            log_probs, values, state = vmap(self.forward)(
                self.params, self.buffers, frames[:, None], state
            )  # LSTM: T = 1
            return log_probs[:, 0], values[:, 0], state

    def loss(self, params, buffers, frames, actions, returns, state):  # noqa: ANN001, ANN201
        a = self.args[0]
        with self.learn_precision:  # (the learning pass's autocast, as the worker's)
            if state:  # LSTM: the rollout (T = n, B = 1) replayed from its start state
                log_probs, values, _ = self.forward(params, buffers, frames, state)
                log_probs, values = log_probs.flatten(0, 1), values.flatten(0, 1)
            else:
                log_probs, values = self.forward(params, buffers, frames, ())
        log_probs, values = log_probs.float(), values.float()  # the loss in float32
        loss, policy_loss, value_loss, entropy = self.module.a3c_loss(
            log_probs, actions, values, returns, a.ent_coef, a.vf_coef, a.value_loss_form
        )
        if hasattr(self.module, "tau_corrected_loss"):  # GLPQ: the policy loss times 1/tau
            loss = self.module.tau_corrected_loss(loss, policy_loss, entropy, self.loss_scale, a)
        return loss, (policy_loss, value_loss, entropy)

    def update(self) -> int:
        """One rollout of up to t_max steps in every run, and its update; returns its steps."""
        a, n_runs, envs, t_max = self.args[0], len(self.runs), self.envs, self.args[0].t_max
        self.set_progress()
        frames = torch.empty((t_max + 1, n_runs, 4, 84, 84), dtype=torch.uint8, device=self.device)
        frames[0] = envs.stack
        actions = torch.zeros((t_max, n_runs), dtype=torch.int64, device=self.device)
        rewards = torch.zeros((t_max, n_runs), dtype=torch.float32, device=self.device)
        dones = torch.zeros((t_max, n_runs), dtype=torch.bool, device=self.device)
        rollout_state = tuple(s.clone() for s in self.state)  # (LSTM: the rollout's start)
        with torch.no_grad():
            for t in range(t_max):
                log_probs, _, self.state = self.act(network_frames(frames[t][:, None]), self.state)
                actions[t] = sample_actions(log_probs[:, 0].float().exp(), self.uniforms.next())
                frames[t + 1], rewards[t], _, ended = envs.step(actions[t])  # (ended: the host's)
                if ended.any():  # all together: the runs' balls started on one row
                    dones[t] = True
                    self.add_stats(episodes=1.0, return_sum=envs.final_returns,
                                   length_sum=envs.final_lengths)  # fmt: skip
                    self.state = tuple(torch.zeros_like(s) for s in self.state)  # (LSTM)
                    break
            n = t + 1
            bootstrap = torch.zeros(n_runs, dtype=torch.float32, device=self.device)
            if not ended.any():  # V(s_n), as the worker's learning pass computes it (its autocast)
                bootstrap = self.act(
                    network_frames(frames[n][:, None]), self.state, self.learn_precision
                )[1][:, 0]
        # the script's returns, on the device (Catch never truncates: no done values)
        done_values = torch.zeros((n, n_runs), dtype=torch.float32, device=self.device)
        returns = self.module.n_step_returns(
            rewards[:n], dones[:n], done_values, bootstrap.float(), a.gamma
        )
        rollout = frames[:n].transpose(0, 1)  # (N, n, 4, 84, 84); LSTM: (N, T = n, B = 1, ...)
        grads, (policy_loss, value_loss, entropy) = vmap(grad(self.loss, has_aux=True))(
            self.params,
            self.buffers,
            network_frames(rollout[:, :, None] if self.state else rollout),
            actions[:n].T.contiguous(),
            returns.T.contiguous(),
            rollout_state,
        )
        self.last_actions = actions[:n].T  # (N, n), for the equivalence tests
        grad_norm = clip_stacked(grads, a.grad_clip_mode, a.grad_clip)
        # annealed_lr of every run, on the device: its --learning-rate times the batch's factor
        factor = annealed_lr(dataclasses.replace(a, learning_rate=1.0), self.step_count)
        self.optimizer.step(grads, (self.learning_rates * factor).float())
        self.step_count += n
        self.add_stats(updates=1.0, policy_loss=policy_loss, value_loss=value_loss,
                       entropy=entropy, grad_norm=grad_norm)  # fmt: skip
        return n

    def add_stats(self, **totals: float | torch.Tensor) -> None:
        """Add to every run's totals by name, as a worker to its WorkerStats: a number for all
        runs or a tensor (N,) of each run's."""
        for name, value in totals.items():
            self.stats[:, WorkerStats.INDEX[name]] += value

    def network(self, i: int) -> dict[str, torch.Tensor]:
        """Run i's state dict: its parameters and persistent buffers."""
        stacked = {**dict(zip(self.names, self.params, strict=True)), **self.buffers}
        return {name: stacked[name][i].detach().cpu().clone() for name in self.saved_names}

    def evaluate(self, i: int) -> dict:
        """Run i's evaluation at this step: the runtime's `evaluate_network` of its network, the
        process backend's evaluator's own code (its envs, episode keys and action choice)."""
        if self.eval_envs is None:  # (--eval-episodes is the batch's: one set of envs)
            self.eval_envs = make_eval_envs(self.agent, self.args[0], None)
        self.eval_model.load_state_dict(self.network(i))
        return evaluate_network(self.eval_model, self.eval_envs, self.step_count, self.args[i])

    def worker_state(self, i: int) -> tuple:
        """Run i's worker as its script's `worker_state()` gives it to a checkpoint: its
        generator, env and frames (and an LSTM's carried state)."""
        parts = (self.uniforms.generator(i), NumpyStateView(self.envs, i),
                 self.envs.stack[i : i + 1].cpu().numpy())  # fmt: skip
        return parts + ((tuple(s[i].cpu().clone() for s in self.state),) if self.state else ())

    def checkpoint(self, i: int, run_dir: Path, wall_time: float) -> None:
        """Run i's checkpoint, as its one-worker run writes it."""
        snapshot = {
            "model": self.network(i),
            "optimizer": {"square_avg": [s[i].cpu().clone() for s in self.optimizer.square_avg]},
            "global_step": self.step_count,
            "workers": {0: saved_state(self.worker_state(i))},
        }
        save_checkpoint(run_dir / "checkpoint.pt", None, self.args[i], wall_time,
                        self.agent.script, snapshot)  # fmt: skip


def set_up_device(device: str, precision: str = "fp32") -> None:
    """torch's settings for a batch on this device (the benchmarks' too)."""
    if device == "cuda":  # fp32 as the scripts compute it (TF32 only where --precision tf32
        tf32 = precision == "tf32"  # opts in), and the same run twice the same: cuDNN's
        torch.backends.cudnn.allow_tf32 = tf32  # deterministic algorithms
        torch.backends.cuda.matmul.allow_tf32 = tf32
        torch.backends.cudnn.deterministic = True
        torch.backends.cudnn.benchmark = False
    else:  # one core, as one process-backend run uses
        torch.set_num_threads(1)


def allow_open_files(count: int) -> None:
    """Raise the soft limit of open files to `count` where it is lower (up to the hard limit): a
    batch holds FILES_PER_RUN per run, past the common 1,024 at a few hundred runs."""
    try:
        import resource
    except ImportError:  # (not POSIX)
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft != resource.RLIM_INFINITY and soft < count:
        wanted = count if hard == resource.RLIM_INFINITY else min(count, hard)
        if wanted > soft:
            resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))


def train_batched(
    module: ModuleType,
    runs: list[BatchedRun],
    device: str = "cpu",
    should_stop: Callable[[], str | None] = lambda: None,
    log_interval: float = 30.0,
) -> list[dict]:
    """Train the runs as one batch to their --total-timesteps, each run's folder locked (the
    runtime's lock, where the caller took none) and written as a run writes it: its RunLog
    (evaluations.csv, TensorBoard scalars, progress lines in its stdout.log), its evaluations
    and checkpoints at the marks (the runtime's MarkClock), its last checkpoint and final
    evaluation. should_stop() names the signal that stops the batch, or None: a stop checkpoints
    every run at its last update. log_interval: seconds between the batch's console lines.
    Returns each run's outcome: "done" or "stopped by <signal>", its wall time and closing line."""
    set_up_device(device, runs[0].args.precision)
    batch = BatchedA3C(module, runs, device)  # (refuses runs it cannot batch: nothing written)
    allow_open_files(FILES_PER_RUN * len(runs) + 256)
    folders, logs, consoles = [], [], []
    try:
        for i, run in enumerate(runs[: batch.shown]):
            folders.append(run.folder or RunFolder(Path(run.args.run_dir)))
            consoles.append(open(folders[i].path / "stdout.log", "a"))  # noqa: SIM115
            logs.append(RunLog(folders[i].path, run.args, batch.wall_offsets[i],
                               resumed_step=batch.step_count, console=consoles[i]))  # fmt: skip
        start = batch.step_count
        clock = MarkClock(torch.empty(2, dtype=torch.int64), batch.args[0], start)
        # (a resumed run's evaluation of its checkpoint's step may be logged already)
        logged = [logged_steps(log.csv_path, start) for log in logs]

        def evaluate_all() -> None:
            for i, log in enumerate(logs):
                if batch.step_count not in logged[i]:
                    log.evaluation(batch.evaluate(i))
                    logged[i].add(batch.step_count)

        if start == 0:
            evaluate_all()  # the untrained network's, as every run's first row
        last_line, stopped_by = (time.time(), start), None
        while batch.step_count < batch.total and not (stopped_by := should_stop()):
            batch.update()
            evaluate, checkpoint = clock.reached(step := batch.step_count)
            if evaluate:
                evaluate_all()
            for i, log in enumerate(logs if checkpoint else ()):
                batch.checkpoint(i, folders[i].path, log.wall_time())
            if logs[0].progress_due():  # each run's scalars, as a run logs them
                stats = batch.stats.cpu()
                for i, log in enumerate(logs):
                    log.progress(step, stats[i])
            if (now := time.time()) - last_line[0] >= log_interval:
                sps = (step - last_line[1]) * len(logs) / (now - last_line[0])
                print(f"batched: {len(logs)} runs at step {step:,}/{batch.total:,} | "
                      f"{sps:,.0f} run-steps/s", flush=True)  # fmt: skip
                last_line = (now, step)
        for i, log in enumerate(logs):  # every run's last checkpoint, as a run's last
            batch.checkpoint(i, folders[i].path, log.wall_time())
        if not stopped_by:
            evaluate_all()
        outcome = f"stopped by {stopped_by}" if stopped_by else "done"
        outcomes = []
        for log, folder in zip(logs, folders, strict=True):
            log.close()
            sps = (batch.step_count - start) / max(time.time() - log.start, 1e-9)
            summary = summarize(outcome, sps, batch.step_count, log, folder.path, len(logs))
            outcomes.append({"outcome": outcome, "wall_time_s": summary["wall_time_s"],
                             "stdout": summary["closing_line"]})  # fmt: skip
        return outcomes
    except BaseException:
        for log in logs:
            log.close(quietly=True)
        raise
    finally:
        for console in consoles:
            console.close()
        for run, folder in zip(runs, folders, strict=False):
            if run.folder is None:  # the lock taken here
                folder.close()
