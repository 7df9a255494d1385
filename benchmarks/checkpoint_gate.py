"""The checkpoint gate's time: a checkpoint of agents/a3c_ff.py with every part (the network, its
RMSprop statistics, a pending evaluation's network, one worker with two Catch games) read as
--resume, --evaluate and a sweep's scan read it (open_checkpoint, then for_agent: the header,
the seal, the schema, the tensor table against the network, the tensors and their values), in
ms a load; one torch thread. Against another commit, in the same run:

    python benchmarks/against_commit.py BASE --rounds 3 --out FILE --measure "gate" \
        "^checkpoint gate: ([\\d.]+) ms" "python $PWD/benchmarks/checkpoint_gate.py"

(the script from this tree, the runtime and agents/a3c_ff.py from the tree it runs in).
"""

from __future__ import annotations

import argparse
import importlib.util
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--loads", type=int, default=40, help="loads timed (default 40)")
    args = parser.parse_args(argv)
    import a3c_runtime as runtime
    import numpy as np
    import torch

    from catch_env.wrappers import make_vector_env

    torch.set_num_threads(1)
    module = sys.modules.get("a3c_ff")  # (the script, once per process: its Args by name)
    if module is None:
        agents = Path(runtime.__file__).resolve().parents[1]  # (the tree whose runtime runs)
        spec = importlib.util.spec_from_file_location("a3c_ff", agents / "a3c_ff.py")
        module = sys.modules["a3c_ff"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    flags = runtime.resolve_defaults(module.Args(num_workers=1, envs_per_worker=2))
    context = multiprocessing.get_context("fork")
    shared = runtime.Shared(module.AGENT.build_network(3, flags), flags, context)
    envs = make_vector_env("Catch-v0", 2)
    obs, _ = envs.reset(seed=3)
    worker = (np.random.default_rng(7), envs, obs.copy())
    snapshot = {
        "workers": {0: runtime.snapshots.saved_state(worker)},
        "pending_evaluations": [(1000, runtime.snapshots.copy_of(shared.model.state_dict()))],
    }
    path = Path(tempfile.mkdtemp()) / "checkpoint.pt"
    runtime.save_checkpoint(path, shared, flags, 1.0, "a3c_ff.py", snapshot)
    data = path.read_bytes()
    load = lambda: runtime.checkpoints.for_agent(  # noqa: E731
        runtime.checkpoints.open_checkpoint(str(path), data=data), module.AGENT
    )
    load()  # (the first builds what later loads reuse)
    start = time.perf_counter()
    for _ in range(args.loads):
        load()
    ms = (time.perf_counter() - start) / args.loads * 1000
    print(f"checkpoint gate: {ms:.1f} ms a load of {len(data) / 1e6:.1f} MB ({args.loads} loads)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
