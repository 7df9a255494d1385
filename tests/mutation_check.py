"""Mutation check: does the fast test tier catch a broken algorithm or game?

Each mutant in MUTANTS replaces one exact snippet of source (in every file it names: the copies
of shared code in every agent script at once, so that the drift test alone cannot catch it) with
a plausible bug. For each, this script applies it to a scratch copy of the tree, runs the fast
tier there (`pytest -x -m "not slow"`, the test files most likely to catch it first) and records
whether a test fails, which test failed first, and how long it took. A mutant must be ruff clean
(so that tests/test_repo.py's ruff test cannot be what catches it), and its snippet must occur
exactly once in each file it names (else the list has rotted: the script stops, exit 2).

    python tests/mutation_check.py [--only ID ...] [--out results/mutation_check/output.txt]

Exit 0 when every mutant is caught, 1 when some survive, 2 when the list or the unmutated tree's
fast tier is broken. Not collected by pytest (its name does not start with test_).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[1]


class Mutant(NamedTuple):
    id: str
    breaks: str  # what it breaks, in words
    files: tuple[str, ...]  # each gets the same replacement
    original: str  # occurs exactly once in each file
    replacement: str
    first: tuple[str, ...] = ()  # test files to run first (then the others, by name)


def scripts(*names: str) -> tuple[str, ...]:
    return tuple(f"agents/{name}.py" for name in names)


THESIS = scripts("a3c_ff", "a3c_lws", "a3c_ss", "a3c_ww", "a3c_lstm", "a3c_lpq", "a3c_glpq")
IDEAS = ("value_head", "data_init", "growth")  # chapter 8's ideas on LPQ and on GLPQ
FUTURE = scripts(
    *(f"future_work/a3c_{head}_{idea}" for head in ("lpq", "glpq") for idea in IDEAS),
    "future_work/a3c_lws_online",
)
ALL = THESIS + FUTURE  # every copy of a3c_ff.py's shared code
NOT_LSTM = tuple(f for f in ALL if f != "agents/a3c_lstm.py")  # the LSTM's own lines differ
LPQ = scripts("a3c_lpq", *(f"future_work/a3c_lpq_{idea}" for idea in IDEAS))
GLPQ = scripts("a3c_glpq", *(f"future_work/a3c_glpq_{idea}" for idea in IDEAS))
GLPQ_NOT_GROWTH = GLPQ[:3]  # growth's glpq_log_policy has its own form (free slots)
LWS = scripts("a3c_lws", "future_work/a3c_lws_online")
HOGWILD = ("agents/a3c_runtime/hogwild.py",)
CHECKPOINTS = ("agents/a3c_runtime/checkpoints.py",)
RUN_FOLDER = ("agents/a3c_runtime/run_folder.py",)
RUN_LOG = ("agents/a3c_runtime/run_log.py",)
FLAGS = ("agents/a3c_runtime/flags.py",)
CAMPAIGN = ("agents/a3c_tools/campaign.py",)
RESUME = ("agents/a3c_runtime/resume.py",)
RUN = ("agents/a3c_runtime/a3c.py",)
SUPERVISION = ("agents/a3c_runtime/supervision.py",)
EVALUATION = ("agents/a3c_runtime/evaluation.py",)
SNAPSHOTS = ("agents/a3c_runtime/snapshots.py",)
BATCHED_BACKEND = ("agents/a3c_runtime/batched.py",)
BATCHED_SWEEP = ("agents/a3c_tools/batched.py",)
BATCHABLE = ("agents/a3c_runtime/batchable.py",)
STACKED_CONVS = ("agents/a3c_runtime/stacked_convs.py",)
TORCH_CATCH = ("catch_env/torch_catch.py",)
TOOLS_INIT = ("agents/a3c_tools/__init__.py",)
SWEEP = ("agents/a3c_tools/sweep.py",)
RUN_LOCK = ("agents/a3c_tools/run_lock.py",)
ATARI_FIGURES = ("agents/a3c_tools/atari_figures.py",)
PAIRED = ("agents/a3c_tools/paired.py",)
CONFIRMATORY = ("agents/a3c_tools/confirmatory.py",)
THESIS_CLAIMS = ("agents/a3c_tools/thesis_claims.py",)
STUDY_READING = ("agents/a3c_tools/study_reading.py",)
TOOLS = ("agents/a3c_tools/__init__.py",)
CATCH = ("catch_env/catch.py",)
WRAPPERS = ("catch_env/wrappers.py",)

# the test files to run first
UNITS = "tests/test_a3c_units.py"  # the loss
BATCHED = "tests/test_batched_actors.py"  # the n-step returns, sampling, the LSTM's resets
WORKERS = "tests/test_workers.py"  # the worker loop
OPTIM = "tests/test_runtime_hogwild.py"
CKPT = "tests/test_runtime_checkpoints.py"
RES = "tests/test_runtime_resume.py"
TRAIN = "tests/test_runtime_train.py"
SUPERVISION_T = "tests/test_runtime_supervision.py"
EVALUATION_T = "tests/test_runtime_evaluation.py"
PROTO = "tests/test_prototype_policies.py"
ARCH = "tests/test_variants_arch.py"
CATCH_T = "tests/test_catch.py"
WRAP_T = "tests/test_wrappers.py"
BATCH_T = "tests/test_batched.py"  # the batched backend against the scripts' own runs
SWEEP_T = "tests/test_sweep.py"
COMPARE_T = "tests/test_compare.py"
CLAIMS_T = "tests/test_thesis_claims.py"
CONFIRM_T = "tests/test_confirmatory.py"
STUDY_T = "tests/test_study_reading.py"
CAMPAIGN_T = "tests/test_campaign.py"
RUN_FOLDER_T = "tests/test_runtime_run_folder.py"
RUN_LOG_T = "tests/test_runtime_run_log.py"
FLAGS_T = "tests/test_runtime_flags.py"
PRECISION_T = "tests/test_precision.py"

# fmt: off
MUTANTS = [
    # --- the A3C loss and the n-step returns (a3c_ff.py, and every copy) ---------------------
    Mutant("advantage-not-detached", "the policy gradient back-propagates into the critic "
           "through the advantage", ALL,
           "* advantages.detach()).sum()", "* advantages).sum()", (UNITS,)),
    Mutant("entropy-sign", "the entropy bonus becomes a penalty (beta's sign)", ALL,
           "return policy_loss - ent_coef * entropy + vf_coef * value_loss",
           "return policy_loss + ent_coef * entropy + vf_coef * value_loss", (UNITS,)),
    Mutant("lambda-v-ignored", "the value loss factor lambda_V (--vf-coef) is not applied", ALL,
           "return policy_loss - ent_coef * entropy + vf_coef * value_loss",
           "return policy_loss - ent_coef * entropy + value_loss", (UNITS,)),
    Mutant("value-loss-half", "the default value loss loses its 1/2: (G - V)^2", ALL,
           'if value_loss_form == "code":', 'if value_loss_form == "text":', (UNITS,)),
    Mutant("gamma-squared", "each n-step return discounts by gamma^2 per step", ALL,
           "g = rewards[t] + gamma * (dones[t]", "g = rewards[t] + gamma**2 * (dones[t]",
           (BATCHED,)),
    Mutant("returns-cross-episodes", "a return flows back across an episode's end (terminal "
           "or truncated)", ALL,
           "g = rewards[t] + gamma * (dones[t] * done_values[t] + ~dones[t] * g)",
           "g = rewards[t] + gamma * g", (BATCHED,)),
    Mutant("no-bootstrap", "the n-step return starts from 0, not V(s_n), at a rollout's end",
           ALL, "    g = bootstrap_values\n", "    g = np.zeros_like(bootstrap_values)\n",
           (BATCHED,)),
    # --- the worker (Algorithm 1) ------------------------------------------------------------
    Mutant("gamma-flag-ignored", "the worker discounts with the default gamma (Args.gamma), "
           "not --gamma's", ALL,
           "rewards[:n], dones[:n], done_values[:n], bootstrap_values, args.gamma",
           "rewards[:n], dones[:n], done_values[:n], bootstrap_values, Args.gamma", (WORKERS,)),
    Mutant("terminal-as-truncation", "a terminal state bootstraps from V(s_last) like a time "
           "limit", ALL, "cut = truncated & ~terminated", "cut = truncated | terminated",
           (WORKERS,)),
    Mutant("truncation-as-terminal", "a time limit bootstraps from 0 like a terminal state",
           NOT_LSTM, "done_values[t, cut] = model(last_obs)[1].float().numpy()",
           "done_values[t, cut] = 0.0 * model(last_obs)[1].float().numpy()", (WORKERS,)),
    Mutant("bootstrap-from-first-state", "the n-step bootstrap takes V(s_0), not V(s_n)", ALL,
           "bootstrap_values = values[n * num_envs :].detach()",
           "bootstrap_values = values[:num_envs].detach()", (WORKERS,)),
    Mutant("theta-not-synced", "theta' is never synced from theta: each worker acts and "
           "learns with its own initial network", ALL,
           "torch._foreach_copy_(params, shared.params)  # theta' <- theta",
           "torch._foreach_copy_(params, params)  # theta' <- theta", (WORKERS,)),
    Mutant("sample-zero-probability", "sampling can draw an action of probability 0", HOGWILD,
           "cdf <= uniforms[:, None] * cdf[:, -1:]", "cdf < uniforms[:, None] * cdf[:, -1:]",
           (BATCHED,)),
    Mutant("sample-cumsum-torch-order", "the cumulative sums by cumsum, which torch takes in "
           "float64: a batch draws another action than the worker at a cdf's edge", HOGWILD,
           "    cdf = probs * 1\n    for k in range(1, probs.shape[1]):\n"
           "        cdf[:, k] += cdf[:, k - 1]\n", "    cdf = probs.cumsum(1)\n", (BATCH_T,)),
    Mutant("act-without-randomness", "the workers act with u = 0: always the first action "
           "of nonzero probability, not a sample of pi", ALL,
           "sample_actions(log_probs.float().exp().numpy(), rng.random(num_envs))",
           "sample_actions(log_probs.float().exp().numpy(), 0.0 * rng.random(num_envs))",
           (WORKERS,)),
    Mutant("clip-a-copy", "the worker clips a copy of the gradients and applies the "
           "unclipped ones", ALL,
           "grad_norm = clip_gradients(grads, args.grad_clip_mode, args.grad_clip)",
           "grad_norm = clip_gradients([g.clone() for g in grads], args.grad_clip_mode, "
           "args.grad_clip)", (WORKERS,)),
    Mutant("lr-not-annealed-in-worker", "the worker steps with the learning rate of step 0 "
           "throughout", ALL,
           "shared.optimizer.step(grads, annealed_lr(args, global_step))",
           "shared.optimizer.step(grads, annealed_lr(args, 0))", (WORKERS,)),
    # --- LSTM ----------------------------------------------------------------------------------
    Mutant("lstm-acting-state-not-reset", "the LSTM carries its acting state into the next "
           "episode", scripts("a3c_lstm"),
           "continuing = torch.from_numpy(~ended)[:, None]",
           "continuing = torch.from_numpy(ended | ~ended)[:, None]", (WORKERS, ARCH)),
    Mutant("lstm-replay-start-at-step-1-ignored", "the LSTM's replay does not restart an "
           "episode that starts at the rollout's second step", scripts("a3c_lstm"),
           "if episode_starts is not None and t > 0:", "if episode_starts is not None and t > 1:",
           (BATCHED, ARCH)),
    Mutant("lstm-episode-starts-shifted", "the LSTM's replay restarts an episode one step "
           "early (at the terminal state)", scripts("a3c_lstm"),
           "episode_starts[1:] = torch.from_numpy(dones[:n])",
           "episode_starts[:n] = torch.from_numpy(dones[:n])", (WORKERS, ARCH)),
    # --- LPQ and GLPQ heads ------------------------------------------------------------------
    Mutant("lpq-logit-sign", "LPQ's per-action logit adds the shift it should subtract", LPQ,
           "sum(-1).log() - nearest.squeeze(-1)", "sum(-1).log() + nearest.squeeze(-1)",
           (PROTO,)),
    Mutant("lpq-farthest-compete", "LPQ's competition takes each action's k farthest "
           "prototypes", LPQ,
           "return distances.topk(k, dim=-1, largest=False, sorted=False).values",
           "return distances.topk(k, dim=-1, largest=True, sorted=False).values", (PROTO,)),
    Mutant("glpq-mu-sign", "GLPQ's mu = (d_- - d) / (d_- + d) has its sign flipped", GLPQ,
           "return (d_minus - distances) / (d_minus + distances + MU_EPS)",
           "return (distances - d_minus) / (d_minus + distances + MU_EPS)", (PROTO,)),
    Mutant("glpq-temperature-ignored", "GLPQ's logits drop the temperature tau", GLPQ_NOT_GROWTH,
           "per_action = torch.exp(tau * (scores - 1.0)).sum(-1).log()",
           "per_action = torch.exp(scores - 1.0).sum(-1).log()", (PROTO,)),
    Mutant("glpq-farthest-compete", "GLPQ's competition takes each action's k farthest "
           "prototypes", GLPQ_NOT_GROWTH,
           "nearest = distances.topk(k, dim=-1, largest=False, sorted=False).indices",
           "nearest = distances.topk(k, dim=-1, largest=True, sorted=False).indices", (PROTO,)),
    Mutant("glpq-tau-schedule-reversed", "the tau schedule runs from p_end to p_start", GLPQ,
           "p = self.p_start + (self.p_end - self.p_start) * self.progress",
           "p = self.p_end + (self.p_start - self.p_end) * self.progress", (PROTO,)),
    Mutant("glpq-scheduled-tau-doubled", "tau = ln(p (n - 1) / (1 - p)) without the 1/2 of "
           "eqs. 7.17-7.18", GLPQ,
           "return 0.5 * math.log(p * (n - 1) / (1 - p))",
           "return math.log(p * (n - 1) / (1 - p))", (PROTO,)),
    Mutant("glpq-loss-times-tau", "the policy loss is multiplied by tau instead of 1/tau",
           GLPQ, "return 1.0 / float(self.tau())", "return float(self.tau())", (PROTO,)),
    Mutant("glpq-progress-not-set", "the worker never tells the network the training "
           "progress: tau stays at its schedule's start", GLPQ,
           "model.set_progress(global_step / args.total_timesteps)  # GLPQ",
           "model.set_progress(0.0)  # GLPQ", (PROTO, WORKERS)),
    # --- LWS, SS, WW -------------------------------------------------------------------------
    Mutant("lws-similarity-sign", "LWS weights each kernel by exp(+d): the farthest centroid "
           "wins", LWS, "return torch.softmax(-distance, dim=-2)",
           "return torch.softmax(distance, dim=-2)", (ARCH,)),
    Mutant("lws-rows-cols-swapped", "LWS reads a centroid's (row, column) as (column, row)",
           scripts("a3c_lws"), "centroid_rows, centroid_cols = self.centroids.unbind(-1)",
           "centroid_cols, centroid_rows = self.centroids.unbind(-1)", (ARCH,)),
    Mutant("ss-coordinates-transposed", "the spatial softmax's x and y coordinates are "
           "swapped", scripts("a3c_ss"), 'indexing="xy")', 'indexing="ij")', (ARCH,)),
    Mutant("ss-temperature-multiplies", "the spatial softmax multiplies by its temperature "
           "instead of dividing", scripts("a3c_ss"), "features.flatten(2) / self.temperature",
           "features.flatten(2) * self.temperature", (ARCH,)),
    Mutant("ww-coordinates-range", "WW's spatial softmax coordinates span [0, 1], not "
           "[-0.5, 0.5]", scripts("a3c_ww"), "axis = torch.linspace(-0.5, 0.5, size)",
           "axis = torch.linspace(0.0, 1.0, size)", (ARCH,)),
    # --- the shared optimizers, clipping, the learning rate (hogwild.py) ----------------------
    Mutant("rmsprop-eps-outside-root", "RMSprop divides by sqrt(ms) + eps, not sqrt(ms + eps)",
           HOGWILD,
           "        inv_rms = torch._foreach_add(self.square_avg, self.eps)\n"
           "        torch._foreach_pow_(inv_rms, -0.5)\n",
           "        inv_rms = torch._foreach_sqrt(self.square_avg)\n"
           "        torch._foreach_add_(inv_rms, self.eps)\n"
           "        torch._foreach_reciprocal_(inv_rms)\n", (OPTIM,)),
    Mutant("rmsprop-decay-swapped", "RMSprop adds rho * g^2 to the mean square instead of "
           "(1 - rho) * g^2", HOGWILD,
           "grads, grads, value=1.0 - self.decay)", "grads, grads, value=self.decay)", (OPTIM,)),
    Mutant("adam-no-bias-correction", "Adam's first moment is not bias-corrected", HOGWILD,
           "        torch._foreach_addcmul_(\n"
           "            self.params, self.exp_avg, inv_rms, value=-lr / (1.0 - self.beta1**t)\n"
           "        )\n",
           "        torch._foreach_addcmul_(self.params, self.exp_avg, inv_rms, value=-lr)\n",
           (OPTIM,)),
    Mutant("adam-no-second-bias-correction", "Adam's second moment is not bias-corrected",
           HOGWILD, "torch._foreach_div(self.exp_avg_sq, 1.0 - self.beta2**t)",
           "torch._foreach_div(self.exp_avg_sq, 1.0)", (OPTIM,)),
    Mutant("clip-norm-scales-up", "per-tensor norm clipping also scales up the tensors "
           "under the bound", HOGWILD,
           "factors = torch.where(over, (bound / (norms + 1e-6)).clamp(max=1.0), 1.0)",
           "factors = torch.where(over, bound / (norms + 1e-6), 1.0)", (OPTIM,)),
    Mutant("clip-global-norm-is-a-sum", "the global gradient norm is the sum of the tensors' "
           "norms", HOGWILD, "global_norm = torch.linalg.vector_norm(norms, dim=1)\n",
           "global_norm = norms.sum(dim=1)\n", (OPTIM,)),
    Mutant("lr-not-clamped", "the annealed learning rate goes negative after T_max",
           HOGWILD, "max(0.0, 1.0 - global_step / args.total_timesteps)",
           "(1.0 - global_step / args.total_timesteps)", (OPTIM,)),
    # --- checkpoints and --resume ------------------------------------------------------------
    Mutant("checkpoint-rmsprop-stats-zeroed", "a checkpoint holds zeros for RMSprop's mean "
           "square", HOGWILD, 'return {"square_avg": [s.clone() for s in self.square_avg]}',
           'return {"square_avg": [torch.zeros_like(s) for s in self.square_avg]}',
           (CKPT, RES)),
    Mutant("checkpoint-adam-step-zeroed", "a checkpoint holds 0 for Adam's step count",
           HOGWILD, '"step_count": self.step_count.clone(),',
           '"step_count": torch.zeros_like(self.step_count),', (CKPT, RES)),
    Mutant("resume-optimizer-not-restored", "--resume keeps fresh optimizer statistics, not "
           "the checkpoint's", CHECKPOINTS,
           "shared.optimizer.load_state_dict(checkpoint.optimizer)",
           "shared.optimizer.load_state_dict(shared.optimizer.state_dict())", (CKPT, RES)),
    Mutant("resume-global-step-reset", "--resume starts again from global step 0", CHECKPOINTS,
           "shared.base_step[0] = checkpoint.global_step", "shared.base_step[0] = 0",
           (CKPT, RES)),
    Mutant("worker-ending-early-not-a-failure", "a worker that exits 0 before T_max ends "
           "the run as done, not failed", SUPERVISION,
           'early = name == "evaluator" or global_step < total',
           'early = name == "evaluator" or global_step < 0 * total', (SUPERVISION_T,)),
    Mutant("evaluation-lstm-state-rows-shifted", "an LSTM's evaluation keeps the state rows "
           "by position when an episode ends, so the episodes still running swap states",
           EVALUATION,
           "state = tuple(s[[running.index(i) for i in still_running]] for s in state)",
           "state = tuple(s[: len(still_running)] for s in state)", (EVALUATION_T,)),
    Mutant("evaluation-at-t-max-twice", "the update that reaches T_max exactly hands the "
           "evaluator an evaluation of its own besides the run's final one", SNAPSHOTS,
           "evaluate = step < self.total", "evaluate = step <= self.total", (TRAIN, BATCH_T)),
    Mutant("resume-of-a-run-ended-at-t-max-runs-again", "a run that ended exactly at T_max is "
           "not finished when resumed: it evaluates its end again", RUN,
           "    return step >= args.total_timesteps and",
           "    return step > args.total_timesteps and", (TRAIN,)),
    Mutant("resume-drops-pending-evaluations", "a resumed run drops the evaluations its "
           "checkpoint left pending (the evaluator was behind when the run stopped)", RUN,
           "pending = list(checkpoint.pending_evaluations) if checkpoint else []",
           "pending = []", (TRAIN,)),
    Mutant("resume-evaluates-a-logged-step-again", "a resumed run takes again an evaluation "
           "the killed run logged after its checkpoint", RUN,
           "pending = [request for request in pending if request[0] not in logged]",
           "pending = [request for request in pending if request[0] not in logged or True]",
           (TRAIN,)),
    Mutant("evaluator-behind-announced-too-late", "the console says that the evaluator is "
           "behind only when it is ten times as far behind", RUN,
           "if len(pending) > LATE and not behind[0]:",
           "if len(pending) > 10 * LATE and not behind[0]:", (TRAIN,)),
    Mutant("evaluator-behind-announced-at-each-request", "the console says that the evaluator "
           "is behind again at each evaluation it is handed", RUN,
           "behind[0] = len(pending) > LATE", "behind[0] = False", (TRAIN,)),
    Mutant("evaluator-behind-checked-after-the-drain-only", "the main process checks whether "
           "the evaluator is behind only after a whole drain, which may write checkpoints for "
           "seconds while the evaluator catches up", RUN,
           "                take_results()  # at each request: one drain may write checkpoints "
           "for seconds\n",
           "", (TRAIN,)),
    Mutant("resume-accepts-changed-flag", "--resume silently ignores a changed flag that "
           "changes the experiment", RESUME,
           "for name in sorted(given - set(COMMAND_LINE_ONLY)):",
           "for name in sorted(given & set(RESUMABLE)):", (RES,)),
    # --- Catch (catch.py) --------------------------------------------------------------------
    Mutant("catch-wall-clamps", "the ball stops at a wall instead of reflecting", CATCH,
           "col = col - 2 * (col - (self.grid_size - 1)) * right - 2 * col * left",
           "col = col - (col - (self.grid_size - 1)) * right - col * left", (CATCH_T,)),
    Mutant("catch-left-wall-keeps-speed", "a bounce off the left wall keeps the ball's "
           "speed", CATCH, "return col, vx - 2 * vx * (right | left)",
           "return col, vx - 2 * vx * right", (CATCH_T,)),
    Mutant("catch-paddle-short-of-right-edge", "the paddle cannot reach its rightmost "
           "position", CATCH, "(target >= self.paddle_min) & (target <= self.paddle_max)",
           "(target >= self.paddle_min) & (target < self.paddle_max)", (CATCH_T,)),
    Mutant("catch-paddle-off-grid", "the paddle's centre may go to the grid's edge, half "
           "the paddle off the grid", CATCH,
           "(target >= self.paddle_min) & (target <= self.paddle_max)",
           "(target >= 0) & (target <= self.grid_size - 1)", (CATCH_T,)),
    Mutant("catch-narrow-catch", "a ball on the paddle's outer cells is not caught", CATCH,
           "return abs(ball_col - paddle) <= self.paddle_half",
           "return abs(ball_col - paddle) < self.paddle_half", (CATCH_T,)),
    Mutant("catch-ball-speed-range", "the ball's start speed is never +2", CATCH,
           "(u[..., 1] * (2 * MAX_BALL_SPEED + 1))", "(u[..., 1] * (2 * MAX_BALL_SPEED))",
           (CATCH_T,)),
    Mutant("catch-vector-reward-unguarded", "the vector env rewards a game whose ball is over "
           "the paddle before it reaches the paddle's row", CATCH,
           "rewards[terminated & self.rules.caught(self.ball_col, self.paddle)] = 1.0",
           "rewards[self.rules.caught(self.ball_col, self.paddle)] = 1.0", (CATCH_T,)),
    # --- the thesis's preprocessing (wrappers.py) ---------------------------------------------
    Mutant("atari-native-no-maxpool", "the native ALE env's frames are not max-pooled over "
           "the last two", WRAPPERS, "            frameskip=4,\n",
           "            frameskip=4,\n            maxpool=False,\n", (WRAP_T,)),
    Mutant("atari-native-clip-drops-negative", "the native env clips rewards to [0, 1]",
           WRAPPERS, "rewards = np.clip(rewards, -1.0, 1.0)",
           "rewards = np.clip(rewards, 0.0, 1.0)", (WRAP_T,)),
    Mutant("atari-clip-drops-negative", "make_env clips rewards to [0, 1]", WRAPPERS,
           "env = ClipReward(env, -1.0, 1.0)", "env = ClipReward(env, 0.0, 1.0)", (WRAP_T,)),
    Mutant("catch-stack-leaks-across-episodes", "Catch's frame stack keeps the last "
           "episode's frames after an autoreset", WRAPPERS,
           "self._stack[ended] = obs[ended][:, None]", "self._stack[ended, -1] = obs[ended]",
           (WRAP_T,)),
    Mutant("atari-native-stack-leaks-across-episodes", "the native env's frame stack keeps "
           "the last episode's frames after an autoreset", WRAPPERS,
           "self._stack[ended] = obs[ended]  # the next", "self._stack[ended, -1] = obs[ended, 0]"
           "  # the next", (WRAP_T,)),
    # --- the batched backend: each run its own learning rate, clipping, streams ----------------
    Mutant("batched-one-learning-rate", "every run of a batch learns at run 0's learning rate",
           BATCHED_BACKEND, "torch.tensor([args.learning_rate for args in self.args],",
           "torch.tensor([self.args[0].learning_rate for args in self.args],", (BATCH_T,)),
    Mutant("batched-clip-across-runs", "global-norm clipping scales each run by the largest "
           "norm in the batch, not its own", HOGWILD,
           "global_norm = torch.linalg.vector_norm(norms, dim=1)\n",
           "global_norm = torch.linalg.vector_norm(norms, dim=1).max().expand(len(norms))\n",
           (BATCH_T, OPTIM)),
    Mutant("batched-one-action-stream", "every run draws its actions from run 0's generator",
           BATCHED_BACKEND, "np.stack([rng.random(UNIFORM_BLOCK) for rng in self.rngs], axis=1)",
           "np.stack([self.rngs[0].random(UNIFORM_BLOCK) for _ in self.rngs], axis=1)",
           (BATCH_T,)),
    Mutant("batched-one-evaluation-stream", "every run's evaluation plays run 0's episodes",
           BATCHED_BACKEND,
           "evaluate_network(self.eval_model, self.eval_envs, self.step_count, self.args[i])",
           "evaluate_network(self.eval_model, self.eval_envs, self.step_count, self.args[0])",
           (BATCH_T,)),
    Mutant("batched-rmsprop-no-decay", "the batch's RMSprop statistics never decay (rho = 1)",
           HOGWILD, "torch._foreach_mul_(self.square_avg, self.decay)",
           "torch._foreach_mul_(self.square_avg, 1.0)", (BATCH_T, OPTIM)),
    Mutant("batched-parse-names-the-rule", "a run flag the script refuses is named by tyro's "
           "ASCII rule, not its message", TOOLS_INIT,
           """(line and set(line) <= set("-─━╰╯ "))]""",
           """(line and set(line) <= set("─━╰╯ "))]""", (BATCH_T,)),
    Mutant("batched-k-envs-as-one", "a run with K = 4 envs per worker is batched, silently as "
           "K = 1", BATCHABLE, '"envs_per_worker": ("1", lambda v: v == 1),',
           '"envs_per_worker": ("1", lambda v: v >= 1),', (BATCH_T,)),
    Mutant("batched-one-wall-clock", "every run resumed in a batch goes on from run 0's "
           "checkpoint wall time", BATCHED_BACKEND,
           "self.wall_offsets[i] = checkpoint.wall_time",
           "self.wall_offsets[i] = checkpoints[0].wall_time", (BATCH_T,)),
    Mutant("batched-one-episode-step", "runs resuming at one global step but at different steps "
           "of their episodes are one batch", BATCHED_SWEEP,
           "group = groups.setdefault((start, episode_row(checkpoint)), [])",
           "group = groups.setdefault((start, BALL_START_ROW), [])", (BATCH_T,)),
    Mutant("batched-stopped-by-sigint", "a batch stopped by SIGTERM says SIGINT", BATCHED_BACKEND,
           'outcome = f"stopped by {stopped_by}" if stopped_by else "done"',
           'outcome = "stopped by SIGINT" if stopped_by else "done"', (BATCH_T,)),
    Mutant("batched-cudnn-free", "cuDNN may pick nondeterministic algorithms for a batch on CUDA",
           BATCHED_BACKEND, "torch.backends.cudnn.deterministic = True",
           "torch.backends.cudnn.deterministic = False", (BATCH_T,)),
    Mutant("batched-lone-run-alone", "a run alone in a batch computes as a batch of one, whose "
           "kernels part from a batch of two's in the last bits", BATCHED_BACKEND,
           "        if len(runs) == 1:\n", "        if len(runs) == 0:\n",
           ("tests/test_batched_invariance.py", BATCH_T)),
    Mutant("checkpoint-catch-values-unchecked", "a checkpoint's Catch ball may sit one column "
           "right of the board (it reaches the env)", ("agents/a3c_runtime/catch_state.py",),
           "ball_col: per_env(0, RULES.grid_size - 1)", "ball_col: per_env(0, RULES.grid_size)",
           ("tests/test_checkpoint_env_state.py",)),
    Mutant("checkpoint-newest-frame-not-drawn", "a checkpoint's Catch stacks load with a blank "
           "newest frame (the canvas is not drawn from the positions)",
           ("agents/a3c_runtime/catch_state.py",), ".scatter_(1, drawn, 255)",
           ".scatter_(1, drawn, 0)", ("tests/test_checkpoint_env_state.py",)),
    Mutant("checkpoint-generator-increment-short", "a checkpoint's generator loads with its "
           "increment's top byte lost", ("agents/a3c_runtime/catch_state.py",),
           '"inc": word(data[16:32])}', '"inc": word(data[16:31])}',
           ("tests/test_checkpoint_env_state.py",)),
    Mutant("convert-moved-flag-kept", "a thesis script's checkpoint with a chapter-8 flag set "
           "converts as the thesis script's, which cannot play it",
           ("agents/a3c_tools/convert_checkpoint.py",), 'MOVED_FLAGS.get(fields["script"], {})',
           'MOVED_FLAGS.get(fields["script"][1:], {})',
           ("tests/test_checkpoint_env_state.py", "tests/test_future_work.py")),
    # --- the sweep: run i's seed and sampled flags -----------------------------------------------
    Mutant("sweep-restarts-cut-off-run", "a sweep started again runs a cut-off run from its "
           "start, not on from its checkpoint", SWEEP,
           'command = [command[0], "--resume", str(checkpoint), *split_elsewhere(command[1:])[1]]',
           "command = [*command]",
           ("tests/test_atari_figures.py", SWEEP_T)),
    Mutant("atari-figure-default-seed", "an Atari figure names a line's runs by sweep.py's "
           "default seeds, not the seed its sweep ran from (a campaign item's own)",
           ATARI_FIGURES, "first = line_seed(folder)", "first = SEED",
           ("tests/test_atari_figures.py",)),
    Mutant("sweep-run-autogroup-unniced", "a run, a session of its own, takes the CPU at "
           "autogroup nice 0 whatever the sweep's group was niced to", SWEEP,
           "AUTOGROUP.write_text(str(autogroup))", "AUTOGROUP.write_text(str(0 * autogroup))",
           (SWEEP_T,)),
    Mutant("atari-figure-curve-waits-for-every-run", "an Atari figure's curve stops where its "
           "least advanced run is (a run under way ends the line at step 0)", ATARI_FIGURES,
           "if len(rows) == full}", "if len(rows) <= full}", ("tests/test_atari_figures.py",)),
    Mutant("sweep-seeds-adjacent", "a sweep's run seeds are 1 apart, not 1000 (worker seeds of "
           "neighbouring runs collide)", SWEEP, "SEED_STRIDE = 1000  # run i", "SEED_STRIDE = 1  "
           "# run i", (SWEEP_T,)),
    Mutant("sweep-samples-one-stream", "every run of a sweep samples run 0's flag values",
           SWEEP, 'rng = random.Random(f"sweep-{sweep_seed}-run-{index}")',
           'rng = random.Random(f"sweep-{sweep_seed}-run-{0 * index}")', (SWEEP_T,)),
    # --- what a plan may name ---------------------------------------------------------------
    Mutant("plan-script-unchecked", "a plan's script is taken as an agent script whatever it "
           "names", TOOLS, "resolved = (ROOT / value).resolve()",
           'resolved = (AGENTS / "a3c_ff.py").resolve()', (CAMPAIGN_T,)),
    Mutant("plan-folder-anywhere", "a plan's folder may lie anywhere on the machine", TOOLS,
           'if not (root / value).resolve().is_relative_to((root / "results").resolve()):',
           'if not (root / value).resolve().is_relative_to(Path("/")):', (CAMPAIGN_T, CONFIRM_T)),
    # --- the statistics of the claims page and the confirmatory study --------------------------
    Mutant("t-test-one-sided", "the paired t test's p-value is one-sided (halved)", PAIRED,
           "return float(2 * stats.t.sf(gap / se, n - 1))",
           "return float(stats.t.sf(gap / se, n - 1))", (COMPARE_T, CLAIMS_T)),
    Mutant("t-interval-biased-spread", "the t interval takes the spread with ddof 0", PAIRED,
           "half = t_quantile(n, confidence) * d.std(axis=-1, ddof=1)",
           "half = t_quantile(n, confidence) * d.std(axis=-1, ddof=0)", (COMPARE_T, CLAIMS_T)),
    Mutant("t-quantile-degrees", "the t quantile of n pairs takes n degrees of freedom, not "
           "n - 1", PAIRED, "q[2:] = stats.t.ppf(0.5 + confidence / 2, n[2:] - 1)",
           "q[2:] = stats.t.ppf(0.5 + confidence / 2, n[2:])", (COMPARE_T, CLAIMS_T)),
    Mutant("holm-as-bonferroni", "Holm's step-down multiplies every p by m (Bonferroni)",
           PAIRED, "running = max(running, min(1.0, (m - rank) * p_values[i]))",
           "running = max(running, min(1.0, (m - 0 * rank) * p_values[i]))",
           (CLAIMS_T, CONFIRM_T)),
    Mutant("holm-not-monotone", "Holm's adjusted p-values lose their running maximum", PAIRED,
           "running = max(running, min(1.0, (m - rank) * p_values[i]))",
           "running = min(1.0, (m - rank) * p_values[i])", (CLAIMS_T, CONFIRM_T)),
    Mutant("power-one-sided-level", "the power of the two-sided test uses the one-sided "
           "quantile", PAIRED, "q = stats.t.ppf(1 - alpha / 2, df)",
           "q = stats.t.ppf(1 - alpha, df)", (CONFIRM_T, CLAIMS_T)),
    Mutant("comparable-far-edge", "a comparable claim is tested against the band's far edge",
           PAIRED, "edge = margin if d.mean() >= 0 else -margin",
           "edge = -margin if d.mean() >= 0 else margin", (CLAIMS_T, CONFIRM_T)),
    Mutant("confirmatory-comparable-always-reproduced", "a comparable claim that its test "
           "decides is reproduced on whichever side of the band its effect lies", CONFIRMATORY,
           'verdict = "reproduced" if abs(effect) < MARGIN else "contradicted"',
           'verdict = "reproduced" if abs(effect) >= 0 else "contradicted"', (CONFIRM_T,)),
    Mutant("confirmatory-atari-failed-never-in", "a failed Atari run of the study never counts "
           "as in, so the one look waits for ever", CONFIRMATORY, "failed.add(seed)",
           "ok.discard(seed)", (CONFIRM_T,)),
    Mutant("confirmatory-atari-failed-pair-kept", "a study's Atari run that its line records "
           "as failed is paired all the same where its table has its score (amended 2026-12-02, "
           "when the look moved from the figure's table to the lines' own)", CONFIRMATORY,
           'if row.get("status") != "ok" or (wanted is not None and seed not in wanted):',
           'if row.get("status") == "?" or (wanted is not None and seed not in wanted):',
           (CONFIRM_T,)),
    Mutant("confirmatory-atari-any-steps", "an Atari run counts as in at any steps, a shorter "
           "run taken for a finished one", CONFIRMATORY,
           'elif int(row.get("final_step") or 0) >= int(spec["steps"]):',
           'elif int(row.get("final_step") or 0) >= 0 * int(spec["steps"]):', (CONFIRM_T,)),
    Mutant("confirmatory-early-look", "the confirmatory study's one look is taken once any "
           "claim's runs are in, not all", CONFIRMATORY,
           'if not all(complete(c["test"], c["runs"]) for c in claims):',
           'if not any(complete(c["test"], c["runs"]) for c in claims):', (CONFIRM_T,)),
    Mutant("claims-answer-without-study-verdict", "the answer's table takes the exploratory "
           "rows' word where the study has answered the conclusion", THESIS_CLAIMS,
           "if names and len(read) == len(names):", "if names and len(read) == len(names) + 1:",
           (CONFIRM_T, STUDY_T)),
    Mutant("equivalence-power-both-tails", "a comparable verdict's power adds the chance below the "
           "band's low edge to the chance inside it", PAIRED,
           "return 0.5 * (math.erfc(-upper / SQRT2) - math.erfc(-lower / SQRT2))",
           "return 0.5 * (math.erfc(-upper / SQRT2) + math.erfc(-lower / SQRT2))", (STUDY_T,)),
    Mutant("reading-comparable-inside-band", "an inconclusive comparable claim whose interval "
           "straddles the band's edge reads 'not comparable'", STUDY_READING,
           "if outcome.low > MARGIN or outcome.high < -MARGIN:",
           "if outcome.high > MARGIN or outcome.high < -MARGIN:", (STUDY_T,)),
    Mutant("reading-study-power-at-pilot-spread", "the sensitivity power is computed at the "
           "pilot's spread, not the study's", STUDY_READING,
           "at_study = power(abs(effect), study_spread, runs, level)",
           "at_study = power(abs(effect), planned.spread, runs, level)", (STUDY_T,)),
    Mutant("planning-spread-lower-limit", "the next study is sized for the lower confidence "
           "limit of its pilots' spread", CONFIRMATORY,
           "return spread * math.sqrt(df / stats.chi2.ppf(1 - float(confidence), df))",
           "return spread * math.sqrt(df / stats.chi2.ppf(float(confidence), df))", (STUDY_T,)),
    Mutant("claims-study-points-all-reproduced", "the forest plot draws every claim of the "
           "study as reproduced, whatever its verdict", THESIS_CLAIMS,
           "points.append(Point(STUDY_SECTION, name, effect, low, high, o.verdict,",
           'points.append(Point(STUDY_SECTION, name, effect, low, high, "reproduced",',
           (CONFIRM_T,)),
    # --- the campaign runner, the run folder and the run log (run machinery) -----------------
    Mutant("campaign-goes-on-after-sigterm", "a campaign whose sweep was stopped by a signal "
           "(exit 130) goes on to the next sweep instead of stopping", CAMPAIGN,
           "if code in (2, 130):", "if code in (2,):", (CAMPAIGN_T,)),
    Mutant("campaign-reruns-a-done-sweep", "a sweep that already holds its runs is started "
           "again (and logged) at every campaign start", CAMPAIGN,
           "if before >= sweep.runs:", "if before > sweep.runs:", (CAMPAIGN_T,)),
    Mutant("campaign-batchable-first", "--batchable-last runs the sweeps a GPU could batch "
           "first, not last", CAMPAIGN, "[s for s in item.sweeps if batchable(s) == second]",
           "[s for s in item.sweeps if batchable(s) != second]", (CAMPAIGN_T,)),
    Mutant("campaign-local-runs-batched", "a campaign on the process backend runs its Catch "
           "sweeps batched all the same", CAMPAIGN,
           'elif backend == "batched" and batchable(sweep):', "elif batchable(sweep):",
           (CAMPAIGN_T,)),
    Mutant("campaign-progress-counts-first-look", "the progress counts a line's runs from before "
           "the plan as the plan's own", CAMPAIGN,
           "new_rows = rows[sweep.first_look :][: sweep.runs - sweep.first_look]",
           "new_rows = rows[: sweep.runs - sweep.first_look]", (CAMPAIGN_T,)),
    Mutant("campaign-batched-cost-per-run", "a batched line's CPU-hours count the batch's wall "
           "time once per run", CAMPAIGN, "cost = [c / max(sweep.runs, 1) for c in cost]",
           "cost = [c / max(1, 1) for c in cost]", (CAMPAIGN_T,)),
    Mutant("campaign-wall-time-double-counts", "an item's wall time counts sweeps side by side "
           "twice", CAMPAIGN, "total += max(0.0, end - max(start, reached))",
           "total += max(0.0, end - start)", (CAMPAIGN_T,)),
    Mutant("campaign-log-row-added-again", "a running sweep's SWEEPS.tsv row is added again at "
           "each update instead of kept current", CAMPAIGN,
           'lines[mine[-1]] = "\\t".join(row) + "\\n"',
           'lines.insert(mine[-1] + 1, "\\t".join(row) + "\\n")', (CAMPAIGN_T,)),
    Mutant("campaign-extend-other-seed", "an extended line's new runs take the default sweep "
           "seed, not the line's own, so its run i is not the run it drew before", CAMPAIGN,
           'command += ["--seed", str(config["seed"])]', 'command += ["--seed", "1"]',
           (CAMPAIGN_T,)),
    Mutant("campaign-exit-0-unfinished", "a campaign that ends with its plan unfinished exits 0",
           CAMPAIGN, "return 1 if failed else 0 if finished else 1",
           "return 1 if failed else 0 if finished is not None else 1", (CAMPAIGN_T,)),
    Mutant("campaign-bf16-gate-inverted", "an item that needs native bf16 runs only where the "
           "CPU lacks it", CAMPAIGN, "if item.needs_native_bf16 and not native_bf16():",
           "if item.needs_native_bf16 and native_bf16():", (CAMPAIGN_T,)),
    Mutant("campaign-atari-figure-not-drawn", "an Atari item's figure table is not drawn after "
           "its sweep, so the claims page reads stale runs", CAMPAIGN,
           "failed |= execute(item.draw)[0] != 0\n            # an item",
           "failed |= False\n            # an item", (CAMPAIGN_T,)),
    Mutant("run-folder-mixes-runs", "a new run goes into a folder that holds another run",
           RUN_FOLDER, "            check_no_run_in(path)\n",
           "            check_no_run_in(path / \"none\")\n", (RUN_FOLDER_T,)),
    Mutant("run-folder-shared-lock", "two processes can train into one run folder at once",
           RUN_FOLDER, "fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)",
           "fcntl.lockf(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)", (RUN_FOLDER_T,)),
    Mutant("run-log-drops-checkpoint-step-row", "a resumed run drops the evaluation row of its "
           "checkpoint's own step", RUN_LOG, "if int(line.split(\",\", 1)[0]) <= step]",
           "if int(line.split(\",\", 1)[0]) < step]", (RUN_LOG_T, RES)),
    Mutant("run-log-half-row-kept", "a row of evaluations.csv whose write failed is left half "
           "written", RUN_LOG, "os.ftruncate(self.csv_fd, size)",
           "os.ftruncate(self.csv_fd, max(size, os.fstat(self.csv_fd).st_size))",
           (RUN_LOG_T,)),
    Mutant("run-log-wall-time-from-resume", "a resumed run's wall time leaves out the time "
           "before its resume (the campaign's CPU-hours read it)", RUN_LOG,
           "return self.wall_offset + time.time() - self.start",
           "return time.time() - self.start", (RUN_LOG_T, RES)),
    Mutant("run-log-no-purge", "a resumed run's TensorBoard shows the killed run's scalars after "
           "the checkpoint twice", RUN_LOG,
           "purge_step=resumed_step + 1 if resumed_step else None",
           "purge_step=resumed_step + 1 if resumed_step < 0 else None",
           (RUN_LOG_T, RES)),
    Mutant("run-log-progress-totals", "a progress line logs the run's totals since its start "
           "as its interval's", RUN_LOG,
           "stats = dict(zip(Shared.STATS, (stats - last_stats).tolist(), strict=True))",
           "stats = dict(zip(Shared.STATS, (stats - last_stats * 0).tolist(), strict=True))",
           (RUN_LOG_T,)),
    Mutant("run-log-progress-interval-kept", "the interval of a progress line is not restarted "
           "by it: a line at every check after the first", RUN_LOG,
           "self.last_progress = (now, global_step, stats.double().clone())",
           "self.last_progress = (last_time, global_step, stats.double().clone())", (RUN_LOG_T,)),
    Mutant("batched-progress-run-0-stats", "every run of a batch logs run 0's losses",
           BATCHED_BACKEND, "stats = batch.stats.cpu()",
           "stats = batch.stats.cpu()[[0] * len(logs)]", (BATCH_T,)),
    Mutant("clear-run-folder-drops-lock", "a partial run's folder is emptied with its lock file: "
           "two processes may then lock it at once", RUN_LOCK, "if path.name == RUN_LOCK:",
           "if path.name == RUN_LOCK * 2:", (SWEEP_T,)),
    Mutant("clear-run-folder-through-link", "a link to a folder in a partial run's folder is "
           "removed as a folder (which rmtree refuses: the sweep fails there)", RUN_LOCK,
           "if path.is_dir() and not path.is_symlink():", "if path.is_dir():", (SWEEP_T,)),
    Mutant("precision-auto-bf16-at-one-env", "--precision auto computes in bf16 at one env a "
           "worker (the thesis's algorithm, fp32 on every CPU)", FLAGS,
           'return "bf16" if envs_per_worker > 1 and native_bf16() else "fp32"',
           'return "bf16" if envs_per_worker >= 1 and native_bf16() else "fp32"',
           (FLAGS_T, PRECISION_T)),
    Mutant("precision-bf16-learn-acts-in-bf16", "--precision bf16-learn acts in bf16 too",
           FLAGS, 'enabled=precision == "bf16"),', 'enabled=precision != "fp32"),',
           (PRECISION_T, FLAGS_T)),
    Mutant("flags-beyond-checkpoint-bounds", "a run takes counts and sizes its checkpoints "
           "cannot hold (--eval-episodes 10001: it fails at its first checkpoint)", FLAGS,
           "    check_within_checkpoint_bounds(args)\n", "", (FLAGS_T,)),
    Mutant("checkpoint-interval-not-eval", "the checkpoint interval defaults to a fixed step "
           "count, not the evaluation interval", FLAGS,
           "args.checkpoint_interval = args.eval_interval",
           "args.checkpoint_interval = 100_000", (FLAGS_T, RES)),
    Mutant("sweep-score-counts-step-0", "a run's score counts the untrained network's "
           "evaluation at step 0 among its final 5", SWEEP,
           'if row.get("global_step") != "0"]', 'if row.get("global_step") != "none"]',
           (SWEEP_T,)),
    Mutant("sweep-score-final-6", "a run's score is the mean of its final 6 evaluations, not 5",
           SWEEP, "final = (trained or returns)[-SCORE_LAST:]",
           "final = (trained or returns)[-SCORE_LAST - 1 :]", (SWEEP_T,)),
    Mutant("sweep-resumed-wall-time-last-part", "a resumed run's wall time in results.csv is "
           "its last part's only (the campaign's CPU-hours read it)", SWEEP,
           'round(max(result["wall_time_s"], scores.pop("clock_s")), 2)',
           'round(min(result["wall_time_s"], scores.pop("clock_s")), 2)', (SWEEP_T,)),
    Mutant("sweep-interrupted-run-recorded", "a run the sweep stopped (Ctrl-C, SIGTERM) is "
           "recorded as failed, so it never resumes", SWEEP,
           'if result["interrupted"] or result.get("in_use"):', 'if result.get("in_use"):',
           (SWEEP_T,)),
    Mutant("sweep-stopped-run-taken-for-finished", "a run that a signal stopped before its "
           "budget (its own last line says so) is recorded as ok", SWEEP,
           'elif stdout_lines and stdout_lines[-1].startswith("stopped by"):',
           'elif stdout_lines and stdout_lines[-1].startswith("stopped by nothing"):',
           (SWEEP_T,)),
    Mutant("sweep-stopped-exits-0", "a sweep stopped by a signal exits 0, taken for a finished "
           "one", SWEEP, "start again to finish\", flush=True)\n        return 130",
           "start again to finish\", flush=True)\n        return 0", (SWEEP_T, CAMPAIGN_T)),
    Mutant("sweep-auto-precision-foreign", "a --precision auto run begun on another host is "
           "taken for another run's checkpoint and refused", SWEEP,
           'skip = ("precision",) if getattr(given, "precision", None) == "auto" else ()',
           "skip = ()", ("tests/test_safe_loading.py", SWEEP_T)),
    # --- issue 103: a file from someone else is data by construction ----------------------------
    Mutant("resume-predated-flag-takes-given-value", "--resume takes a flag the checkpoint "
           "predates from the command line, so a changed non-resumable one (--rms-init 1) is "
           "accepted silently", RESUME,
           "values[name] = trained[name] if name in trained else getattr(agent.Args(), name)",
           "values[name] = trained[name] if name in trained else getattr(args, name)", (RES,)),
    Mutant("resume-predated-flag-not-compared", "--resume accepts a changed non-resumable flag "
           "silently where the checkpoint predates it", RESUME,
           "        if name not in RESUMABLE:\n",
           "        if name not in RESUMABLE and name in checkpoint.args:\n", (RES,)),
    Mutant("checkpoint-script-name-prefix-only", "a checkpoint's script passes the gate when "
           "it only begins with an agent script's name (a3c_ff.py/../../elsewhere.py)",
           CHECKPOINTS, 'if raw["script"] and not SCRIPT_NAME.fullmatch(raw["script"]):',
           'if raw["script"] and not SCRIPT_NAME.match(raw["script"]):',
           ("tests/test_safe_loading.py", CKPT)),
    Mutant("checkpoint-one-finite-weight-passes", "the gate looks at each tensor's first weight "
           "only: a NaN among finite weights is loaded",
           ("agents/a3c_runtime/checkpoint_file.py",), "torch.aminmax(tensor)",
           "torch.aminmax(tensor.flatten()[:1])", ("tests/test_safe_loading.py", CKPT)),
    # --- issue 104: --evaluate stopped by a signal, and its thread count ------------------------
    Mutant("evaluate-sigterm-kills", "--evaluate takes Ctrl-C but not SIGTERM: `kill` ends it "
           "with no report of the episodes that ended", EVALUATION,
           "for s in (signal.SIGINT, signal.SIGTERM)}", "for s in (signal.SIGINT,)}",
           (EVALUATION_T,)),
    Mutant("evaluate-all-threads", "--evaluate plays on every core's thread, not on one as the "
           "run's evaluations do (6x slower on a shared CPU)", EVALUATION,
           "    torch.set_num_threads(1)\n    checkpoint = load_checkpoint(",
           "    checkpoint = load_checkpoint(", (EVALUATION_T,)),
    # --- issue 103: checkpoints as safetensors with a declared document ----------------------
    Mutant("checkpoint-negative-mean-square-passes", "a checkpoint's RMSprop mean squares of -1 "
           "pass the gate (the update's root of them is NaN)",
           ("agents/a3c_runtime/checkpoint_file.py",),
           "if name.startswith(squares) and bool((tensor < 0).any()):",
           "if name.startswith(squares) and bool((tensor < -1).any()):",
           ("tests/test_safe_loading.py",)),
    Mutant("checkpoint-lstm-cells-unbounded", "a checkpoint's --lstm-cells 10**9 passes the "
           "gate's bounds", FLAGS,
           "lstm_cells: within(1, 16_384) = None", "lstm_cells: within(1, 10**12) = None",
           ("tests/test_safe_loading.py",)),
    Mutant("batched-learning-rate-not-annealed", "the batch's learning rates stay at their "
           "initial values (--anneal-lr ignored)", BATCHED_BACKEND,
           "factor = annealed_lr(dataclasses.replace(a, learning_rate=1.0), self.step_count)",
           "factor = annealed_lr(dataclasses.replace(a, learning_rate=1.0), 0)", (BATCH_T,)),
    Mutant("stacked-convs-weight-order", "the matmul convolution reads its weight's rows and "
           "columns swapped", STACKED_CONVS, "weight = weight.permute(0, 2, 4, 3, 5, 1).flatten(1)",
           "weight = weight.permute(0, 4, 2, 5, 3, 1).flatten(1)",
           ("tests/test_stacked_convs.py", BATCH_T)),
    Mutant("stacked-convs-blocks-swapped", "the matmul convolution takes the block below for the "
           "block right of a cell", STACKED_CONVS,
           "(blocks[..., :-1, :-1, :], blocks[..., :-1, 1:, :],",
           "(blocks[..., :-1, :-1, :], blocks[..., 1:, :-1, :],",
           ("tests/test_stacked_convs.py", BATCH_T)),
    Mutant("torch-catch-device-row-kept", "the device's ball row is not reset when a game "
           "starts again (the frames draw the ball off the grid)", TORCH_CATCH,
           "self._ball_row[index] = BALL_START_ROW", "self._ball_row[index] += 0", (BATCH_T,)),
    Mutant("returns-not-done-where-done", "an episode's end leaks the next episode's return back "
           "(the returns' choice by the dones inverted for the bootstrap)", THESIS,
           "g = rewards[t] + gamma * (dones[t] * done_values[t] + ~dones[t] * g)",
           "g = rewards[t] + gamma * (dones[t] * done_values[t] + dones[t] * g)",
           ("tests/test_batched_actors.py", BATCH_T)),

    Mutant("batched-precision-ignored", "a batch opted into bf16 computes in fp32 all the same",
           BATCHED_BACKEND, "            self.precision, self.device.type\n",
           '            "fp32" if self.precision else "bf16", self.device.type\n', (BATCH_T,)),
    Mutant("batched-tf32-on-a-cpu", "a batch on the CPU takes --precision tf32 (and computes "
           "fp32, saying tf32)", BATCHED_BACKEND,
           'if self.precision == "tf32" and self.device.type != "cuda":',
           'if self.precision == "tf32" and self.device.type == "mps":', (BATCH_T,)),
]
# fmt: on


def check_list(mutants: list[Mutant]) -> list[str]:
    """What is wrong with the list: a duplicate id, a snippet not exactly once in a file."""
    problems, seen = [], set()
    for m in mutants:
        if m.id in seen:
            problems.append(f"{m.id}: duplicate id")
        seen.add(m.id)
        if m.original == m.replacement:
            problems.append(f"{m.id}: the replacement is the original")
        for path in m.files:
            count = (ROOT / path).read_text().count(m.original)
            if count != 1:
                problems.append(f"{m.id}: {path} holds the snippet {count} times, not once")
        for path in m.first:
            if not (ROOT / path).is_file():
                problems.append(f"{m.id}: no test file {path}")
    return problems


def tree_files() -> list[str]:
    """The working tree's files that git tracks or would (not ignored)."""
    out = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    return [f for f in out.split("\0") if f and (ROOT / f).is_file()]


