"""The run machinery of the A3C scripts (agents/a3c_*.py): everything they share that is not the
thesis's algorithm, written once, as CleanRL keeps its shared pieces in `cleanrl_utils`. One
module per concern:

- `a3c`: A3C's structure in one function (`train`: the shared network and optimizer, N
  actor-learner processes, the evaluator) and the command line (`run`);
- `hogwild`: what the processes share (`Shared`, each worker's `WorkerStats`), the shared
  RMSprop and Adam, action sampling, gradient clipping, the learning-rate schedule, the
  processes' seeds;
- `batched`: N one-worker runs as one program on one device (the sweep's --backend batched),
  through the same pieces; `batchable`, which runs it takes; `stacked_convs`, its convolutions
  as one batched matmul;
- `supervision`: starting and watching the processes, signals, how a run stops;
- `evaluation`: the evaluator process, the thesis's evaluation protocol, --evaluate;
- `checkpoints`: atomic save; the gate (a checkpoint read once, every field checked, handed on
  as a `Checkpoint` record); restoring for --resume;
- `resume`: --resume continues the same experiment (the checkpoint's flags);
- `run_folder`: the run folder, checked and locked (one writer at a time);
- `run_log`: TensorBoard, evaluations.csv, the console;
- `flags`: env-dependent defaults, the flag checks (UsageError), --precision;
- `snapshots`: evaluations and checkpoints at the exact steps the flags name, and each worker's
  state in the checkpoint, so that a resumed run is the run it continues;
- `replay`: the activation replay that spares the update its forward pass.

A script gives `run` an `Agent` from its `main`; see `Agent` for what each field must be.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import torch
import torch.nn as nn

from .a3c import run, train
from .checkpoints import (
    Checkpoint,
    WriteFailed,
    load_checkpoint,
    load_network,
    open_checkpoint,
    restore,
    save_checkpoint,
)
from .evaluation import evaluate, evaluate_network, evaluator, make_eval_envs, play_episodes
from .flags import (
    UsageError,
    autocast_contexts,
    default_num_workers,
    default_text,
    native_bf16,
    probe_env,
    resolve_defaults,
)
from .hogwild import (
    RMSprop,
    Shared,
    SharedAdam,
    WorkerStats,
    annealed_lr,
    clip_gradients,
    clip_stacked,
    process_seed,
    sample_actions,
    seed_everything,
)
from .replay import ActivationReplay, replay_activations
from .run_log import RunLog
from .supervision import RunFailed, configure_process, run_process


@dataclass(frozen=True)
class Agent:
    """What a script gives the runtime.

    - `script`: the script's file name, stored in its checkpoints;
    - `Args`: a dataclass with the flags of a3c_ff.py's Args (a variant adds its own);
    - `make_env(env_id, render_mode=None)`: (4, 84, 84) uint8 observations, info["episode"] at
      the end of a game;
    - `network(num_actions, args)`: an nn.Module. forward(obs uint8 (B, 4, 84, 84)) ->
      (log-probs (B, A), values (B,)); a recurrent network also has `initial_state(batch)` and
      forward(obs (T, B, ...), state) -> (log-probs (T, B, A), values (T, B), state). An
      optional `set_progress(fraction)` hears the training progress T / T_max before
      evaluation episodes. The constructor raises UsageError for bad network flags; it runs
      before any run folder exists;
    - `network_args`: the Args fields a checkpoint's network depends on (resuming with another
      value is refused);
    - `worker(worker_id, shared, args)`: the actor-learner loop. It runs while
      `shared.keep_running()` and the global step is below T_max, reads and updates
      `shared.params` with `shared.optimizer`, counts its env steps after each update with
      `shared.count_steps(worker_id, steps, worker_state)` (worker_state() gives what a
      checkpoint keeps of it, each part saved as data by a3c_runtime.snapshots.saved_state: a
      NumPy generator, an array, a tensor or a tuple of them, an env with get_state/set_state;
      any other part is made afresh on resume), starts from `shared.resumed(worker_id, ...)`
      and ends with `shared.finish_worker(worker_id, worker_state)`, and adds its statistics
      (`Shared.STATS`) by name to `shared.worker_stats(worker_id)`;
    - `checkpoint_defaults`: flags newer than some checkpoints, with the value those
      checkpoints' runs had where it is not the flag's default (e.g. SS's --conv-layout: final
      before it existed);
    - `initialize(network, args)` (optional): sets a new run's global network before the
      workers start, for an initialisation that needs the env or data (e.g. prototypes placed on
      the features of random play, agents/future_work/a3c_lpq_data_init.py); not called when
      resuming, where the checkpoint's network is the run's.

    Anything else a variant needs (upkeep of the shared network during training, say) is the
    script's own: its worker holds `shared`, and worker 0 can do what one process must do.
    """

    script: str
    Args: type
    make_env: Callable[..., gym.Env]
    network: Callable[[int, Any], nn.Module]
    network_args: tuple[str, ...]
    worker: Callable[..., None]
    checkpoint_defaults: dict[str, Any] = field(default_factory=dict)
    initialize: Callable[[nn.Module, Any], None] | None = None

    def trained_args(self, checkpoint: Checkpoint) -> dict[str, Any]:
        """The flags a checkpoint was trained with; a flag it predates has its
        checkpoint_defaults value (or, for --precision, fp32: the runs before the flag), else
        (left out here) the flag's default."""
        return {"precision": "fp32", **self.checkpoint_defaults, **checkpoint.args}

    def build_network(self, num_actions: int, args: Any) -> nn.Module:
        # channels_last makes oneDNN's convolution backward about 2x faster on CPU
        return self.network(num_actions, args).to(memory_format=torch.channels_last)


__all__ = [
    "ActivationReplay",
    "Agent",
    "Checkpoint",
    "RunFailed",
    "RunLog",
    "Shared",
    "SharedAdam",
    "RMSprop",
    "UsageError",
    "WriteFailed",
    "WorkerStats",
    "annealed_lr",
    "autocast_contexts",
    "clip_gradients",
    "clip_stacked",
    "configure_process",
    "default_num_workers",
    "default_text",
    "evaluate",
    "evaluate_network",
    "evaluator",
    "load_checkpoint",
    "load_network",
    "make_eval_envs",
    "native_bf16",
    "open_checkpoint",
    "play_episodes",
    "probe_env",
    "process_seed",
    "replay_activations",
    "resolve_defaults",
    "restore",
    "run",
    "run_process",
    "sample_actions",
    "save_checkpoint",
    "seed_everything",
    "train",
]
