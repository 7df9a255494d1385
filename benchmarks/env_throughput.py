"""Steps per second of Catch-v0: one env through gym.make, and the NumPy vector env.

    python benchmarks/env_throughput.py [--seconds 2] [--repeats 3]

Each configuration steps with pre-drawn random actions for `--seconds` of CPU time,
`--repeats` times, and reports the best repeat, as steps per second of wall time and per
second of CPU time (the benchmark is single-threaded: CPU time is what the code costs even
when other processes share the machine, which lowers the wall-time figure).
The vector env is measured with `copy=True` (the default: fresh observation arrays, as
`SyncVectorEnv` returns) and `copy=False` (the env's own buffer, which a training loop
copies into its rollout storage anyway). Targets on a 2-core machine: single env >= 100k
steps/s; N=1024 >= 1M steps/s with 84x84 pixels and >= 10M steps/s with grid observations.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import gymnasium as gym
import numpy as np

import catch_env  # noqa: F401  (registers Catch-v0)


def time_steps(step, actions: np.ndarray, seconds: float) -> np.ndarray:
    """Call step(actions[i]) in a loop for about `seconds` of CPU time.

    Returns calls per second of wall time and per second of this process's CPU time. The
    benchmark is single-threaded, so the second is what the code costs even when other
    processes share the cores (the first then drops, the second barely moves).
    """
    calls, wall_start, cpu_start = 0, time.perf_counter(), time.process_time()
    while True:
        for action in actions:
            step(action)
        calls += len(actions)
        cpu = time.process_time() - cpu_start
        if cpu >= seconds:
            return np.array([calls / (time.perf_counter() - wall_start), calls / cpu])


def single_env(seconds: float) -> np.ndarray:
    env = gym.make("Catch-v0")
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 3, 15 * 64).tolist()

    def step(action: int) -> None:
        if env.step(action)[2]:
            env.reset()

    return time_steps(step, actions, seconds)


def vector_env(num_envs: int, obs_type: str, copy: bool, seconds: float) -> np.ndarray:
    envs = gym.make_vec("Catch-v0", num_envs=num_envs, obs_type=obs_type, copy=copy)
    envs.reset(seed=0)
    actions = np.random.default_rng(0).integers(0, 3, (64, num_envs))
    return time_steps(envs.step, actions, seconds) * num_envs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    parser.add_argument("--repeats", type=int, default=3, help="measurements per configuration")
    args = parser.parse_args()

    def report(name: str, measure, *params) -> None:
        runs = np.array([measure(*params, args.seconds) for _ in range(args.repeats)])
        wall, cpu = runs.max(axis=0)
        print(f"{name:<40} {wall:>14,.0f} {cpu:>14,.0f}", flush=True)

    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, NumPy {np.__version__}, "
        f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    print(f"{'configuration':<40} {'steps/s (wall)':>14} {'steps/CPU-s':>14}")
    report("gym.make(Catch-v0), single env", single_env)
    for obs_type in ("pixels", "grid"):
        for copy in (True, False):
            for num_envs in (1, 64, 1024):
                name = f"make_vec N={num_envs} {obs_type} copy={copy}"
                report(name, vector_env, num_envs, obs_type, copy)


if __name__ == "__main__":
    main()
