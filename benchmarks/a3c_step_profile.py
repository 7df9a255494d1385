"""Where one A3C FF worker's time goes, per env step, on Catch-v0.

    python benchmarks/a3c_step_profile.py [--seconds 20]

One process and one torch thread run the loop of agents/a3c_ff.py's `worker` (sync, act up to
t_max steps, one batched forward and backward, clip, shared RMSprop step) with a timer around
each phase, built from the script's own functions and network. It is a copy of the loop with
timers, not the loop itself: keep the two in step when the worker changes. The phases' shares are
what matters; absolute times depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import importlib.util
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch

SCRIPT = Path(__file__).resolve().parents[1] / "agents" / "a3c_ff.py"
PHASES = ("sync", "act forward", "env step", "learn forward", "backward", "clip", "optimizer")
NETWORK_PHASES = ("act forward", "learn forward", "backward")  # the network's own kernels


def load_a3c():
    spec = importlib.util.spec_from_file_location("a3c_ff", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["a3c_ff"] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def profile(a3c, seconds: float) -> tuple[int, dict[str, float]]:
    """Run the worker loop for `seconds`; returns (env steps, seconds spent in each phase)."""
    args = a3c.resolve_defaults(a3c.Args(num_workers=1))
    env = a3c.make_env(args.env)
    num_actions = env.action_space.n
    model = a3c.ActorCritic(num_actions, args).to(memory_format=torch.channels_last)
    global_model = a3c.ActorCritic(num_actions, args).to(memory_format=torch.channels_last)
    params, global_params = list(model.parameters()), list(global_model.parameters())
    optimizer = a3c.make_optimizer(global_params, args)
    obs_buf = torch.zeros((args.t_max + 1, *env.observation_space.shape), dtype=torch.uint8)
    obs_buf = obs_buf.contiguous(memory_format=torch.channels_last)
    actions = np.zeros(args.t_max, dtype=np.int64)
    rewards = np.zeros(args.t_max, dtype=np.float32)
    rng = random.Random(args.seed)
    obs, _ = env.reset(seed=args.seed)
    obs_buf[0].copy_(torch.from_numpy(obs))
    spent = dict.fromkeys(PHASES, 0.0)
    steps, clock = 0, time.perf_counter
    end = clock() + seconds
    while clock() < end:
        t0 = clock()
        with torch.no_grad():
            torch._foreach_copy_(params, global_params)
        spent["sync"] += clock() - t0
        terminated = truncated = False
        with torch.inference_mode():
            for t in range(args.t_max):
                t1 = clock()
                log_probs, _ = model(obs_buf[t : t + 1])
                action = a3c.sample_action(log_probs[0].exp().tolist(), rng.random())
                t2 = clock()
                obs, reward, terminated, truncated, _ = env.step(action)
                actions[t], rewards[t] = action, reward
                obs_buf[t + 1].copy_(torch.from_numpy(obs))
                spent["act forward"] += t2 - t1
                spent["env step"] += clock() - t2
                if terminated or truncated:
                    break
        n = t + 1
        t3 = clock()
        log_probs, values = model(obs_buf[: n if terminated else n + 1])
        bootstrap = 0.0 if terminated else float(values[n])
        returns = torch.from_numpy(a3c.n_step_returns(rewards[:n], bootstrap, args.gamma))
        loss = a3c.a3c_loss(log_probs[:n], torch.from_numpy(actions[:n]), values[:n], returns,
                            args.ent_coef, args.vf_coef)[0]  # fmt: skip
        t4 = clock()
        grads = torch.autograd.grad(loss, params)
        t5 = clock()
        a3c.clip_gradients(grads, args.grad_clip_mode, args.grad_clip)
        t6 = clock()
        optimizer.step(grads, a3c.annealed_lr(args, steps))
        t7 = clock()
        spent["learn forward"] += t4 - t3
        spent["backward"] += t5 - t4
        spent["clip"] += t6 - t5
        spent["optimizer"] += t7 - t6
        steps += n
        if terminated or truncated:
            obs, _ = env.reset()
            obs_buf[0].copy_(torch.from_numpy(obs))
        else:
            obs_buf[0].copy_(obs_buf[n])
    return steps, spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="how long to run the loop")
    opts = parser.parse_args()
    if opts.seconds <= 0:
        parser.error("--seconds must be > 0")
    torch.set_num_threads(1)
    torch.set_flush_denormal(True)  # as the workers do
    import catch_env  # noqa: F401  (registers Catch-v0)

    steps, spent = profile(load_a3c(), opts.seconds)
    total = sum(spent.values())
    print(f"{steps:,} env steps, {steps / total:,.0f} steps/s in one process")
    for phase, seconds in spent.items():
        print(f"{phase:<14} {seconds / steps * 1e6:8.1f} us/step {seconds / total:6.1%}")
    # the ceiling that removing all per-step Python, copying, sync and optimizer work would reach
    network = sum(spent[phase] for phase in NETWORK_PHASES)
    print(
        f"network forward+backward alone: {network / total:.1%} of the time; with every other "
        f"phase free, at most {steps / network:,.0f} steps/s in one process"
    )


if __name__ == "__main__":
    main()
