"""Run-steps/s of N one-worker A3C FF runs on Catch-v0 as one batched program (the sweep's
--backend batched: a3c_tools.batched) against the process backend (the same runs as processes of
agents/a3c_ff.py side by side, one core each).

    python benchmarks/batched_throughput.py [--device cpu|cuda] [--runs 50 64 256 1024]
        [--conv-form grouped [matmul]] [--seconds 20] [--process-runs W]
        [--process-seconds 40] [--t-max 20] [--out FILE]

For each N of --runs it builds a batch of N runs (run i: seed 1 + 1000 i, a learning rate
log-uniform in [1e-4, 1e-2], the script's other defaults), trains it for --seconds after two
warm-up updates and reports run-steps/s (N x env steps per second; evaluations apart) and the
ms of an update, once for each --conv-form (how the stacked convolutions are computed,
a3c_runtime.batched.CONV_FORMS; several: each N measured with each, in turns), then
times one evaluation of the thesis protocol (N x 50 episodes; the runs' evaluations are
sequential, so it times EVALUATED of them and scales to N). From these it projects a
thesis-scale line: 50 runs of 1M steps with an evaluation every 50,000 steps, run as one batch.

The process backend: --process-runs W runs of agents/a3c_ff.py --num-workers 1 side by side, each
for --process-seconds with evaluations too rare to count; their SPS (each run's closing line,
measured after its worker started) summed; 0 skips it. The ratio is the batch's run-steps/s over
the W processes'. By default W is what the batch stands against: on the CPU the one core the
batch uses (one thread), with --device cuda every core this process may use (16 on the lent
GPU machine).

Other load on the machine lowers every number: the load average is printed with each line.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "agents"), str(ROOT)]

from a3c_runtime import resolve_defaults  # noqa: E402
from a3c_runtime.batched import CONV_FORMS, BatchedA3C, BatchedRun, set_up_device  # noqa: E402
from a3c_tools import load_script  # noqa: E402

THESIS_LINE = {"runs": 50, "steps": 1_000_000, "eval_interval": 50_000}
EVALUATED = 8  # runs whose evaluation is timed, the rest projected from theirs


def load() -> str:
    return f"load {os.getloadavg()[0]:.2f}" if hasattr(os, "getloadavg") else "load ?"


def sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def batch_of(module, n: int, device: str, t_max: int, conv_form: str = "grouped") -> BatchedA3C:
    runs = []
    for i in range(n):
        lr = math.exp(math.log(1e-4) + (i + 0.5) / n * (math.log(1e-2) - math.log(1e-4)))
        args = module.Args(num_workers=1, seed=1 + 1000 * i, learning_rate=lr, t_max=t_max,
                           total_timesteps=10**9, precision="fp32")  # fmt: skip
        runs.append(BatchedRun(resolve_defaults(args)))
    return BatchedA3C(module, runs, device, conv_form)


def measure_batch(
    module, n: int, device: str, seconds: float, t_max: int, conv_form: str = "grouped"
) -> dict:
    """run-steps/s of a batch of n runs over `seconds`, the ms of an update, and one
    evaluation's seconds."""
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    batch = batch_of(module, n, device, t_max, conv_form)
    for _ in range(2):  # warm-up: the first vmap traces, cuDNN picks its algorithms
        batch.update()
    sync(device)
    start, steps, updates = time.time(), 0, 0
    while time.time() - start < seconds:
        steps += batch.update()
        updates += 1
    sync(device)
    elapsed = time.time() - start
    # a batch's evaluation is each run's in turn (the runtime's evaluate_network): timed on at
    # most EVALUATED runs and scaled to N, where N of them would take minutes
    start, evaluated = time.time(), min(n, EVALUATED)
    for i in range(evaluated):
        batch.evaluate(i)
    sync(device)
    evaluation = (time.time() - start) * n / evaluated
    memory = torch.cuda.max_memory_allocated() / 2**30 if device == "cuda" else float("nan")
    return {"run_steps_s": n * steps / elapsed, "steps_s": steps / elapsed,
            "update_ms": 1000 * elapsed / updates, "eval_s": evaluation,
            "memory_gib": memory, "conv_form": batch.conv_form}  # fmt: skip


