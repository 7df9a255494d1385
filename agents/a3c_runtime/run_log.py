"""What the main process writes while a run goes: TensorBoard scalars (CleanRL's charts/ and
losses/ names, eval/ for the evaluations), evaluations.csv, and the console's progress lines."""

from __future__ import annotations

import contextlib
import csv
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .checkpoints import WriteFailed
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
    """The main process's outputs: TensorBoard scalars, evaluations.csv and the console. A write
    that fails raises WriteFailed naming the file; a failed row of evaluations.csv is taken back,
    so the file stays whole."""

    def __init__(self, run_dir: Path, args: Any, wall_offset: float):
        from torch.utils.tensorboard import SummaryWriter

        self.args, self.start, self.wall_offset = args, time.time(), wall_offset
        self.csv_path = run_dir / "evaluations.csv"
        self.events_path = run_dir / "events.out.tfevents.*"
        self.last_eval = last_evaluation(self.csv_path)  # a resumed run's, until its next one
        self.recent_return = float("nan")
        self.eval_seconds = 0.0
        new_csv = not self.csv_path.exists()
        try:
            self.csv_fd = os.open(self.csv_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        except OSError as e:
            raise WriteFailed(self.csv_path, e) from e
        self.writer = None
        if new_csv:
            self.append_row(CSV_COLUMNS)
        with self.writing_events():
            self.writer = SummaryWriter(str(run_dir))
            table = "\n".join(f"|{k}|{v}|" for k, v in vars(args).items())
            self.writer.add_text("hyperparameters", "|param|value|\n|-|-|\n" + table)

    def append_row(self, values: Any) -> None:
        """One line of evaluations.csv, all or nothing."""
        line = ",".join(str(v) for v in values) + "\n"
        size = os.fstat(self.csv_fd).st_size
        try:
            data = line.encode()
            while data:
                data = data[os.write(self.csv_fd, data) :]
        except OSError as e:
            with contextlib.suppress(OSError):
                os.ftruncate(self.csv_fd, size)
            raise WriteFailed(self.csv_path, e) from e

    @contextlib.contextmanager
    def writing_events(self):
        """TensorBoard's writer thread reports a failed write at the next call."""
        try:
            yield
        except OSError as e:
            raise WriteFailed(self.events_path, e) from e

    def wall_time(self) -> float:
        """Seconds of training, including those before --resume."""
        return self.wall_offset + time.time() - self.start

    def evaluation(self, result: dict) -> None:
        scores = np.asarray(result["scores"])
        row = {"global_step": result["global_step"], "wall_time_s": round(self.wall_time(), 2),
               "mean_return": float(scores.mean()), "std_return": float(scores.std()),
               "episodes": len(scores)}  # fmt: skip
        self.append_row(row.values())
        with self.writing_events():
            self.writer.add_scalar("eval/mean_return", row["mean_return"], row["global_step"])
            self.writer.add_scalar("eval/std_return", row["std_return"], row["global_step"])
        self.last_eval = row
        self.eval_seconds += result["seconds"]

    def progress(self, global_step: int, sps: float, lr: float, stats_delta: torch.Tensor) -> None:
        """Log the scalars of the last interval; stats_delta holds Shared.STATS summed."""
        episodes, return_sum, length_sum, updates = stats_delta[:4].tolist()
        with self.writing_events():
            self.writer.add_scalar("charts/SPS", sps, global_step)
            self.writer.add_scalar("charts/learning_rate", lr, global_step)
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

    def close(self, quietly: bool = False) -> None:
        """Flush and close; quietly: when the run already failed, a second failure is dropped."""
        try:
            with self.writing_events():
                if self.writer is not None:
                    self.writer.close()
        except WriteFailed:
            if not quietly:
                raise
        finally:
            if self.csv_fd >= 0:
                os.close(self.csv_fd)
                self.csv_fd = -1
