"""Where a batched update's time goes (the sweep's --backend batched, a3c_tools.batched): for
each N of --runs, a batch of N one-worker runs of a script at the given flags is built, warmed
up for two updates, timed over --updates updates (run-steps/s and steps/s, the batch's lockstep
rate), then profiled over 3 updates with torch.profiler: the ops with the most host time and,
on a GPU, the most device time, and the kernels' time an update.

    python benchmarks/batched_profile.py [--device cpu|cuda] [--runs 50 1024] [--updates 20]
        [--script a3c_ff.py] [--no-profile] [-- FLAG ...]

What it is for: to see whether a batch is bound by the device's arithmetic or by the host
(its Python and kernel launches, the returns computed on the host), before optimising it.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "agents"), str(ROOT)]

from a3c_runtime import UsageError  # noqa: E402
from a3c_runtime.batchable import BATCHED_SCRIPTS, resolve_run_args  # noqa: E402
from a3c_runtime.batched import BatchedA3C, BatchedRun, set_up_device  # noqa: E402
from a3c_tools import load_script, parsed_flags  # noqa: E402


def sync(device: str) -> None:
    if device == "cuda":
        torch.cuda.synchronize()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    parser.add_argument("--runs", type=int, nargs="+", default=[50, 1024])
    parser.add_argument("--updates", type=int, default=20)
    parser.add_argument("--script", type=os.path.basename, default="a3c_ff.py",
                        choices=BATCHED_SCRIPTS, help="a script the backend batches")  # fmt: skip
    parser.add_argument("--no-profile", action="store_true", help="time the updates only")
    parser.add_argument("flags", nargs="*", help="the script's flags (after --)")
    args = parser.parse_args()
    if any(n < 1 for n in args.runs) or args.updates < 1:
        parser.error("--runs and --updates must be >= 1")
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: torch sees no CUDA device")
    set_up_device(args.device)  # as the backend trains: one thread on a CPU, no TF32 on a GPU
    module = load_script(ROOT / "agents" / args.script)
    print(f"# {args.script} {' '.join(args.flags)} on {args.device}, torch {torch.__version__}")
    for n in args.runs:
        runs = []
        for i in range(n):
            lr = math.exp(math.log(1e-4) + (i + 0.5) / n * (math.log(1e-2) - math.log(1e-4)))
            flags = [*args.flags, "--num-workers", "1", "--seed", str(1 + 1000 * i),
                     "--learning-rate", str(lr), "--total-timesteps", str(10**9)]  # fmt: skip
            try:
                runs.append(BatchedRun(resolve_run_args(parsed_flags(module.Args, flags))))
            except ValueError as e:  # tyro's refusal, in one line
                parser.error(f"the script's flags do not parse: {e}")
            except UsageError as e:  # the runtime's
                parser.error(str(e))
        built = time.time()
        batch = BatchedA3C(module, runs, args.device)
        built = time.time() - built
        for _ in range(2):
            batch.update()
        sync(args.device)
        start, steps = time.time(), 0
        for _ in range(args.updates):
            steps += batch.update()
        sync(args.device)
        elapsed = time.time() - start
        rate = f"{steps / elapsed:,.0f} steps/s (lockstep), {n * steps / elapsed:,.0f} run-steps/s"
        per_update = (
            f"{elapsed / args.updates * 1e3:.1f} ms an update of {steps / args.updates:.1f}"
        )
        print(f"N={n}: built in {built:.1f} s; {rate}, "
              f"{per_update} steps")  # fmt: skip
        if args.no_profile:
            continue
        activities = [ProfilerActivity.CPU]
        if args.device == "cuda":
            activities.append(ProfilerActivity.CUDA)
        wall = time.time()
        with profile(activities=activities) as prof:
            for _ in range(3):
                batch.update()
            sync(args.device)
        wall = time.time() - wall
        averages = prof.key_averages()
        print(averages.table(sort_by="self_cpu_time_total", row_limit=18, max_name_column_width=48))
        if args.device == "cuda":
            print(averages.table(sort_by="self_device_time_total", row_limit=12,
                                 max_name_column_width=48))  # fmt: skip
            # the kernels' own time (an op's row repeats its kernels' time as its own)
            busy = sum(e.self_device_time_total for e in prof.events()
                       if e.device_type == DeviceType.CUDA) / 1e6  # fmt: skip
            print(f"N={n}: the kernels' time {busy * 1e3 / 3:.1f} ms an update (profiled: "
                  f"{wall * 1e3 / 3:.1f} ms an update of wall time)")  # fmt: skip
        del batch
    return 0


if __name__ == "__main__":
    sys.exit(main())