def measure_processes(count: int, seconds: float) -> float:
    """The summed SPS of `count` one-worker runs of agents/a3c_ff.py side by side."""
    with tempfile.TemporaryDirectory() as runs_root:
        processes = [
            subprocess.Popen(
                [
                    sys.executable,
                    str(ROOT / "agents" / "a3c_ff.py"),
                    "--num-workers",
                    "1",
                    "--seed",
                    str(1 + 1000 * i),
                    "--total-timesteps",
                    str(10**9),
                    "--time-limit",
                    str(seconds),
                    "--eval-interval",
                    str(10**9),
                    "--eval-episodes",
                    "1",
                    "--precision",
                    "fp32",
                    "--runs-root",
                    runs_root,
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
                cwd=ROOT,
                env={
                    **os.environ,
                    "PYTHONPATH": os.pathsep.join(  # the caller's too (the device's wheels)
                        filter(
                            None, [str(ROOT / "agents"), str(ROOT), os.environ.get("PYTHONPATH")]
                        )
                    ),
                },
            )  # fmt: skip
            for i in range(count)
        ]
        total = 0.0
        for process in processes:
            out, _ = process.communicate()
            found = re.findall(r"\| SPS ([\d,]+) \|", out)
            if process.returncode != 0 or not found:
                raise SystemExit(f"a process-backend run failed: {out[-500:]}")
            total += float(found[-1].replace(",", ""))
    return total


def thesis_line_minutes(result: dict) -> float:
    """A thesis-scale line (50 runs x 1M steps, 21 evaluations) as one batch, in minutes, from
    the batch's steps/s and evaluation time (measured at its own N; 50 runs step faster)."""
    evaluations = THESIS_LINE["steps"] // THESIS_LINE["eval_interval"] + 1
    return (THESIS_LINE["steps"] / result["steps_s"] + evaluations * result["eval_s"]) / 60


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--runs", type=int, nargs="+", default=[50, 64, 256, 1024])
    parser.add_argument("--conv-form", nargs="+", choices=CONV_FORMS, default=["grouped"])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--process-runs", type=int, default=None)
    parser.add_argument("--process-seconds", type=float, default=40.0)
    parser.add_argument("--t-max", type=int, default=20)
    parser.add_argument("--out", default=None, help="also write the report to this file")
    args = parser.parse_args()
    if args.process_runs is None:  # the cores the batch stands against: its one, or all of them
        args.process_runs = 1 if args.device == "cpu" else len(os.sched_getaffinity(0))
    if any(n < 1 for n in args.runs) or args.seconds <= 0 or args.process_runs < 0:
        parser.error("--runs must be >= 1, --seconds > 0, --process-runs >= 0")
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: torch sees no CUDA device")
    set_up_device(args.device)  # as the backend trains: one thread on a CPU, no TF32 on a GPU
    module = load_script(ROOT / "agents" / "a3c_ff.py")
    lines = []

    def report(line: str) -> None:
        print(line, flush=True)
        lines.append(line)

    name = torch.cuda.get_device_name() if args.device == "cuda" else platform.processor()
    report(f"# {args.device} ({name or platform.machine()}), torch {torch.__version__}, "
           f"{len(os.sched_getaffinity(0))} cores, t_max {args.t_max}")  # fmt: skip
    processes = None
    if args.process_runs:
        processes = measure_processes(args.process_runs, args.process_seconds)
        report(f"process backend: {args.process_runs} one-worker runs side by side: "
               f"{processes:,.0f} run-steps/s ({load()})")  # fmt: skip
    for n, conv_form in ((n, form) for n in args.runs for form in args.conv_form):
        result = measure_batch(module, n, args.device, args.seconds, args.t_max, conv_form)
        ratio = (
            f" = {result['run_steps_s'] / processes:.2f}x the process backend" if processes else ""
        )
        report(f"batched N={n} ({result['conv_form']} convolutions): "
               f"{result['run_steps_s']:,.0f} run-steps/s{ratio}, "
               f"{result['update_ms']:.1f} ms an update; one evaluation (N x 50 episodes) "
               f"{result['eval_s']:.2f} s; peak device memory "
               f"{result['memory_gib']:.1f} GiB; a thesis-scale line (50 runs x 1M steps) at "
               f"this N's speed: {thesis_line_minutes(result):.1f} min ({load()})")  # fmt: skip
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
