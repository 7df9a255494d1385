"""a3c_runtime.a3c.train's main loop, in process (one worker on Catch, a few seconds): what the
slow tier's subprocess runs check at length, checked here at the size a fast test affords."""

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
