"""What the main process writes while a run goes: TensorBoard scalars (CleanRL's charts/ and
losses/ names, eval/ for the evaluations), evaluations.csv, and the console's progress lines."""

from __future__ import annotations

import csv
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .hogwild import Shared

CSV_COLUMNS = ["global_step", "wall_time_s", "mean_return", "std_return", "episodes"]


def format_seconds(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m{secs:02d}s" if hours else f"{minutes}m{secs:02d}s"


def last_evaluation(csv_path: Path) -> dict | None:
    """The last row of an evaluations.csv (numbers parsed), or None."""
    if not csv_path.exists():
        return None
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None
    row = rows[-1]
    return {"global_step": int(row["global_step"]), "mean_return": float(row["mean_return"])}


class RunLog:
    """The main process's outputs: TensorBoard scalars, evaluations.csv and the console."""

    def __init__(self, run_dir: Path, args: Any, wall_offset: float):
        from torch.utils.tensorboard import SummaryWriter

        self.args, self.start, self.wall_offset = args, time.time(), wall_offset
        self.writer = SummaryWriter(str(run_dir))
        self.writer.add_text(
            "hyperparameters",
            "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items()),
        )
        csv_path = run_dir / "evaluations.csv"
        self.last_eval = last_evaluation(csv_path)  # a resumed run's, until its next one
        new_csv = not csv_path.exists()
        self.csv_file = open(csv_path, "a", newline="")  # noqa: SIM115 (open for the whole run)
        self.csv = csv.writer(self.csv_file)
        if new_csv:
            self.csv.writerow(CSV_COLUMNS)
        self.recent_return = float("nan")
        self.eval_seconds = 0.0

    def wall_time(self) -> float:
        """Seconds of training, including those before --resume."""
        return self.wall_offset + time.time() - self.start

    def evaluation(self, result: dict) -> None:
        scores = np.asarray(result["scores"])
        row = {"global_step": result["global_step"], "wall_time_s": round(self.wall_time(), 2),
               "mean_return": float(scores.mean()), "std_return": float(scores.std()),
               "episodes": len(scores)}  # fmt: skip
        self.csv.writerow(row.values())
        self.csv_file.flush()
        self.writer.add_scalar("eval/mean_return", row["mean_return"], row["global_step"])
        self.writer.add_scalar("eval/std_return", row["std_return"], row["global_step"])
        self.last_eval = row
        self.eval_seconds += result["seconds"]

    def progress(self, global_step: int, sps: float, lr: float, stats_delta: torch.Tensor) -> None:
        """Log the scalars of the last interval; stats_delta holds Shared.STATS summed."""
        self.writer.add_scalar("charts/SPS", sps, global_step)
        self.writer.add_scalar("charts/learning_rate", lr, global_step)
        episodes, return_sum, length_sum, updates = stats_delta[:4].tolist()
        if episodes > 0:
            self.recent_return = return_sum / episodes
            self.writer.add_scalar("charts/episodic_return", self.recent_return, global_step)
            self.writer.add_scalar("charts/episodic_length", length_sum / episodes, global_step)
        if updates > 0:
            for key, total in zip(Shared.STATS[4:], stats_delta[4:].tolist(), strict=True):
                self.writer.add_scalar(f"losses/{key}", total / updates, global_step)
        total_steps = self.args.total_timesteps
        eta = (total_steps - global_step) / sps if sps > 0 else float("inf")
        last = self.last_eval
        print(
            f"step {global_step:,}/{total_steps:,} ({100 * global_step / total_steps:.1f}%) | "
            f"SPS {sps:,.0f} | return {self.recent_return:.3f} | eval "
            + (f"{last['mean_return']:.3f} @ {last['global_step']:,}" if last else "-")
            + f" | ETA {format_seconds(max(0.0, eta))}",
            flush=True,
        )

    def close(self) -> None:
        self.writer.close()
        self.csv_file.close()
