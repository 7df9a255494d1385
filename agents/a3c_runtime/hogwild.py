"""The Hogwild pieces of A3C (thesis 2.2.3, 5.2.2): what the actor-learners share, and the
library pieces their loops use, as torch.optim is to CleanRL's scripts: the shared RMSprop and
Adam, gradient clipping, the learning-rate schedule and the processes' seeds."""

from __future__ import annotations

import os
import random
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn as nn

from .flags import UsageError
from .snapshots import StepMarks, restored_state


class Shared:
    """Everything the processes share: the global network theta and the optimizer statistics
    (in shared memory, updated without locks), each worker's step counter and statistics, and
    the stop event. Built in the main process; a forked process sees the same tensors and its
    own copy of the plain attributes (`signalled` is per process)."""

    STATS = ("episodes", "return_sum", "length_sum", "updates", "policy_loss", "value_loss",
             "entropy", "grad_norm")  # fmt: skip

    def __init__(self, model: nn.Module, args: Any, ctx: Any):
        self.model = model
        self.params = list(self.model.parameters())
        try:
            self.model.share_memory()
            self.optimizer = make_optimizer(self.params, args)
        except RuntimeError as e:  # /dev/shm full, or a file size limit (ulimit -f) below a tensor
            network = sum(t.numel() * t.element_size() for t in model.state_dict().values())
            copies = 3 if args.optimizer == "adam" else 2  # theta and the optimizer's statistics
            size = copies * network / 2**20
            raise UsageError(
                f"cannot put the network and its optimizer statistics ({size:.1f} MiB) in shared "
                f"memory: {e}; free space in /dev/shm or raise the file size limit (ulimit -f)"
            ) from None
        # one step counter per worker, written only by its worker: lock-free and exact
        self.steps = torch.zeros(args.num_workers, dtype=torch.int64).share_memory_()
        self.base_step = torch.zeros(1, dtype=torch.int64).share_memory_()  # from --resume
        self.stats = torch.zeros(args.num_workers, len(self.STATS), dtype=torch.float64)
        self.stats.share_memory_()
        self.stop = ctx.Event()  # the workers stop after their rollout, the evaluator after its
        self.main_pid = os.getpid()
        self.signalled = False  # this process got SIGTERM (or, in the main process, a signal)
        self.marks = StepMarks(ctx)  # evaluations and checkpoints at exact steps

    def global_step(self) -> int:
        return int(self.steps.sum()) + int(self.base_step)

    def count_steps(
        self, worker_id: int, steps: int, state: Callable[[], tuple[Any, ...]] | None = None
    ) -> None:
        """A worker's update took `steps` env steps. Where the global step reaches an evaluation
        or checkpoint mark, theta is copied there for it (a3c_runtime.snapshots); `state()`
        gives what a checkpoint keeps of this worker (its generator, envs, next frames...)."""
        self.steps[worker_id] += steps
        self.marks.reached(self, worker_id, self.global_step(), state)

    def resumed(self, worker_id: int, *fresh: Any) -> tuple[Any, ...]:
        """A worker's state from the checkpoint of a resumed run, in the order its `state()`
        gives it, each part that the checkpoint holds in place of the fresh one given."""
        saved = self.marks.resumed_states.get(worker_id)
        return tuple(fresh) if saved is None else restored_state(saved, fresh)

    def finish_worker(self, worker_id: int, state: Callable[[], tuple[Any, ...]]) -> None:
        """A worker's state as its loop ends, for the run's last checkpoint."""
        self.marks.finished(worker_id, state, self.orphaned())

    def keep_running(self) -> bool:
        """False once the run is stopping: the stop event, a signal to this process, or (in a
        forked process) the main process gone."""
        return not (self.signalled or self.stop.is_set() or self.orphaned())

    def orphaned(self) -> bool:
        """A forked process whose main process is gone (killed): it ends at once."""
        return os.getpid() != self.main_pid and os.getppid() != self.main_pid

    def worker_stats(self, worker_id: int) -> WorkerStats:
        return WorkerStats(self.stats[worker_id])


