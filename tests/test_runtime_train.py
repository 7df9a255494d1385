"""a3c_runtime.a3c.train's main loop, in process (one worker on Catch, a few seconds): what the
slow tier's subprocess runs check at length, checked here at the size a fast test affords."""

import os
import signal
import threading
import time

from conftest import load_script, main_exit, read_checkpoint

import catch_env  # noqa: F401  (registers Catch-v0)


def test_a_time_limit_stops_the_run_after_that_many_seconds_not_before(
    tmp_path, monkeypatch, capsys
):
    run_dir = tmp_path / "run"
    flags = ["--num-workers", "1", "--total-timesteps", "100000000", "--time-limit", "2",
             "--eval-interval", "100000000", "--eval-episodes", "1", "--log-interval", "60",
             "--run-dir", str(run_dir)]  # fmt: skip
    code, err = main_exit(load_script("a3c_ff"), flags, monkeypatch, capsys)
    assert code == 0, err
    checkpoint = read_checkpoint(run_dir / "checkpoint.pt")
    assert checkpoint["wall_time"] >= 2.0 and checkpoint["global_step"] > 0


def test_a_signal_stops_the_run_at_once_with_its_checkpoint_and_no_final_evaluation(
    tmp_path, monkeypatch, capsys
):
    """SIGTERM to the run's main process (here: this process, from a thread, once the run has
    logged its step-0 evaluation): the run stops, writes its checkpoint, plays no final
    evaluation, and says "stopped by SIGTERM" (not "in the final evaluation": no final
    evaluation was running) with the command that resumes it."""
    run_dir = tmp_path / "run"
    flags = ["--num-workers", "1", "--total-timesteps", "100000000", "--eval-interval",
             "100000000", "--eval-episodes", "1", "--log-interval", "60",
             "--run-dir", str(run_dir)]  # fmt: skip

    def signal_once_started() -> None:
        deadline = time.time() + 60
        csv = run_dir / "evaluations.csv"
        while time.time() < deadline and len(csv.read_text().splitlines() if csv.exists() else
                                             []) < 2:  # fmt: skip
            time.sleep(0.05)
        time.sleep(0.5)  # some updates in
        os.kill(os.getpid(), signal.SIGTERM)

    sender = threading.Thread(target=signal_once_started)
    sender.start()
    code, _ = main_exit(load_script("a3c_ff"), flags, monkeypatch, capsys, keep_out=True)
    sender.join()
    out = capsys.readouterr().out
    assert code == 0
    closing = [line for line in out.splitlines() if line.startswith("stopped by")]
    assert len(closing) == 1 and closing[0].startswith("stopped by SIGTERM: last eval"), out
    assert "in the final evaluation" not in out
    checkpoint = read_checkpoint(run_dir / "checkpoint.pt")
    assert checkpoint["global_step"] > 0
    steps = [line.split(",")[0] for line in (run_dir / "evaluations.csv").read_text().split()]
    assert steps[1:] == ["0"], steps  # the step-0 evaluation only: no final one
    assert f"survives; resume: python a3c_ff.py --resume {run_dir / 'checkpoint.pt'}" in out
