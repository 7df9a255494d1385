"""Where training takes GLPQ's features and prototypes: the thesis's, the data's, the value head's.

    cd results/future_work_catch && python trained_scale.py > trained_scale.txt

For each run of the glpq, glpq_data and glpq_value configurations: the network as the run built
it (its seed, its prototypes placed as a new run places them) and as its final checkpoint left
it (runs/<run>/checkpoint.pt, which the sweep writes and the repository does not commit: run the
configurations first), on 512 states of random play (seed 5): the mean squared norm of the
features h and of the policy prototypes w, how far the prototypes moved (mean |w_final - w_init|
per element, against the mean |w_init|), the spread of eq. 7.7's mu, the policy's entropy, and
for the value head the spread of V over the states and exp(entropy of g), the number of value
prototypes a state's V effectively averages (1: V is the value of the nearest one).
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
        value = model.state_value(hidden)
        spread, effective = float(value.std()), float("nan")
        if args.value_head == "prototypes":
            d = glpq.prototype_distances(hidden, model.value_prototypes, args.distance)
            log_g = torch.log_softmax(-model.log_value_beta.exp() * d, dim=-1)
            effective = float((-(log_g.exp() * log_g).sum(1)).exp().mean())
        norm_w = model.prototypes.square().sum(1).mean()
    entropy = -(log_pi.exp() * log_pi).sum(1).mean()
    norm_h = hidden.square().sum(1).mean()
    return [float(norm_h), float(norm_w), float(mu.std()), float(entropy), spread, effective]


frames = glpq.random_play_frames("Catch-v0", np.random.default_rng(5), 5)
print("config     run       |h|^2 init final   |w|^2 init final   mean|dw| / mean|w|   "
      "mu std init final   entropy init final (ln 3 = 1.0986)   V std final   "
      "value prototypes averaged init final")  # fmt: skip
CONFIGS = (("glpq", "uniform", "linear"), ("glpq_data", "data", "linear"),
           ("glpq_value", "uniform", "prototypes"))  # fmt: skip
for config, init, value_head in CONFIGS:
    with open(HERE / config / "results.csv", newline="") as f:
        runs = [(r["run_id"], int(r["seed"])) for r in csv.DictReader(f) if r["status"] == "ok"]
    for run_id, seed in sorted(runs):
        torch.manual_seed(seed)
        args = glpq.Args(prototype_init=init, value_head=value_head, seed=seed)
        args = glpq.resolve_defaults(args)
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
            f"   {end[4]:34.3f}   {start[5]:16.2f} {end[5]:5.2f}"
        )