class WorkerStats:
    """One worker's running totals (Shared.STATS), added to by name; the main process logs the
    change of their sum over the workers."""

    INDEX = {name: i for i, name in enumerate(Shared.STATS)}

    def __init__(self, row: torch.Tensor):
        self.row = row.numpy()  # a view of the shared memory

    def add(self, **totals: float) -> None:
        for name, value in totals.items():
            self.row[self.INDEX[name]] += value


def annealed_lr(args: Any, global_step: int) -> float:
    """The learning rate at global_step: annealed linearly to 0 at T_max (thesis Table 5.1)."""
    if not args.anneal_lr:
        return args.learning_rate
    return args.learning_rate * max(0.0, 1.0 - global_step / args.total_timesteps)


def sample_actions(probs: Any, uniforms: Any) -> Any:
    """Inverse-CDF sampling of one action per row of probs (K, A) with uniforms (K,) ~ U[0, 1),
    on NumPy arrays (a worker's, a few microseconds, unlike torch.multinomial's per-call
    overhead) or on tensors (the batched backend's, on its device), the same code for both: the
    float32 cumulative sums compared in float64, as both promote them, so the same probabilities
    and uniforms draw the same actions. An action of probability 0 is never drawn."""
    # the sums taken left to right in float32, in place on a copy: np.cumsum's order, which
    # torch's cumsum (accumulating in float64 on the CPU) does not keep in its last bit
    cdf = probs * 1
    for k in range(1, probs.shape[1]):
        cdf[:, k] += cdf[:, k - 1]
    return (cdf <= uniforms[:, None] * cdf[:, -1:]).sum(1).clip(max=probs.shape[1] - 1)


def clip_stacked(grads: list[torch.Tensor], mode: str, bound: float) -> torch.Tensor:
    """Clip in place (thesis 6.3.1) the gradients of a stack of runs, each tensor (N, ...) with
    run i's gradient at [i], each run by its own norms: "norm", each tensor by its norm where it
    exceeds the bound (tf.clip_by_norm); "value", each element; "global-norm", all by their
    global norm. Returns each run's global norm before clipping (N,). A worker clips its one
    run as a stack of one (clip_gradients); the batched backend, its N runs."""
    norms = torch.stack([g.reshape(len(g), -1).norm(dim=1) for g in grads], dim=1)  # (N, tensors)
    global_norm = torch.linalg.vector_norm(norms, dim=1)
    if mode == "value":
        torch._foreach_clamp_min_(grads, -bound)
        torch._foreach_clamp_max_(grads, bound)
    if mode not in ("norm", "global-norm"):
        return global_norm
    # on the CPU, nothing more where no bound is exceeded (most updates); on a GPU that check
    # would wait for the device, and scaling by 1 is the same
    exceeded = (norms if mode == "norm" else global_norm) > bound
    if not grads[0].is_cuda and not bool(exceeded.any()):
        return global_norm
    if mode == "norm":  # where any tensor of a run exceeds the bound, each by its own norm
        over = (norms > bound).any(dim=1, keepdim=True)
        factors = torch.where(over, (bound / (norms + 1e-6)).clamp(max=1.0), 1.0)
    else:
        scale = (bound / (global_norm + 1e-6)).clamp(max=1.0)
        factors = torch.where(global_norm > bound, scale, 1.0)[:, None].expand_as(norms)
    for j, g in enumerate(grads):
        g.mul_(factors[:, j].view(-1, *[1] * (g.dim() - 1)))
    return global_norm


def clip_gradients(grads: list[torch.Tensor], mode: str, bound: float) -> float:
    """Clip one run's gradients in place (thesis 6.3.1): `clip_stacked` of a stack of one.
    Returns the global norm before clipping."""
    return float(clip_stacked([g.unsqueeze(0) for g in grads], mode, bound)[0])


