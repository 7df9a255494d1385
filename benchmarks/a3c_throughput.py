"""Global env steps per second of the agent scripts, with the default worker count.

    python benchmarks/a3c_throughput.py [SCRIPT ...] [--seconds 30] [--rounds 1]
                                        [--num-workers N] [--no-baseline] [--env Catch-v0]
                                        [--envs-per-worker 1 [K ...]] [--precision fp32 [...]]
                                        [--replay script|on|off ...] [--eval-episodes N]
                                        [--env-backend native [python]] [--env-threads 1 [T ...]]
                                        [--ceilings]

It runs each script's own training loop (evaluations included) for --seconds and reports the
steps/s after the workers have started. agents/a3c_ff.py is always measured, and the other
SCRIPTs (e.g. agents/a3c_lws.py) are compared with it: time per step relative to a3c_ff's, from
the same run. Every script runs at every setting, each value of --envs-per-worker with each
--precision (K = 1 is the thesis's algorithm) and each --replay: script leaves the choice to the
scripts' replay_activations (as a run does), on attaches the ActivationReplay to every worker
(K = 1 too) and off to none (the learning pass recomputes the forward), to measure what it saves;
both replace replay_activations in this process, before the workers fork.
On an ALE game, --env-backend and --env-threads choose catch_env.wrappers.make_vector_env's
backend (native: ale-py's C++ AtariVectorEnv on --env-threads emulator threads per worker;
python: today's SyncVectorEnv of Gymnasium-wrapped envs), also before the workers fork.

--ceilings (ALE games) measures, in the same run, the two bounds of a learning agent on this
machine: the emulator's (AtariVectorEnv with random actions, 16 envs on all cores, no learner)
and the network's (a3c_ff on Catch-v0 at each K and precision measured, where the env costs
almost nothing), and the bound of the two sharing the cores, 1 / (1 / emulator + 1 / network),
which each setting is compared with at its own K and precision.
With --rounds R the baseline and the scripts take turns R times and the means are reported, so
that slow drifts of a shared machine's speed fall on all of them alike.

For comparison it runs, in each round, a plain Hogwild loop of A3C FF for as long: load_state_dict
to sync, a fresh tensor per step, torch.optim-style per-parameter clipping and RMSprop. For
context it prints each network's FLOPs per env step (acting forward + the step's share of the
rollout's forward and backward), this machine's single-thread fp32 matmul GFLOP/s, and the
steps/s bound they give. Other load on the machine lowers every number: the load average is
printed before each measurement.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import inspect
import os
import platform
import resource
import sys
import tempfile
import time
from pathlib import Path

import a3c_runtime
import numpy as np
import torch
import torch.multiprocessing as mp
from torch.utils.flop_counter import FlopCounterMode

import catch_env  # noqa: F401  (registers Catch-v0)
import catch_env.wrappers

AGENTS = Path(__file__).resolve().parents[1] / "agents"
FF_SCRIPT = AGENTS / "a3c_ff.py"
PRECISIONS = ("auto", "fp32", "bf16", "bf16-learn")  # --precision of the scripts


def no_replay(model, rollout_frames, args) -> None:
    """--replay off: the scripts' replay_activations does nothing, every layer stays plain."""


def forced_replay(model, rollout_frames, args) -> a3c_runtime.ActivationReplay:
    """--replay on: every worker replays, whatever replay_activations would choose."""
    return a3c_runtime.ActivationReplay(model, rollout_frames)


REPLAY = {"script": a3c_runtime.replay_activations, "on": forced_replay, "off": no_replay}


def load_script(path: Path):
    """Import an agent script as a module named after its file."""
    name = path.stem
    if path.suffix != ".py":
        raise SystemExit(f"{path} is not an A3C agent script (agents/a3c_*.py)")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    for attr in ("Args", "ActorCritic", "AGENT"):
        if not hasattr(module, attr):
            raise SystemExit(f"{path} is not an A3C agent script: it has no {attr}")
    return module


