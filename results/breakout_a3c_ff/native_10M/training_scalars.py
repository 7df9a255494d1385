"""A run's training scalars by 1M steps, from its TensorBoard events (<folder>/tensorboard/;
by default this script's folder, seed 1's run):

    python results/breakout_a3c_ff/native_10M/training_scalars.py > \\
        results/breakout_a3c_ff/native_10M/training_scalars.txt
    python results/breakout_a3c_ff/native_10M/training_scalars.py \\
        results/breakout_a3c_ff/native_10M_seed2 > \\
        results/breakout_a3c_ff/native_10M_seed2/training_scalars.txt

Each column is the mean of the logged values in the 500k steps up to that step. The entropy is
logged as a sum over the update's rollout (K x t_max = 16 x 5 = 80 states); it is also shown per
state, against ln 4 = 1.386 for Breakout's 4 actions.
"""

import sys
from pathlib import Path

import numpy as np
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

FOLDER = (Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent) / "tensorboard"
ROLLOUT_STATES = 16 * 5
MARKS = [m * 1_000_000 for m in (0.5, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10)]

events = EventAccumulator(str(FOLDER), size_guidance={"scalars": 0})
events.Reload()


def by_mark(tag: str, scale: float = 1.0) -> list[str]:
    scalars = events.Scalars(tag)
    steps = np.array([s.step for s in scalars])
    values = np.array([s.value for s in scalars]) * scale
    cells = []
    for mark in MARKS:
        window = (steps > mark - 500_000) & (steps <= mark)
        cells.append(f"{values[window].mean():9.3g}" if window.any() else f"{'-':>9}")
    return cells


print(f"{'step':28}" + "".join(f"{m / 1e6:8.1f}M" for m in MARKS))
for label, tag, scale in (
    ("learning rate", "charts/learning_rate", 1.0),
    ("training episodes' score", "charts/episodic_return", 1.0),
    ("entropy per state (nats)", "losses/entropy", 1.0 / ROLLOUT_STATES),
    ("gradient norm (before clip)", "losses/grad_norm", 1.0),
):
    print(f"{label:28}" + "".join(by_mark(tag, scale)))
