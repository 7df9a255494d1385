"""A run's training scalars by 1M steps, from its TensorBoard events (FOLDER/tensorboard/):

    python -m a3c_tools.training_scalars results/breakout_a3c_ff/native_10M > \\
        results/breakout_a3c_ff/native_10M/training_scalars.txt

Each column is the mean of the logged values in the 500k steps up to that step. The entropy is
logged as a sum over the update's rollout (K x t_max states, --rollout-states, 16 x 5 = 80 for the
Atari command); it is also shown per state, against ln 4 = 1.386 for Breakout's 4 actions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from a3c_tools import run_main, tool_parser

MARKS = [m * 1_000_000 for m in (0.5, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10)]
ROWS = (
    ("learning rate", "charts/learning_rate", False),
    ("training episodes' score", "charts/episodic_return", False),
    ("entropy per state (nats)", "losses/entropy", True),  # True: divided by the rollout's states
    ("gradient norm (before clip)", "losses/grad_norm", False),
)


def by_mark(steps: np.ndarray, values: np.ndarray) -> list[str]:
    """The mean of the values in the 500k steps up to each mark ('-' where none was logged)."""
    cells = []
    for mark in MARKS:
        window = (steps > mark - 500_000) & (steps <= mark)
        cells.append(f"{values[window].mean():9.3g}" if window.any() else f"{'-':>9}")
    return cells


def table(folder: Path, rollout_states: int) -> list[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder / "tensorboard"), size_guidance={"scalars": 0})
    events.Reload()
    lines = [f"{'step':28}" + "".join(f"{m / 1e6:8.1f}M" for m in MARKS)]
    for label, tag, per_state in ROWS:
        scalars = events.Scalars(tag)
        steps = np.array([s.step for s in scalars])
        values = np.array([s.value for s in scalars]) / (rollout_states if per_state else 1)
        lines.append(f"{label:28}" + "".join(by_mark(steps, values)))
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser(
        "training_scalars", "A run's training scalars by 1M steps, from its TensorBoard events."
    )
    parser.add_argument("folder", type=Path, help="a run folder (with tensorboard/ inside)")
    parser.add_argument(
        "--rollout-states",
        type=int,
        default=16 * 5,
        help="K x t_max, the states of one update (default 80)",
    )
    options = parser.parse_args(argv)
    if not (options.folder / "tensorboard").is_dir():
        parser.error(f"{options.folder / 'tensorboard'} is not a folder of TensorBoard events")
    for line in table(options.folder, options.rollout_states):
        print(line)
    return 0


if __name__ == "__main__":
    run_main(main)