def matmul_gflops(size: int = 1024, seconds: float = 1.0) -> float:
    """Single-thread fp32 matmul GFLOP/s, the best of a few timed rounds."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    best = 0.0
    for _ in range(3):
        calls, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 3:
            torch.mm(a, b)
            calls += 1
        best = max(best, 2 * size**3 * calls / (time.perf_counter() - start) / 1e9)
    return best


def network_outputs(model, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(log-probs, values) of a batch of states; a recurrent network (a3c_lstm: a `state`
    argument) sees them as one sequence from its initial state."""
    if "state" in inspect.signature(model.forward).parameters:
        log_probs, values, _ = model(obs[:, None], model.initial_state(1))
        return log_probs[:, 0], values[:, 0]
    return model(obs)


def flops_per_env_step(a3c, t_max: int) -> float:
    """FLOPs of one acting forward plus 1/t_max of a t_max-step training forward and backward."""
    args = a3c_runtime.resolve_defaults(a3c.Args())
    model = a3c.ActorCritic(3, args)
    params = [p for p in model.parameters() if p.requires_grad]
    with FlopCounterMode(display=False) as act, torch.inference_mode():
        network_outputs(model, torch.zeros(1, 4, 84, 84, dtype=torch.uint8))
    with FlopCounterMode(display=False) as learn:
        log_probs, values = network_outputs(model, torch.zeros(t_max, 4, 84, 84, dtype=torch.uint8))
        torch.autograd.grad(log_probs.sum() + values.sum(), params, allow_unused=True)
    return act.get_total_flops() + learn.get_total_flops() / t_max


def baseline_returns(rewards: np.ndarray, bootstrap_value: float, gamma: float) -> np.ndarray:
    """G_i = r_i + gamma * G_{i+1}, starting from G = V(s_last), or 0 after a terminal state."""
    returns = np.empty(len(rewards), dtype=np.float32)
    g = bootstrap_value
    for i in range(len(rewards) - 1, -1, -1):
        g = rewards[i] + gamma * g
        returns[i] = g
    return returns


def baseline_worker(a3c, worker_id, global_model, square_avg, steps, stop, args) -> None:
    """A straightforward Hogwild A3C worker: the same algorithm, written plainly."""
    torch.set_num_threads(1)
    torch.manual_seed(args.seed + worker_id)
    env = a3c.make_env(args.env)
    model = a3c.ActorCritic(env.action_space.n, args)
    obs, _ = env.reset(seed=args.seed + worker_id)
    while not stop.is_set():
        model.load_state_dict(global_model.state_dict())
        observations, actions, rewards, terminated = [], [], [], False
        for _ in range(args.t_max):
            x = torch.from_numpy(np.asarray(obs)).unsqueeze(0)
            with torch.no_grad():
                log_probs, _ = model(x)
            action = torch.multinomial(log_probs.exp(), 1).item()
            observations.append(x)
            obs, reward, terminated, truncated, _ = env.step(action)
            actions.append(action)
            rewards.append(reward)
            if terminated or truncated:
                break
        observations.append(torch.from_numpy(np.asarray(obs)).unsqueeze(0))
        log_probs, values = model(torch.cat(observations))
        n = len(rewards)
        bootstrap = 0.0 if terminated else values[n].item()
        returns = torch.from_numpy(baseline_returns(np.array(rewards), bootstrap, args.gamma))
        loss = a3c.a3c_loss(log_probs[:n], torch.tensor(actions), values[:n], returns,
                            args.ent_coef, args.vf_coef)[0]  # fmt: skip
        model.zero_grad()
        loss.backward()
        lr = args.learning_rate
        with torch.no_grad():
            for p, gp, ms in zip(model.parameters(), global_model.parameters(), square_avg,
                                 strict=True):  # fmt: skip
                torch.nn.utils.clip_grad_norm_([p], args.grad_clip)
                ms.mul_(args.rms_decay).addcmul_(p.grad, p.grad, value=1 - args.rms_decay)
                gp.addcdiv_(p.grad, (ms + args.optim_eps).sqrt(), value=-lr)
        steps[worker_id] += n
        if terminated or truncated:
            obs, _ = env.reset()


