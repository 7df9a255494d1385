"""What the main process writes while a run goes: TensorBoard scalars (CleanRL's charts/ and
losses/ names, eval/ for the evaluations), evaluations.csv, and the console's progress lines."""

from __future__ import annotations

import contextlib
import csv
import math
import os
import threading
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch

from .checkpoints import WriteFailed, write_atomically
from .hogwild import Shared, annealed_lr

CSV_COLUMNS = ["global_step", "wall_time_s", "mean_return", "std_return", "episodes"]


def format_seconds(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m{secs:02d}s" if hours else f"{minutes}m{secs:02d}s"


def drop_rows_after(csv_path: Path, step: int) -> None:
    """Rewrite evaluations.csv (atomically) without the rows after global step `step`."""
    with open(csv_path, newline="") as f:
        lines = f.read().splitlines(keepends=True)
    kept = [line for line in lines[1:] if int(line.split(",", 1)[0]) <= step]
    if len(kept) < len(lines) - 1:
        write_atomically(csv_path, "".join(lines[:1] + kept).encode())
        dropped = len(lines) - 1 - len(kept)
        print(f"note: {csv_path.name}: {dropped} evaluation(s) logged after the checkpoint's "
              f"step {step:,} dropped", flush=True)  # fmt: skip


def logged_steps(csv_path: Path, up_to: int) -> set[int]:
    """The steps of the evaluations.csv rows up to step up_to (none without the file)."""
    if not csv_path.exists():
        return set()
    with open(csv_path, newline="") as f:
        steps = {int(row["global_step"]) for row in csv.DictReader(f)}
    return {step for step in steps if step <= up_to}


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


def start_wandb(args: Any, run_dir: Path) -> Any:
    """--track: a Weights & Biases run (CleanRL's way): the flags are its config, the run folder
    its name; RunLog logs to it each scalar it gives TensorBoard, against global_step. Logged
    directly rather than with sync_tensorboard=True: W&B's reading of the events file missed
    scalars (all of them, or the last ones) in runs that end soon after they start (W&B 0.31).
    WANDB_MODE (online, offline) and the credentials are W&B's own settings."""
    import wandb

    run = wandb.init(
        project=args.wandb_project_name,
        entity=args.wandb_entity,
        name=run_dir.name,
        dir=str(run_dir),
        config=vars(args),
        resume="allow",
        id=run_dir.name.replace("__", "-"),  # a resumed run continues its W&B run
        settings=wandb.Settings(quiet=True),
    )
    # the x axis of every chart: evaluations arrive after later progress lines, so W&B's own
    # step, which must only grow, cannot be the environment step
    run.define_metric("global_step")
    run.define_metric("*", step_metric="global_step")
    return run


class RunLog:
    """The main process's outputs: TensorBoard scalars, evaluations.csv and the console. A write
    that fails raises WriteFailed naming the file; a failed row of evaluations.csv is taken back,
    so the file stays whole."""

    def __init__(
        self,
        run_dir: Path,
        args: Any,
        wall_offset: float,
        resumed_step: int = 0,
        console: TextIO | None = None,
    ):
        """resumed_step: a resumed run's checkpoint step. What the run logged after it (it ended
        without a checkpoint at its last step: a killed process, a failed write) is dropped, so
        the resumed run's rows and scalars carry on from the checkpoint without repeats.
        console: where the progress lines go (stdout by default; the sweep's batched backend,
        whose many runs share one stdout, gives each run its stdout.log)."""
        from torch.utils.tensorboard import SummaryWriter

        self.args, self.start, self.wall_offset = args, time.time(), wall_offset
        self.console = console
        self.csv_path = run_dir / "evaluations.csv"
        self.events_path = run_dir / "events.out.tfevents.*"
        if resumed_step and self.csv_path.exists():
            drop_rows_after(self.csv_path, resumed_step)
        self.last_eval = last_evaluation(self.csv_path)  # a resumed run's, until its next one
        self.recent_return = float("nan")
        self.eval_seconds = 0.0
        # (time, step, Shared.STATS totals) of the last progress line: its interval's start
        self.last_progress = (self.start, resumed_step, torch.zeros(len(Shared.STATS)).double())
        try:
            self.csv_fd = os.open(self.csv_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        except OSError as e:
            raise WriteFailed(self.csv_path, e) from e
        self.writer = None
        if os.fstat(self.csv_fd).st_size == 0:
            self.append_row(CSV_COLUMNS)
        self.quiet_writer_thread()
        self.wandb = start_wandb(args, run_dir) if getattr(args, "track", False) else None
        with self.writing_events():
            # purge_step: TensorBoard hides a resumed run's old events from that step on
            self.writer = SummaryWriter(
                str(run_dir), purge_step=resumed_step + 1 if resumed_step else None
            )
            self.events_path = Path(self.writer.file_writer.get_logdir()) / os.path.basename(
                getattr(self.writer.file_writer.event_writer, "_file_name", "events.out.tfevents.*")
            )
            table = "\n".join(f"|{k}|{v}|" for k, v in vars(args).items())
            self.writer.add_text("hyperparameters", "|param|value|\n|-|-|\n" + table)

    @staticmethod
    def quiet_writer_thread() -> None:
        """TensorBoard's writer thread re-raises a failed write, which Python would print as a
        traceback; the main thread reports it as one line (WriteFailed) at the next call.
        Installed once per process: a batch of many runs' logs must not chain a hook each."""
        default = threading.excepthook
        if getattr(default, "quiets_writer_threads", False):
            return

        def hook(info: threading.ExceptHookArgs) -> None:
            if not issubclass(info.exc_type, OSError):
                default(info)

        hook.quiets_writer_threads = True
        threading.excepthook = hook

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
        self.scalars(
            {"eval/mean_return": row["mean_return"], "eval/std_return": row["std_return"]},
            row["global_step"],
        )
        self.last_eval = row
        self.eval_seconds += result["seconds"]

    def scalars(self, values: dict[str, float], global_step: int) -> None:
        """TensorBoard's scalars at global_step, and W&B's under --track."""
        with self.writing_events():
            for tag, value in values.items():
                self.writer.add_scalar(tag, value, global_step)
        if self.wandb is not None:
            self.wandb.log({**values, "global_step": global_step})

    def progress_due(self) -> bool:
        """Whether --log-interval seconds have passed since the last progress line."""
        return time.time() - self.last_progress[0] >= self.args.log_interval

    def progress(self, global_step: int, stats: torch.Tensor) -> None:
        """Log the scalars of the interval since the last progress line: its steps per second,
        the learning rate, and the change of `stats`, the run's Shared.STATS totals (summed over
        its workers)."""
        now, (last_time, last_step, last_stats) = time.time(), self.last_progress
        sps = (global_step - last_step) / max(now - last_time, 1e-9)
        lr = annealed_lr(self.args, global_step)
        self.last_progress = (now, global_step, stats.double().clone())
        stats = dict(zip(Shared.STATS, (stats - last_stats).tolist(), strict=True))
        episodes, updates = stats["episodes"], stats["updates"]
        scalars = {"charts/SPS": sps, "charts/learning_rate": lr}
        if episodes > 0:
            self.recent_return = stats["return_sum"] / episodes
            scalars["charts/episodic_return"] = self.recent_return
            scalars["charts/episodic_length"] = stats["length_sum"] / episodes
        if updates > 0:
            for key in ("policy_loss", "value_loss", "entropy", "grad_norm"):
                scalars[f"losses/{key}"] = stats[key] / updates
        self.scalars(scalars, global_step)
        total_steps = self.args.total_timesteps
        eta = (total_steps - global_step) / sps if sps > 0 else float("inf")
        last = self.last_eval
        print(
            f"step {global_step:,}/{total_steps:,} ({100 * global_step / total_steps:.1f}%) | "
            f"SPS {sps:,.0f} | return {self.recent_return:.3f} | eval "
            + (f"{last['mean_return']:.3f} @ {last['global_step']:,}" if last else "-")
            + f" | ETA {format_seconds(max(0.0, eta))}",
            file=self.console,
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
            if self.wandb is not None:
                self.wandb.finish()
                self.wandb = None


def summarize(
    outcome: str, sps: float, global_step: int, log: RunLog, run_dir: Path, batch: int = 0
) -> dict:
    """The run's summary, and its closing line on the log's console (the batched backend's runs:
    each its stdout.log, naming the `batch` size), also its "closing_line"."""
    last = log.last_eval
    summary = {
        "outcome": outcome,
        "run_dir": str(run_dir),
        "global_step": global_step,
        "final_eval": last["mean_return"] if last else float("nan"),
        "final_eval_step": last["global_step"] if last else None,
        "wall_time_s": log.wall_time(),  # the run's own clock, its parts before --resume included
        "part_time_s": time.time() - log.start,
        "eval_time_s": log.eval_seconds,
        "sps": sps,
    }
    # "final" only for the evaluation after the last update; a run stopped early (a signal)
    # took none, and its last one may be step 0's
    label = "final eval" if outcome in ("done", "time limit") else "last eval"
    eval_text = (
        f"{label} {last['mean_return']:.3f} at step {last['global_step']:,}"
        if last
        else "no evaluation"
    )
    # a resumed run's evaluation time is this part's only, so it is named as such
    evals = f"evaluations {format_seconds(log.eval_seconds)}"
    if log.wall_offset:
        evals = f"this part {format_seconds(summary['part_time_s'])}, its {evals}"
    batched = f" | batched with {batch} runs" if batch else ""
    summary["closing_line"] = (
        f"{outcome}: {eval_text} | wall time {format_seconds(summary['wall_time_s'])} "
        f"({evals}) | SPS {sps:,.0f}{batched} | {global_step:,} steps | {run_dir}"
    )
    print(summary["closing_line"], file=log.console, flush=True)
    return summary