class RMSprop:
    """RMSprop (thesis 2.2.3, 5.2.2): ms <- rho * ms + (1 - rho) * g^2;  theta <- theta - lr *
    g / sqrt(ms + eps), from ms = `initial` (0 in the thesis's code; TensorFlow's
    RMSPropOptimizer starts at 1). Of one run's parameters, its mean square in shared memory,
    shared by all the run's workers (a step's lr a number); or of a stack of runs' parameters
    (N, ...), a step's lr a tensor (N,) of each run's (the batched backend, shared=False)."""

    def __init__(
        self,
        params: list[torch.Tensor],
        decay: float,
        eps: float,
        initial: float = 0.0,
        shared: bool = True,
    ):
        self.params, self.decay, self.eps, self.initial = params, decay, eps, initial
        self.square_avg = [torch.full_like(p, initial) for p in params]
        if shared:
            for s in self.square_avg:
                s.share_memory_()

    @torch.no_grad()
    def step(self, grads: list[torch.Tensor], lr: float | torch.Tensor) -> None:
        torch._foreach_mul_(self.square_avg, self.decay)
        torch._foreach_addcmul_(self.square_avg, grads, grads, value=1.0 - self.decay)
        # g * (ms + eps)^-0.5: on CPU faster than sqrt and a division, and pow_(-0.5) than
        # rsqrt_ (same values, about half the time in torch 2.13's foreach kernels)
        inv_rms = torch._foreach_add(self.square_avg, self.eps)
        torch._foreach_pow_(inv_rms, -0.5)
        if not isinstance(lr, torch.Tensor):
            torch._foreach_addcmul_(self.params, grads, inv_rms, value=-lr)
            return
        for p, g, inv in zip(self.params, grads, inv_rms, strict=True):  # a rate per run
            p.addcmul_(g * inv, lr.view(-1, *[1] * (p.dim() - 1)), value=-1.0)

    def state_dict(self) -> dict:
        return {"square_avg": [s.clone() for s in self.square_avg]}

    @torch.no_grad()
    def load_state_dict(self, state: dict) -> None:
        torch._foreach_copy_(self.square_avg, state["square_avg"])


class SharedAdam:
    """Adam with shared moments and step count (thesis A.1.2, eqs. A.1-A.5; eps inside the root).
    epsilon_form "code" is the thesis code's update, lr sqrt(1 - beta2^t) / (1 - beta1^t) m /
    sqrt(v + eps): eq. A.5 with eps / (1 - beta2^t) in place of eps."""

    def __init__(
        self,
        params: list[torch.Tensor],
        beta1: float,
        beta2: float,
        eps: float,
        epsilon_form: str = "text",
    ):
        self.params, self.beta1, self.beta2, self.eps = params, beta1, beta2, eps
        self.epsilon_form = epsilon_form
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
        eps = self.eps if self.epsilon_form == "text" else self.eps / (1.0 - self.beta2**t)
        torch._foreach_add_(inv_rms, eps)
        torch._foreach_pow_(inv_rms, -0.5)  # as RMSprop's
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


def make_optimizer(params: list[torch.Tensor], args: Any) -> RMSprop | SharedAdam:
    if args.optimizer == "adam":
        form = getattr(args, "adam_epsilon_form", "text")
        return SharedAdam(params, args.adam_beta1, args.adam_beta2, args.optim_eps, form)
    return RMSprop(params, args.rms_decay, args.optim_eps, getattr(args, "rms_init", 0.0))


def process_seed(seed: int, index: int) -> int:
    """Seed of process `index` (workers 0..N-1, then the evaluator); unlike seed + index, runs
    with neighbouring --seed values share no worker's random streams."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def seed_everything(seed: int) -> None:
    random.seed(seed)
    torch.manual_seed(seed)