def children_cpu_seconds() -> float:
    """CPU time of this process's finished children (the workers, once joined)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def children_page_faults() -> int:
    """Minor page faults of this process's finished children: a fresh multi-megabyte tensor
    that glibc serves by mmap faults once per 4 KB page, and how often that happens in a
    process depends on where its heap happens to end, which makes a loop's speed vary by run."""
    return resource.getrusage(resource.RUSAGE_CHILDREN).ru_minflt


def run_baseline(
    a3c, env: str, num_workers: int, seconds: float, warmup: float
) -> tuple[float, float, float]:
    """Returns (steps/s after the warm-up, total steps / worker CPU-seconds * num_workers,
    the workers' page faults per step)."""
    args = a3c_runtime.resolve_defaults(a3c.Args(num_workers=num_workers, env=env))
    global_model = a3c.ActorCritic(num_actions(a3c, env), args)
    global_model.share_memory()
    square_avg = [torch.zeros_like(p).share_memory_() for p in global_model.parameters()]
    steps = torch.zeros(num_workers, dtype=torch.int64).share_memory_()
    ctx = mp.get_context("fork")
    stop = ctx.Event()
    cpu_before, faults_before = children_cpu_seconds(), children_page_faults()
    workers = [
        ctx.Process(target=baseline_worker,
                    args=(a3c, i, global_model, square_avg, steps, stop, args), daemon=True)
        for i in range(num_workers)
    ]  # fmt: skip
    for w in workers:
        w.start()
    time.sleep(warmup)
    start_steps, start = int(steps.sum()), time.perf_counter()
    time.sleep(seconds)
    sps = (int(steps.sum()) - start_steps) / (time.perf_counter() - start)
    stop.set()
    for w in workers:
        w.join(10)
        if w.exitcode != 0:
            raise RuntimeError(f"baseline worker exited with {w.exitcode}")
    per_cpu = int(steps.sum()) / (children_cpu_seconds() - cpu_before) * num_workers
    return sps, per_cpu, (children_page_faults() - faults_before) / int(steps.sum())


def num_actions(a3c, env_id: str) -> int:
    env = a3c.make_env(env_id)
    n = env.action_space.n
    env.close()
    return n


MAKE_VECTOR_ENV = catch_env.wrappers.make_vector_env


def emulator_ceiling(env_id: str, seconds: float, num_envs: int = 16) -> float:
    """Steps/s of ale-py's AtariVectorEnv alone: random actions, `num_envs` envs on as many
    emulator threads as cores, no learner."""
    envs = MAKE_VECTOR_ENV(env_id, num_envs, num_threads=os.cpu_count() or 1)
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, envs.single_action_space.n, (64, num_envs))
    for i in range(50):
        envs.step(actions[i % 64])
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        envs.step(actions[steps % 64])
        steps += 1
    envs.close()
    return steps * num_envs / (time.perf_counter() - start)


