"""Where training takes the features and the prototypes: GLPQ, --prototype-init uniform and data.

    cd results/future_work_catch && python trained_scale.py > trained_scale.txt

For each run of the glpq and glpq_data configurations: the network as the run built it (its
seed, its prototypes placed as a new run places them) and as its final checkpoint left it
(runs/<run>/checkpoint.pt, which the sweep writes and the repository does not commit: run the
two configurations first), on 512 states of random play (seed 5): the mean squared norm of the
features h and of the prototypes w, how far the prototypes moved (mean |w_final - w_init| per
element, against the mean |w_init|), the spread of eq. 7.7's mu, and the policy's entropy.
"""

import csv
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "agents"))
import a3c_glpq as glpq  # noqa: E402

import catch_env  # noqa: E402, F401  (registers Catch-v0)


def statistics(model: glpq.ActorCritic, args: glpq.Args, frames: np.ndarray) -> list[float]:
    with torch.no_grad():
        hidden = model.features(torch.from_numpy(frames))
        distances = glpq.prototype_distances(hidden, model.prototypes, args.distance)
        mu = glpq.relative_distances(distances.view(len(hidden), 3, -1))
        log_pi = model.log_policy(hidden)
    entropy = -(log_pi.exp() * log_pi).sum(1).mean()
    norm_h, norm_w = hidden.square().sum(1).mean(), model.prototypes.detach().square().sum(1).mean()
    return [float(norm_h), float(norm_w), float(mu.std()), float(entropy)]


frames = glpq.random_play_frames("Catch-v0", np.random.default_rng(5), 5)
print("config     run       |h|^2 init final   |w|^2 init final   mean|dw| / mean|w|   "
      "mu std init final   entropy init final (ln 3 = 1.0986)")  # fmt: skip
for config, init in (("glpq", "uniform"), ("glpq_data", "data")):
    with open(HERE / config / "results.csv", newline="") as f:
        runs = [(r["run_id"], int(r["seed"])) for r in csv.DictReader(f) if r["status"] == "ok"]
    for run_id, seed in sorted(runs):
        torch.manual_seed(seed)
        args = glpq.resolve_defaults(glpq.Args(prototype_init=init, seed=seed))
        model = glpq.ActorCritic(3, args)
        glpq.initialize_network(model, args)
        start = statistics(model, args, frames)
        initial = model.prototypes.detach().clone()
        path = HERE / config / "runs" / run_id / "checkpoint.pt"
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
        model.load_state_dict(checkpoint["model"])
        end = statistics(model, args, frames)
        moved = (model.prototypes.detach() - initial).abs().mean() / initial.abs().mean()
        print(
            f"{config:10} {run_id}  {start[0]:8.1f} {end[0]:6.1f}   {start[1]:8.1f} {end[1]:6.1f}"
            f"   {moved:18.4f}   {start[2]:10.4f} {end[2]:6.4f}   {start[3]:12.4f} {end[3]:6.4f}"
        )