def make_scratch() -> Path:
    """A copy of the tree (no .git, runs/, caches): sources copied, results/ hard-linked (the
    tests only read it, and no mutant touches it)."""
    scratch = Path(tempfile.mkdtemp(prefix="mutation_check_"))
    for f in tree_files():
        target = scratch / f
        target.parent.mkdir(parents=True, exist_ok=True)
        if f.startswith("results/"):
            try:
                os.link(ROOT / f, target)
                continue
            except OSError:
                pass
        shutil.copy2(ROOT / f, target)
    return scratch


def run_pytest(scratch: Path, first: tuple[str, ...], timeout: float) -> tuple[str, str, float]:
    """(status, the first failing test or '', seconds): status caught, survived or timeout."""
    # each test file named: pytest folds a file into a folder given with it, losing the order
    rest = sorted(p.relative_to(scratch).as_posix() for p in (scratch / "tests").glob("test_*.py"))
    command = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m",
               "not slow", *first, *(f for f in rest if f not in first)]  # fmt: skip
    env = pytest_env(scratch)
    start = time.monotonic()
    process = subprocess.Popen(
        command,
        cwd=scratch,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        output, _ = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)  # pytest and the processes its tests started
        process.communicate()
        return "timeout", "", time.monotonic() - start
    seconds = time.monotonic() - start
    if process.returncode == 0:
        return "survived", "", seconds
    failed = re.search(r"^(?:FAILED|ERROR) (\S+)", output, re.MULTILINE)
    if failed is None:
        tail = "\n".join(output.strip().splitlines()[-15:])
        return "error", f"pytest exit {process.returncode}, no failing test: {tail}", seconds
    return "caught", failed.group(1), seconds