def run_script(
    a3c,
    env: str,
    num_workers: int,
    seconds: float,
    envs_per_worker: int,
    precision: str,
    eval_episodes: int | None = None,
    replay: str = "script",
    env_backend: str = "native",
    env_threads: int = 1,
) -> tuple[float, float, float]:
    """Returns (steps/s once the workers are ready, steps / CPU-seconds * num_workers, the
    page faults per step of the run's processes)."""
    a3c.replay_activations = REPLAY[replay]
    catch_env.wrappers.make_vector_env = functools.partial(
        MAKE_VECTOR_ENV, backend=env_backend, num_threads=env_threads
    )
    with tempfile.TemporaryDirectory() as run_dir:
        args = a3c.Args(num_workers=num_workers, time_limit=seconds, run_dir=run_dir, env=env,
                        log_interval=max(5.0, seconds / 4), envs_per_worker=envs_per_worker,
                        precision=precision, eval_episodes=eval_episodes)  # fmt: skip
        args.total_timesteps = 10**9  # the time limit ends the run
        cpu_before, faults_before = children_cpu_seconds(), children_page_faults()
        summary = a3c_runtime.train(a3c.AGENT, a3c_runtime.resolve_defaults(args))
    a3c.replay_activations = a3c_runtime.replay_activations
    catch_env.wrappers.make_vector_env = MAKE_VECTOR_ENV
    per_cpu = summary["global_step"] / (children_cpu_seconds() - cpu_before) * num_workers
    faults = (children_page_faults() - faults_before) / max(summary["global_step"], 1)
    return summary["sps"], per_cpu, faults


