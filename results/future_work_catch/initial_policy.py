"""GLPQ's policy at initialisation on Catch, with --prototype-init uniform (the thesis's) and data.

    cd results/future_work_catch && python initial_policy.py > initial_policy.txt

For each initialisation: the network of a3c_glpq.py's defaults built with seed 1 (as a run
builds it), its prototypes placed as a new run places them, then the relative distances mu of
eq. 7.7 and the policy on 512 other states of random play (seed 5).
"""

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "agents"))
import a3c_glpq as glpq  # noqa: E402

import catch_env  # noqa: E402, F401  (registers Catch-v0)

print("init     mean |h|^2   mu min    mu max   mean max pi   mean entropy (ln 3 = 1.0986)")
for init in ("uniform", "data"):
    torch.manual_seed(1)
    args = glpq.resolve_defaults(glpq.Args(prototype_init=init, seed=1))
    model = glpq.ActorCritic(3, args)
    glpq.initialize_network(model, args)
    frames = glpq.random_play_frames("Catch-v0", np.random.default_rng(5), 5)
    with torch.no_grad():
        hidden = model.features(torch.from_numpy(frames))
        distances = glpq.prototype_distances(hidden, model.prototypes, args.distance)
        mu = glpq.relative_distances(distances.view(len(hidden), 3, -1))
        log_pi = model.log_policy(hidden)
    pi = log_pi.exp()
    print(
        f"{init:8} {hidden.square().sum(1).mean():10.0f} {mu.min():9.4f} {mu.max():8.4f} "
        f"{pi.max(1).values.mean():13.4f} {-(pi * log_pi).sum(1).mean():14.4f}"
    )
