"""Where training takes GLPQ's features and prototypes: the thesis's (a3c_glpq.py), the data's
(a3c_glpq_data_init.py), the value head's (a3c_glpq_value_head.py; both in agents/future_work/).

    python -m a3c_tools.future_work_trained_scale > results/future_work_catch/trained_scale.txt

For each run of the glpq, glpq_data and glpq_value configurations: the network as the run built
it (its seed, its prototypes placed as a new run places them) and as its final checkpoint left
it (FOLDER/CONFIG/runs/<run>/checkpoint.pt, which the sweep writes and the repository does not
commit: run the configurations first), on 512 states of random play (seed 5): the mean squared
norm of the features h and of the policy prototypes w, how far the prototypes moved (mean
|w_final - w_init| per element, against the mean |w_init|), the spread of eq. 7.7's mu, the
policy's entropy, and for the value head the spread of V over the states and exp(entropy of g),
the number of value prototypes a state's V effectively averages (1: V is the value of the
nearest one).
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import torch

from a3c_tools import AGENTS, load_script, run_main
from a3c_tools.future_work_initial_policy import features
from a3c_tools.future_work_runs import folder_argument

CONFIGS = {
    "glpq": AGENTS / "a3c_glpq.py",
    "glpq_data": AGENTS / "future_work" / "a3c_glpq_data_init.py",
    "glpq_value": AGENTS / "future_work" / "a3c_glpq_value_head.py",
}
HEADER = ("config     run       |h|^2 init final   |w|^2 init final   mean|dw| / mean|w|   "
          "mu std init final   entropy init final (ln 3 = 1.0986)   V std final   "
          "value prototypes averaged init final")  # fmt: skip


def statistics(model: torch.nn.Module, glpq: object, frames: np.ndarray) -> list[float]:
    with torch.no_grad():
        hidden = features(model, torch.from_numpy(frames))
        distances = glpq.prototype_distances(hidden, model.prototypes, model.distance)
        mu = glpq.relative_distances(distances.view(len(hidden), 3, -1))
        log_pi = model.log_policy(hidden)
        value = model(torch.from_numpy(frames))[1]
        spread, effective = float(value.std()), float("nan")
        if hasattr(model, "value_prototypes"):
            d = glpq.prototype_distances(hidden, model.value_prototypes, model.distance)
            log_g = torch.log_softmax(-model.log_value_beta.exp() * d, dim=-1)
            effective = float((-(log_g.exp() * log_g).sum(1)).exp().mean())
        norm_w = model.prototypes.square().sum(1).mean()
    entropy = -(log_pi.exp() * log_pi).sum(1).mean()
    norm_h = hidden.square().sum(1).mean()
    return [float(norm_h), float(norm_w), float(mu.std()), float(entropy), spread, effective]


def scale_rows(folder: Path) -> list[str]:
    import a3c_runtime

    import catch_env  # noqa: F401  (registers Catch-v0)

    data_init = load_script(CONFIGS["glpq_data"])
    frames = data_init.random_play_frames("Catch-v0", np.random.default_rng(5), 5)
    rows = []
    for config, script in CONFIGS.items():
        glpq = load_script(script)
        with open(folder / config / "results.csv", newline="") as f:
            runs = [(r["run_id"], int(r["seed"])) for r in csv.DictReader(f) if r["status"] == "ok"]
        for run_id, seed in sorted(runs):
            torch.manual_seed(seed)
            args = a3c_runtime.resolve_defaults(glpq.Args(seed=seed))
            model = glpq.ActorCritic(3, args)
            if glpq.AGENT.initialize is not None:
                glpq.AGENT.initialize(model, args)
            start = statistics(model, glpq, frames)
            initial = model.prototypes.detach().clone()
            path = folder / config / "runs" / run_id / "checkpoint.pt"
            checkpoint = a3c_runtime.load_checkpoint(str(path), glpq.AGENT)
            a3c_runtime.load_network(model, checkpoint, str(path))
            end = statistics(model, glpq, frames)
            moved = (model.prototypes.detach() - initial).abs().mean() / initial.abs().mean()
            rows.append(
                f"{config:10} {run_id}  {start[0]:8.1f} {end[0]:6.1f}   {start[1]:8.1f} "
                f"{end[1]:6.1f}   {moved:18.4f}   {start[2]:10.4f} {end[2]:6.4f}   "
                f"{start[3]:12.4f} {end[3]:6.4f}   {end[4]:34.3f}   {start[5]:16.2f} {end[5]:5.2f}"
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    about = "GLPQ's features and prototypes at the start and end of each run."
    folder = folder_argument("future_work_trained_scale", about, argv, lambda folder: CONFIGS)
    from a3c_runtime import UsageError

    try:
        rows = scale_rows(folder)
    except UsageError as e:  # a missing, changed or foreign checkpoint: one line
        print(f"error: {e}", file=sys.stderr)
        return 2
    print("\n".join([HEADER, *rows]))
    return 0


if __name__ == "__main__":
    run_main(main)