def main() -> None:
    # A CPU measurement. With a CUDA build and a GPU, the FLOP count's backward here would start
    # autograd's device threads, and the forked workers' backward would then refuse to run.
    os.environ["CUDA_VISIBLE_DEVICES"] = ""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("scripts", nargs="*", type=Path, help="scripts to compare with a3c_ff")
    parser.add_argument("--seconds", type=float, default=30.0, help="time per measurement")
    parser.add_argument("--rounds", type=int, default=1, help="measurements per script")
    parser.add_argument("--num-workers", type=int, default=None, help="default: a3c_ff's")
    parser.add_argument("--no-baseline", action="store_true", help="skip the baseline loop")
    parser.add_argument("--env", default="Catch-v0", help="Catch-v0 or an ALE id")
    parser.add_argument("--eval-episodes", type=int, default=None,
                        help="episodes of the step-0 evaluation, which runs beside the workers "
                             "(default: the script's 50; an ALE game's 50 take a core for the "
                             "whole measurement, so use 1 there)")  # fmt: skip
    parser.add_argument("--envs-per-worker", type=int, nargs="+", default=[1],
                        help="the K values to measure")  # fmt: skip
    parser.add_argument("--precision", nargs="+", default=["fp32"], choices=PRECISIONS,
                        help="the precisions to measure")  # fmt: skip
    parser.add_argument("--replay", nargs="+", default=["script"], choices=list(REPLAY),
                        help="ActivationReplay as the scripts choose (script), on every worker "
                             "(on, K = 1 too) and/or off")  # fmt: skip
    parser.add_argument("--env-backend", nargs="+", default=["native"],
                        choices=["native", "python"],
                        help="ALE games: make_vector_env's backend(s) to measure")  # fmt: skip
    parser.add_argument("--env-threads", type=int, nargs="+", default=[1],
                        help="ALE games, native backend: emulator threads per worker")  # fmt: skip
    parser.add_argument("--ceilings", action="store_true",
                        help="ALE games: also measure the two ceilings")  # fmt: skip
    opts = parser.parse_args()
    if min(opts.env_threads) < 1:
        parser.error("--env-threads must be >= 1")
    if opts.eval_episodes is not None and opts.eval_episodes < 1:
        parser.error("--eval-episodes must be >= 1")
    if min(opts.envs_per_worker) < 1:
        parser.error("--envs-per-worker must be >= 1")
    if opts.seconds <= 0:
        parser.error("--seconds must be > 0")
    if opts.rounds < 1:
        parser.error("--rounds must be >= 1")
    for path in opts.scripts:
        if not path.is_file():
            parser.error(f"no such script: {path} (the agents are agents/a3c_*.py)")
    torch.set_num_threads(1)
    paths = [FF_SCRIPT] + [p.resolve() for p in opts.scripts if p.resolve() != FF_SCRIPT]
    scripts = {path.stem: load_script(path) for path in dict.fromkeys(paths)}
    a3c = scripts["a3c_ff"]
    num_workers = opts.num_workers or a3c.Args().num_workers
    if num_workers < 1:
        parser.error("--num-workers must be >= 1")
    try:
        a3c_runtime.resolve_defaults(a3c.Args(env=opts.env))
    except a3c_runtime.UsageError as e:
        parser.error(str(e))
    atari = catch_env.wrappers.is_atari(opts.env)
    if opts.ceilings and not atari:
        parser.error("--ceilings needs an ALE game (--env BreakoutNoFrameskip-v4, ...)")
    env_settings = [("native", t) for t in dict.fromkeys(opts.env_threads)] * (
        "native" in opts.env_backend
    ) + [("python", 1)] * ("python" in opts.env_backend)
    if not atari:
        env_settings = [("native", 1)]  # Catch: the backend does not apply
    settings = [
        (k, p, r, backend, threads)
        for k in dict.fromkeys(opts.envs_per_worker)
        for p in dict.fromkeys(opts.precision)
        for r in dict.fromkeys(opts.replay)
        for backend, threads in env_settings
    ]

    cpu = platform.processor() or platform.machine()
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as f:
            cpu = next(
                (ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu
            )
    print(f"machine: {cpu}, {os.cpu_count()} cores; torch {torch.__version__}; {opts.env}; "
          f"{num_workers} workers; {opts.seconds:g} s per measurement, {opts.rounds} "
          f"round(s)"
          )  # fmt: skip
    gflops = matmul_gflops()
    print(f"matmul: {gflops:.1f} GFLOP/s per core (fp32, 1 thread)")
    bounds = {}
    for name, module in scripts.items():
        flops = flops_per_env_step(module, module.Args().t_max)
        bounds[name] = num_workers * gflops * 1e9 / flops
        print(f"{name}: {flops / 1e6:.1f} MFLOP per env step (acting forward + 1/t_max of the "
              f"rollout's forward and backward) -> bound {bounds[name]:,.0f} steps/s")  # fmt: skip

    baselines = []
    ceilings = {kp: [] for kp in dict.fromkeys(s[:2] for s in settings)} if opts.ceilings else {}
    measured = {(name, *setting): [] for setting in settings for name in scripts}
    for _ in range(opts.rounds):
        if opts.ceilings:
            print(f"load average {os.getloadavg()[0]:.2f}; ceilings ...", flush=True)
            emulator = emulator_ceiling(opts.env, opts.seconds)
            print(f"ceiling: emulator {emulator:,.0f} steps/s")
            for k, precision in ceilings:
                network = run_script(a3c, "Catch-v0", num_workers, opts.seconds, k, precision, 1)
                ceilings[k, precision].append((emulator, network[0]))
                print(f"ceiling: network at K={k} {precision} {network[0]:,.0f} steps/s")
        if not opts.no_baseline:  # every round, so that drifts of the host fall on it too
            print(f"load average {os.getloadavg()[0]:.2f}; baseline Hogwild loop ...", flush=True)
            baselines.append(run_baseline(a3c, opts.env, num_workers, opts.seconds, warmup=3.0))
            sps, per_cpu, faults = baselines[-1]
            print(f"baseline: {sps:,.0f} steps/s ({per_cpu:,.0f} per {num_workers} "
                  f"CPU-seconds; {faults:.1f} page faults per step)")  # fmt: skip
        for name, k, precision, replay, backend, threads in measured:
            print(
                f"load average {os.getloadavg()[0]:.2f}; {name} K={k} {precision} replay "
                f"{replay} env {backend} threads {threads} ...",
                flush=True,
            )
            result = run_script(scripts[name], opts.env, num_workers, opts.seconds, k, precision,
                                opts.eval_episodes, replay, backend, threads)  # fmt: skip
            print(f"{name}: {result[0]:,.0f} steps/s ({result[1]:,.0f} per {num_workers} "
                  f"CPU-seconds), {result[2]:.1f} page faults per step")  # fmt: skip
            measured[name, k, precision, replay, backend, threads].append(result)

    if any(run[0] == 0 for runs in measured.values() for run in runs):
        print(
            "\nnote: a measurement saw no step in its window (the start-up took it): its "
            "ratios print as nan or inf; measure with a longer --seconds"
        )
    # such a measurement divides by 0: said once above rather than as numpy warnings
    with np.errstate(divide="ignore", invalid="ignore"):
        baseline = np.mean(baselines, axis=0) if baselines else None
        if len(baselines) > 1:
            print(f"\nbaseline, mean of {len(baselines)} rounds: {baseline[0]:,.0f} steps/s "
                  f"(rounds: {', '.join(f'{b[0]:,.0f}' for b in baselines)})")  # fmt: skip
        print(f"\n{'script':<12} {'K':>3} {'precision':>10} {'replay':>6} {'env':>9} "
              f"{'steps/s':>9} {'per CPU-s':>10} {'of bound':>9} {'time/step vs a3c_ff':>20} "
              f"{'vs baseline':>11}")  # fmt: skip
        for (name, k, precision, replay, backend, threads), runs in measured.items():
            sps, per_cpu, _ = np.mean(runs, axis=0)
            ff = measured[("a3c_ff", k, precision, replay, backend, threads)]
            ff_sps, ff_per_cpu, _ = np.mean(ff, axis=0)
            env = (f"{backend}/{threads}" if backend == "native" else backend) if atari else "-"
            line = f"{name:<12} {k:>3} {precision:>10} {replay:>6} {env:>9} {sps:>9,.0f} "
            line += f"{per_cpu:>10,.0f} "
            line += f"{per_cpu / bounds[name]:>9.0%} {ff_sps / sps:>9.2f}x wall "
            line += f"{ff_per_cpu / per_cpu:>5.2f}x CPU"
            if baseline is not None:
                line += f" {sps / baseline[0]:>10.2f}x"
            print(line)
        if baseline is not None:
            for setting in settings:
                ff_sps, ff_per_cpu, _ = np.mean(measured[("a3c_ff", *setting)], axis=0)
                print(f"a3c_ff {setting} vs the baseline loop: "
                      f"{ff_sps / baseline[0]:.2f}x steps/s, {ff_per_cpu / baseline[1]:.2f}x per "
                      f"CPU-second")  # fmt: skip
        if atari and len(env_settings) > 1:
            print(
                f"\nsteps/s of a3c_ff against the first env setting, {env_settings[0]}, same run:"
            )
            for setting in settings:
                first = measured[("a3c_ff", *setting[:3], *env_settings[0])]
                ratio = (
                    np.mean(measured[("a3c_ff", *setting)], axis=0)[0] / np.mean(first, axis=0)[0]
                )
                print(f"  {setting}: {ratio:.2f}x")
        for (k, precision), rounds in ceilings.items():
            emulator, network = np.mean(rounds, axis=0)
            bound = 1 / (1 / emulator + 1 / network)
            print(f"\nceilings, mean of {len(rounds)} round(s): emulator {emulator:,.0f} steps/s "
                  f"(AtariVectorEnv, 16 envs, {os.cpu_count()} threads, random actions), network "
                  f"{network:,.0f} (a3c_ff on Catch-v0, K={k} {precision}); "
                  f"the two sharing the cores: 1 / (1/{emulator:,.0f} + 1/{network:,.0f}) = "
                  f"{bound:,.0f} steps/s")  # fmt: skip
            for setting in settings:
                if setting[:2] == (k, precision):
                    sps = np.mean(measured[("a3c_ff", *setting)], axis=0)[0]
                    print(
                        f"  a3c_ff {setting}: {sps:,.0f} steps/s = {sps / bound:.0%} of that bound"
                    )


if __name__ == "__main__":
    main()