def pytest_env(scratch: Path) -> dict[str, str]:
    """The environment of the copy's tests: its packages first on the path."""
    env = {**os.environ, "PYTHONPATH": f"{scratch / 'agents'}{os.pathsep}{scratch}"}
    env.pop("PYTEST_ADDOPTS", None)
    return env


def imports_from(scratch: Path) -> str:
    """'' if the copy's python imports a3c_runtime and catch_env from the copy (not from an
    editable install elsewhere), else where it imports them from."""
    code = "import a3c_runtime, catch_env; print(a3c_runtime.__file__); print(catch_env.__file__)"
    result = subprocess.run(
        [sys.executable, "-c", code],
        cwd=scratch,
        env=pytest_env(scratch),
        capture_output=True,
        text=True,
    )
    paths = result.stdout.split()
    if result.returncode != 0 or len(paths) != 2:
        return result.stderr.strip() or "python failed"
    outside = [p for p in paths if not Path(p).resolve().is_relative_to(scratch.resolve())]
    return ", ".join(outside)


def ruff_problems(scratch: Path, files: tuple[str, ...]) -> str:
    """ruff's complaints about the mutated files ('' when clean)."""
    problems = []
    for command in (["ruff", "check", "-q", *files], ["ruff", "format", "--check", "-q", *files]):
        result = subprocess.run(command, cwd=scratch, capture_output=True, text=True)
        if result.returncode != 0:
            problems.append((result.stdout + result.stderr).strip() or " ".join(command))
    return "; ".join(problems)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="ID", help="run only these mutants")
    parser.add_argument("--out", help="also write the report to this file")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per mutant")
    parser.add_argument("--list", action="store_true", help="print the mutants and exit")
    parser.add_argument(
        "--lint-only", action="store_true", help="apply each mutant and run only ruff on it"
    )
    args = parser.parse_args()

    problems = check_list(MUTANTS)
    if problems:
        print("the mutant list is out of date:\n  " + "\n  ".join(problems), file=sys.stderr)
        return 2
    mutants = MUTANTS
    if args.only:
        unknown = sorted(set(args.only) - {m.id for m in MUTANTS})
        if unknown:
            print(f"unknown mutant ids: {', '.join(unknown)}", file=sys.stderr)
            return 2
        mutants = [m for m in MUTANTS if m.id in args.only]
    if args.list:
        for m in mutants:
            print(f"{m.id}: {m.breaks} [{', '.join(m.files)}]")
        return 0

    lines: list[str] = []

    def report(line: str = "") -> None:
        print(line, flush=True)
        lines.append(line)

    began = time.monotonic()
    fast_tier = 'pytest -x -q -p no:cacheprovider -m "not slow"'
    report(f"mutation check: {len(mutants)} mutants, the fast tier ({fast_tier}) in a copy")
    report()
    for m in mutants:
        files = ", ".join(m.files) if len(m.files) < 4 else f"{len(m.files)} scripts"
        report(f"  {m.id}: {m.breaks} [{files}]")
    report()
    scratch = make_scratch()
    try:
        shadowing = imports_from(scratch)
        if shadowing:
            report(f"the copy's tests would not import the copy's packages: {shadowing}")
            return 2
        if not args.lint_only:
            status, failed, seconds = run_pytest(scratch, (), args.timeout)
            if status != "survived":
                report(
                    f"the unmutated tree's fast tier does not pass ({status} {failed}, "
                    f"{seconds:.0f} s): nothing to check against"
                )
                return 2
            report(f"unmutated: the fast tier passes in {seconds:.0f} s")
            report()
        width = max(len(m.id) for m in mutants)
        report(f"{'id':<{width}}  {'result':<8}  {'seconds':>7}  caught by")
        caught = linted = 0
        for m in mutants:
            originals = {path: (scratch / path).read_text() for path in m.files}
            try:
                for path, text in originals.items():
                    (scratch / path).unlink()  # a fresh file, never a shared inode
                    (scratch / path).write_text(text.replace(m.original, m.replacement))
                lint = ruff_problems(scratch, m.files)
                if lint:
                    status, failed, seconds = "invalid", f"not ruff clean: {lint}", 0.0
                elif args.lint_only:
                    status, failed, seconds = "linted", "", 0.0
                else:
                    status, failed, seconds = run_pytest(scratch, m.first, args.timeout)
            finally:
                for path, text in originals.items():
                    (scratch / path).write_text(text)
            caught += status == "caught"
            linted += status == "linted"
            report(f"{m.id:<{width}}  {status:<8}  {seconds:7.1f}  {failed}")
        report()
        if args.lint_only:
            report(f"{linted} of {len(mutants)} mutants ruff clean")
            return 0 if linted == len(mutants) else 1
        report(
            f"{caught} of {len(mutants)} mutants caught by the fast tier "
            f"(in {(time.monotonic() - began) / 60:.1f} min)"
        )
        return 0 if caught == len(mutants) else 1
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
        if args.out:
            out = ROOT / args.out if not Path(args.out).is_absolute() else Path(args.out)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
