"""Where one A3C FF worker's time goes, per env step, on Catch-v0 or an ALE game.

    python benchmarks/a3c_step_profile.py [--seconds 20] [--env Catch-v0]
                                          [--envs-per-worker 1] [--precision fp32]

One process and one torch thread run agents/a3c_ff.py's own `worker` loop (sync, act up to t_max
steps, one batched forward and backward, clip, shared RMSprop step), unchanged: the phases are
timed from outside, by wrapping what the loop calls (the vector env's step, the network's
forward, torch.autograd.grad, the script's clip_gradients, the shared optimizer's step), so the
loop carries no instrumentation. A forward in inference mode is acting, one with gradients the
update's. "other" is the rest of the loop: the parameter sync, the n-step returns and the loss,
sampling, copying frames and bookkeeping. The phases' shares are what matters; absolute times
depend on the machine and its load. "env step" is the emulator's (or Catch's) share: the vector
env's step, preprocessing and frame stack included.

It then shows how the acting forward's time depends on its place in the rollout, next to the
same forward run back to back on one state and after a pause (sleeping) of a few milliseconds:
on a shared host the first forwards after the learning phase run several times slower than warm
ones, because the caches lose the forward's code and data while the worker is elsewhere, even
asleep. The first line also gives the page faults per step.
"""

from __future__ import annotations

import argparse
import importlib.util
import resource
import statistics
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import a3c_runtime as runtime
import torch

AGENTS = Path(__file__).resolve().parents[1] / "agents"
SCRIPT = AGENTS / "a3c_ff.py"
PHASES = ("act forward", "env step", "learn forward", "backward", "clip", "optimizer", "other")
NETWORK_PHASES = ("act forward", "learn forward", "backward")  # the network's own kernels


