"""a3c_runtime.run_log: the console's progress lines."""

import time
from types import SimpleNamespace

import a3c_runtime as runtime
import pytest
import torch

import catch_env  # noqa: F401  (registers Catch-v0)


def progress_args() -> SimpleNamespace:
    return SimpleNamespace(total_timesteps=4000, learning_rate=1e-3, anneal_lr=True,
                           log_interval=5.0)  # fmt: skip


def test_a_resumed_runs_progress_shows_its_last_evaluation(tmp_path, capsys):
    (tmp_path / "evaluations.csv").write_text(
        "global_step,wall_time_s,mean_return,std_return,episodes\n"
        "0,0.1,0.2,0.4,5\n2000,3.5,0.75,0.4,5\n"
    )
    log = runtime.RunLog(tmp_path, progress_args(), wall_offset=3.6)
    log.progress(2500, torch.zeros(len(runtime.Shared.STATS)))
    log.close()
    assert "| eval 0.750 @ 2,000 |" in capsys.readouterr().out


def test_a_failed_evaluation_row_is_taken_back_and_named(tmp_path, monkeypatch, capsys):
    import errno
    import os

    args = SimpleNamespace(total_timesteps=4000)
    log = runtime.RunLog(tmp_path, args, wall_offset=0.0)
    log.evaluation({"global_step": 0, "scores": [0.0, 1.0], "seconds": 0.1})
    csv_path = tmp_path / "evaluations.csv"
    before = csv_path.read_bytes()
    write = os.write

    def write_half_then_fail(fd, data):
        if fd == log.csv_fd:
            write(fd, data[: len(data) // 2])  # a partial line reaches the disk, then it is full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return write(fd, data)

    monkeypatch.setattr(os, "write", write_half_then_fail)
    with pytest.raises(runtime.WriteFailed, match="evaluations.csv: No space left on device"):
        log.evaluation({"global_step": 1000, "scores": [1.0], "seconds": 0.1})
    monkeypatch.setattr(os, "write", write)
    assert csv_path.read_bytes() == before  # whole rows only
    log.close()


@pytest.mark.parametrize(
    ("outcome", "label"),
    [("done", "final eval"), ("time limit", "final eval"), ("stopped by SIGINT", "last eval")],
)
def test_the_closing_line_labels_the_last_evaluation_truthfully(outcome, label, tmp_path, capsys):
    """A run stopped by a signal takes no final evaluation: its last one (here step 0's) is
    not the final one, as the closing line once said ("final eval 0.140 at step 0")."""
    from a3c_runtime.run_log import summarize

    log = runtime.RunLog(tmp_path, SimpleNamespace(total_timesteps=10**6), wall_offset=0.0)
    log.evaluation({"global_step": 0, "scores": [0.0, 0.28], "seconds": 0.1})
    log.close()
    capsys.readouterr()
    summary = summarize(outcome, 1000.0, 44_430, log, tmp_path)
    line = capsys.readouterr().out
    assert line.startswith(f"{outcome}: {label} 0.140 at step 0 |"), line
    assert "| 44,430 steps |" in line and summary["final_eval_step"] == 0


def test_the_progress_line_gives_the_step_its_share_of_t_max_and_the_time_left(
    tmp_path, capsys, monkeypatch
):
    """2,000 steps in the 20 s since the last line (step 500's): SPS 100, and 1,500 steps left
    take 15 s; TensorBoard gets the learning rate annealed to step 2,500."""
    log = runtime.RunLog(tmp_path, progress_args(), wall_offset=0.0)
    logged = {}
    log.scalars = lambda values, step: logged.update(values)
    log.last_progress = (1000.0, 500, torch.zeros(len(runtime.Shared.STATS)).double())
    monkeypatch.setattr(runtime.run_log.time, "time", lambda: 1020.0)
    assert log.progress_due()
    log.progress(2500, torch.zeros(len(runtime.Shared.STATS)))
    assert not log.progress_due()  # the next line 5 s (--log-interval) after this one
    log.close()
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith("step 2,500/4,000 (62.5%) | SPS 100 | return ")
    assert line.endswith(f"| ETA {runtime.run_log.format_seconds(15.0)}")  # 1,500 steps at 100/s
    assert logged["charts/SPS"] == 100.0 and logged["charts/learning_rate"] == 1e-3 * 1500 / 4000


def test_the_progress_line_gives_the_mean_return_of_the_episodes_ended_in_its_interval(
    tmp_path, capsys
):
    """4 episodes ended since the last line, returns summing to 2.0 over 60 steps: the line and
    TensorBoard say return 0.500 and length 15."""
    log = runtime.RunLog(tmp_path, progress_args(), wall_offset=0.0)
    logged = {}
    log.scalars = lambda values, step: logged.update(values)
    stats = dict.fromkeys(runtime.Shared.STATS, 0.0)
    stats.update(episodes=3, return_sum=1.0, length_sum=30, updates=1, entropy=5.0)
    log.progress(1000, torch.tensor([stats[k] for k in runtime.Shared.STATS]))
    stats.update(episodes=7, return_sum=3.0, length_sum=90, updates=3, entropy=7.0)
    log.progress(2500, torch.tensor([stats[k] for k in runtime.Shared.STATS]))
    log.close()
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "| return 0.500 |" in line, line
    assert logged["charts/episodic_return"] == 0.5 and logged["charts/episodic_length"] == 15
    assert logged["losses/entropy"] == 1.0


def test_a_resumed_runs_closing_line_gives_this_parts_time_beside_the_runs(tmp_path, capsys):
    """A resumed run's wall time is its own clock, the earlier parts included; this part's time
    is the time since this process started it."""
    from a3c_runtime.run_log import summarize

    log = runtime.RunLog(tmp_path, SimpleNamespace(total_timesteps=10**6), wall_offset=100.0)
    log.start -= 30.0  # this part began 30 s ago
    log.close()
    capsys.readouterr()
    summary = summarize("done", 1000.0, 10, log, tmp_path)
    assert summary["part_time_s"] == pytest.approx(30.0, abs=2.0)
    assert summary["wall_time_s"] == pytest.approx(130.0, abs=2.0)
    assert "wall time 2m10s (this part 0m30s, its evaluations" in capsys.readouterr().out


def test_rows_after_a_checkpoints_step_are_dropped_and_counted(tmp_path, capsys):
    csv_path = tmp_path / "evaluations.csv"
    rows = "".join(f"{step},1.0,0.5,0.1,5\n" for step in (0, 100, 200, 300))
    csv_path.write_text("global_step,wall_time_s,mean_return,std_return,episodes\n" + rows)
    runtime.run_log.drop_rows_after(csv_path, 100)
    assert [line.split(",")[0] for line in csv_path.read_text().split()] == [
        "global_step", "0", "100"]  # fmt: skip
    assert capsys.readouterr().out == (
        "note: evaluations.csv: 2 evaluation(s) logged after the checkpoint's step 100 dropped\n"
    )
    runtime.run_log.drop_rows_after(csv_path, 100)  # nothing after it: nothing said
    assert capsys.readouterr().out == ""


def test_a_resumed_run_hides_the_scalars_logged_after_its_checkpoint(tmp_path):
    """A run killed after its checkpoint at step 100 had logged step 150; resumed from 100, it
    logs 150 again. TensorBoard shows each step once, the resumed run's (the writer's purge
    step), not the killed run's beside it."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    args = SimpleNamespace(total_timesteps=4000)
    killed = runtime.RunLog(tmp_path, args, wall_offset=0.0)
    for step in (50, 100, 150):
        killed.scalars({"charts/SPS": float(step)}, step)
    killed.close()
    # TensorBoard reads a folder's event files in name order, and a name starts with its second:
    # a second later, the resumed run's file sorts after the killed run's, as it would in use
    time.sleep(1.1)
    resumed = runtime.RunLog(tmp_path, args, wall_offset=1.0, resumed_step=100)
    resumed.scalars({"charts/SPS": 151.0}, 150)
    resumed.close()
    events = EventAccumulator(str(tmp_path))
    events.Reload()
    shown = [(e.step, e.value) for e in events.Scalars("charts/SPS")]
    assert shown == [(50, 50.0), (100, 100.0), (150, 151.0)]
