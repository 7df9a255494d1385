"""Where one A3C FF worker's time goes, per env step, on Catch-v0 or an ALE game.

    python benchmarks/a3c_step_profile.py [--seconds 20] [--env Catch-v0]
                                          [--envs-per-worker 1] [--precision fp32]

One process and one torch thread run agents/a3c_ff.py's own `worker` loop (sync, act up to t_max
steps, one batched forward and backward, clip, shared RMSprop step) with a PhaseTimer from
agents/a3c_runtime.py, which the loop calls between its phases (training runs pass none, at no
cost per step). "sync" includes the loop's bookkeeping. The phases' shares are what matters;
absolute times depend on the machine and its load. "env step" is the emulator's (or Catch's)
share: the vector env's step, preprocessing and frame stack included.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import threading
from pathlib import Path

import torch

AGENTS = Path(__file__).resolve().parents[1] / "agents"
SCRIPT = AGENTS / "a3c_ff.py"
NETWORK_PHASES = ("act forward", "learn forward", "backward")  # the network's own kernels


def load_a3c():
    sys.path.insert(0, str(AGENTS))  # the script imports its sibling a3c_runtime
    spec = importlib.util.spec_from_file_location("a3c_ff", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["a3c_ff"] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def profile(a3c, seconds: float, **flags) -> tuple[int, dict[str, float]]:
    """Run the worker loop for `seconds` with the given Args `flags`; returns (env steps,
    seconds spent in each phase)."""
    import a3c_runtime as runtime
    import torch.multiprocessing as mp

    args = runtime.resolve_defaults(a3c.Args(num_workers=1, **flags))
    args.total_timesteps = 10**12  # the clock ends the loop
    env = a3c.make_env(args.env)
    num_actions = env.action_space.n
    env.close()
    network = a3c.AGENT.build_network(num_actions, args)
    shared = runtime.Shared(network, args, mp.get_context("fork"))
    timer = runtime.PhaseTimer()
    stop = threading.Timer(seconds, shared.stop.set)
    stop.start()
    a3c.worker(0, shared, args, timer)
    stop.cancel()
    return shared.global_step(), timer.spent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="how long to run the loop")
    parser.add_argument("--env", default="Catch-v0", help="Catch-v0 or an ALE id")
    parser.add_argument("--envs-per-worker", type=int, default=1, help="K envs per worker")
    parser.add_argument(
        "--precision", default="fp32", choices=["auto", "fp32", "bf16", "bf16-learn"]
    )
    opts = parser.parse_args()
    if opts.seconds <= 0:
        parser.error("--seconds must be > 0")
    if opts.envs_per_worker < 1:
        parser.error("--envs-per-worker must be >= 1")
    torch.set_num_threads(1)
    torch.set_flush_denormal(True)  # as the workers do
    import catch_env  # noqa: F401  (registers Catch-v0)

    flags = {"env": opts.env, "envs_per_worker": opts.envs_per_worker, "precision": opts.precision}
    a3c = load_a3c()
    try:
        steps, spent = profile(a3c, opts.seconds, **flags)
    except a3c.UsageError as e:
        parser.error(str(e))
    total = sum(spent.values())
    print(f"{opts.env}, K={opts.envs_per_worker}, {opts.precision}: {steps:,} env steps, "
          f"{steps / total:,.0f} steps/s in one process")  # fmt: skip
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