def load_a3c():
    spec = importlib.util.spec_from_file_location("a3c_ff", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["a3c_ff"] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


class PhaseClock:
    """Seconds spent in each phase, from wrappers around what the loop calls."""

    def __init__(self) -> None:
        self.spent = dict.fromkeys(PHASES, 0.0)
        self.acting: list[list[float]] = []  # acting[k]: the k-th forward of each rollout
        self.position = 0

    def timed(self, phase: str, function: Callable) -> Callable:
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.spent[phase] += time.perf_counter() - start

        return wrapper

    def timed_forward(self, forward: Callable) -> Callable:
        """The network's forward: acting (inference mode, also timed by its place in the
        rollout) or the update's."""

        def wrapper(model, *args, **kwargs):
            start = time.perf_counter()
            result = forward(model, *args, **kwargs)
            seconds = time.perf_counter() - start
            if torch.is_inference_mode_enabled():
                self.spent["act forward"] += seconds
                if self.position == len(self.acting):
                    self.acting.append([])
                self.acting[self.position].append(seconds)
                self.position += 1
            else:
                self.spent["learn forward"] += seconds
                self.position = 0
            return result

        return wrapper


def profile(a3c, seconds: float, **flags) -> tuple[int, float, PhaseClock]:
    """Run the worker loop for `seconds` from its start (building the envs is not timed) and
    on to the end of its first update if it has made none by then (a loaded host), with the
    given Args `flags`; returns (env steps, the loop's seconds, the phases' clock)."""
    args = runtime.resolve_defaults(a3c.Args(num_workers=1, **flags))
    args.total_timesteps = 10**12  # the clock ends the loop
    num_actions = runtime.probe_env(a3c.make_env, args.env)
    network = a3c.AGENT.build_network(num_actions, args)
    shared = runtime.Shared(network, args, runtime.supervision.FORK)
    clock = PhaseClock()
    make_vector_env, loop_start = a3c.make_vector_env, []

    def timed_vector_env(env_id: str, num_envs: int, terminal_on_life_loss: bool = False):
        envs = make_vector_env(env_id, num_envs, terminal_on_life_loss)
        envs.step = clock.timed("env step", envs.step)
        loop_start.append(time.perf_counter())  # building 16 emulators is not a phase
        return envs

    originals = (a3c.make_vector_env, a3c.ActorCritic.forward, a3c.clip_gradients)
    grad = torch.autograd.grad
    a3c.make_vector_env = timed_vector_env
    a3c.ActorCritic.forward = clock.timed_forward(a3c.ActorCritic.forward)
    a3c.clip_gradients = clock.timed("clip", a3c.clip_gradients)
    shared.optimizer.step = clock.timed("optimizer", shared.optimizer.step)
    torch.autograd.grad = clock.timed("backward", grad)
    ended = threading.Event()

    def stop_the_loop() -> None:
        while not loop_start:  # the window opens when the loop starts
            if ended.wait(0.01):
                return
        if ended.wait(max(0.0, loop_start[0] + seconds - time.perf_counter())):
            return
        while shared.global_step() == 0:  # a window that ended before a step: up to the first
            if ended.wait(0.01):
                return
        shared.stop.set()

    stopper = threading.Thread(target=stop_the_loop, daemon=True)
    stopper.start()
    try:
        a3c.worker(0, shared, args)
    finally:  # the wrappers go: later forwards (forward_after_pause) are not the loop's
        ended.set()
        stopper.join()
        a3c.make_vector_env, a3c.ActorCritic.forward, a3c.clip_gradients = originals
        torch.autograd.grad = grad
    total = time.perf_counter() - loop_start[0]
    clock.spent["other"] = total - sum(clock.spent.values())
    return shared.global_step(), total, clock


def forward_after_pause(a3c, env_id: str, pauses_ms: tuple[float, ...]) -> dict[float, float]:
    """Median seconds of one acting forward (batch 1, a fresh network) after sleeping each of
    `pauses_ms` (0: back to back), 40 times each."""
    args = runtime.resolve_defaults(a3c.Args(num_workers=1, env=env_id))
    env = a3c.make_env(env_id)
    obs = torch.from_numpy(env.reset(seed=0)[0])[None]
    model = a3c.ActorCritic(env.action_space.n, args).to(memory_format=torch.channels_last)
    env.close()
    medians = {}
    with torch.inference_mode():
        for _ in range(50):
            model(obs)
        for pause in pauses_ms:
            seconds = []
            for _ in range(40):
                if pause:
                    time.sleep(pause / 1e3)
                start = time.perf_counter()
                model(obs)
                seconds.append(time.perf_counter() - start)
            medians[pause] = statistics.median(seconds)
    return medians


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
    import catch_env  # noqa: F401  (registers Catch-v0)

    flags = {"env": opts.env, "envs_per_worker": opts.envs_per_worker, "precision": opts.precision}
    a3c = load_a3c()
    runtime.configure_process()  # as the workers do
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    try:
        steps, total, clock = profile(a3c, opts.seconds, **flags)
    except runtime.UsageError as e:
        parser.error(str(e))
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    if steps == 0:  # the worker ended before its first update: nothing to divide by
        sys.exit("error: the worker loop ended before its first update; nothing was measured")
    spent = clock.spent
    print(f"{opts.env}, K={opts.envs_per_worker}, {opts.precision}: {steps:,} env steps, "
          f"{steps / total:,.0f} steps/s in one process, {faults / steps:.1f} page faults per "
          "step (building the env and network included)")  # fmt: skip
    for phase, seconds in spent.items():
        print(f"{phase:<14} {seconds / steps * 1e6:8.1f} us/step {seconds / total:6.1%}")
    # the ceiling that removing all per-step Python, copying, sync and optimizer work would reach
    network = sum(spent[phase] for phase in NETWORK_PHASES)
    print(
        f"network forward+backward alone: {network / total:.1%} of the time; with every other "
        f"phase free, at most {steps / network:,.0f} steps/s in one process"
    )
    # the acting forward by its place in the rollout, against the same forward warm
    acting = clock.acting
    rollouts = len(acting[0])
    shown = [k for k, times in enumerate(acting) if len(times) >= rollouts / 2]
    medians = ", ".join(f"{statistics.median(acting[k]) * 1e6:.0f}" for k in shown)
    print(f"acting forward by place in the rollout, median us (1st..{len(shown)}th): {medians}")
    pauses = forward_after_pause(a3c, opts.env, (0, 1, 5, 10, 20))
    print(
        f"the same forward, fresh network, back to back: {pauses[0] * 1e6:.0f} us; after "
        + ", ".join(f"sleeping {p} ms: {pauses[p] * 1e6:.0f}" for p in list(pauses)[1:])
    )
    above = sum(sum(times) - len(times) * pauses[0] for times in acting)
    print(
        f"acting forwards above the back-to-back time: {above / steps * 1e6:.0f} us/step, "
        f"{above / total:.1%} of the loop's time"
    )


if __name__ == "__main__":
    main()
