"""GLPQ's policy at initialisation on Catch, with the thesis's prototypes (a3c_glpq.py) and with
prototypes from the data (agents/future_work/a3c_glpq_data_init.py).

    python -m a3c_tools.future_work_initial_policy > results/future_work_catch/initial_policy.txt

For each initialisation: the network of the script's defaults built with seed 1 (as a run builds
it), its prototypes placed as a new run places them, then the relative distances mu of eq. 7.7
and the policy on 512 other states of random play (seed 5).
"""

from __future__ import annotations

import numpy as np
import torch

from a3c_tools import AGENTS, load_script, run_main, tool_parser

SCRIPTS = (
    ("uniform", AGENTS / "a3c_glpq.py"),
    ("data", AGENTS / "future_work" / "a3c_glpq_data_init.py"),
)
HEADER = "init     mean |h|^2   mu min    mu max   mean max pi   mean entropy (ln 3 = 1.0986)"


def features(model: torch.nn.Module, frames: torch.Tensor) -> torch.Tensor:
    """h (B, 256), the features a prototype network's forward computes from the frames."""
    x = frames.to(dtype=torch.float32, memory_format=torch.channels_last) * model.obs_scale
    return model.torso(x)


def initial_policy_rows() -> list[str]:
    import a3c_runtime

    import catch_env  # noqa: F401  (registers Catch-v0)

    data_init = load_script(SCRIPTS[1][1])
    frames = data_init.random_play_frames("Catch-v0", np.random.default_rng(5), 5)
    rows = []
    for init, path in SCRIPTS:
        glpq = load_script(path)
        torch.manual_seed(1)
        args = a3c_runtime.resolve_defaults(glpq.Args(seed=1))
        model = glpq.ActorCritic(3, args)
        if glpq.AGENT.initialize is not None:
            glpq.AGENT.initialize(model, args)
        with torch.no_grad():
            hidden = features(model, torch.from_numpy(frames))
            distances = glpq.prototype_distances(hidden, model.prototypes, args.distance)
            mu = glpq.relative_distances(distances.view(len(hidden), 3, -1))
            log_pi = model.log_policy(hidden)
        pi = log_pi.exp()
        rows.append(
            f"{init:8} {hidden.square().sum(1).mean():10.0f} {mu.min():9.4f} {mu.max():8.4f} "
            f"{pi.max(1).values.mean():13.4f} {-(pi * log_pi).sum(1).mean():14.4f}"
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    about = "GLPQ's initial policy on Catch with the thesis's and the data's prototypes."
    tool_parser("future_work_initial_policy", about).parse_args(argv)
    print(HEADER)
    for row in initial_policy_rows():
        print(row)
    return 0


if __name__ == "__main__":
    run_main(main)
