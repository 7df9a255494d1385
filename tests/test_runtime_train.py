"""a3c_runtime.a3c.train's main loop, in process (one worker on Catch, a few seconds): what the
slow tier's subprocess runs check at length, checked here at the size a fast test affords."""

import os
import signal
import threading
import time

import pytest
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


def test_a_resumed_runs_steps_per_second_count_this_parts_steps_only(tmp_path, monkeypatch, capsys):
    """Resumed at step 1,000,000 for a few hundred more: the SPS the run reports counts the
    steps it took, not the checkpoint's (which would make it some 10^5 steps/s)."""
    import a3c_runtime as runtime
    from a3c_runtime import a3c
    from conftest import shared_for, tiny_args

    module = load_script("a3c_ff")
    start = 1_000_000
    args = tiny_args(module, total_timesteps=start + 300, eval_interval=10**8, eval_episodes=1)
    shared = shared_for(module, args)
    shared.base_step[0] = start
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    runtime.save_checkpoint(path, shared, args, 1.0, script="a3c_ff.py")
    seen = {}
    summarize = a3c.summarize

    def recorded(outcome, sps, global_step, log, run_dir):
        seen.update(sps=sps, steps=global_step - start, seconds=time.time() - log.start)
        return summarize(outcome, sps, global_step, log, run_dir)

    monkeypatch.setattr(a3c, "summarize", recorded)
    code, err = main_exit(module, ["--resume", str(path)], monkeypatch, capsys)
    assert code == 0, err
    assert seen["steps"] >= 300
    # at most this part's steps over its time from the first step on (not from its start)
    assert 0 < seen["sps"] < 10 * seen["steps"] / seen["seconds"], seen


def test_a_flag_given_before_resume_applies_to_the_resumed_run(tmp_path, monkeypatch, capsys):
    """`--total-timesteps N --resume CKPT`: the flag counts wherever it stands on the command
    line; the run goes on to the new T_max."""
    import a3c_runtime as runtime
    from conftest import shared_for, tiny_args

    module = load_script("a3c_ff")
    args = tiny_args(module, total_timesteps=100, eval_interval=10**8, eval_episodes=1)
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="a3c_ff.py")
    argv = ["--total-timesteps", "200", "--resume", str(path)]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 0, err
    checkpoint = read_checkpoint(path)
    assert checkpoint["global_step"] >= 200 and checkpoint["args"]["total_timesteps"] == 200


def test_an_evaluator_falling_behind_is_announced_once(tmp_path, monkeypatch, capsys):
    """An evaluator slower than the training (here its first evaluation, step 0's, waits until
    the run has handed it more than LATE others): the console says once that it is behind, and
    every evaluation is taken all the same. The wait is for the requests, not a fixed time (on a
    loaded machine the workers may take longer than any sleep to reach the marks). Each
    checkpoint write takes 0.5 s here, as on a slow disk, so that one drain of the main process
    lasts seconds while the evaluator catches up: the check comes at each request it hands over,
    not only when the drain ends."""
    import a3c_runtime as runtime

    evaluator, evaluate = runtime.a3c.evaluator, runtime.evaluation.evaluate_network
    calls, queued = [], {}

    def evaluator_seeing_its_requests(agent, shared, args, requests, *rest):
        queued["requests"] = requests
        return evaluator(agent, shared, args, requests, *rest)

    def slow_at_first(*args, **kwargs):
        deadline = time.time() + 60
        while (
            not calls and queued["requests"].qsize() <= runtime.a3c.LATE and time.time() < deadline
        ):
            time.sleep(0.05)
        calls.append(1)
        return evaluate(*args, **kwargs)

    save_checkpoint = runtime.a3c.save_checkpoint

    def slow_save_checkpoint(*args, **kwargs):
        time.sleep(0.5)
        return save_checkpoint(*args, **kwargs)

    # (patched before the evaluator is forked: the evaluator's)
    monkeypatch.setattr(runtime.a3c, "evaluator", evaluator_seeing_its_requests)
    monkeypatch.setattr(runtime.a3c, "save_checkpoint", slow_save_checkpoint)
    monkeypatch.setattr(runtime.evaluation, "evaluate_network", slow_at_first)
    run_dir = tmp_path / "run"
    flags = ["--num-workers", "1", "--total-timesteps", "100", "--eval-interval", "10",
             "--eval-episodes", "1", "--log-interval", "60", "--run-dir", str(run_dir)]  # fmt: skip
    code, _ = main_exit(load_script("a3c_ff"), flags, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0
    notes = [line for line in out.splitlines() if line.startswith("note: the evaluator is")]
    assert len(notes) == 1, out
    assert notes[0].endswith("each is taken all the same")
    rows = (run_dir / "evaluations.csv").read_text().split()[1:]
    steps = [int(line.split(",")[0]) for line in rows]
    # step 0, one at each update that passes a mark of 10, 20, ..., 90, the final one
    assert steps[0] == 0 and steps == sorted(set(steps)) and steps[-1] >= 100, steps
    assert len(steps) >= 8, steps


@pytest.mark.parametrize("logged", [False, True])
def test_a_resumed_run_takes_the_evaluations_its_checkpoint_left_pending(
    tmp_path, monkeypatch, capsys, logged
):
    """A run stopped while its evaluator was behind keeps, in its checkpoint, the networks of the
    evaluations not yet taken; the resumed run takes each, of that network at that step, before
    its own final one (else a resumed run's evaluations.csv would lose those steps), but not one
    that the killed run logged after its checkpoint was written (logged: else twice)."""
    import a3c_runtime as runtime
    from conftest import evaluation_steps, shared_for, tiny_args

    module = load_script("a3c_ff")
    args = tiny_args(module, total_timesteps=300, eval_interval=10**8, eval_episodes=1)
    shared = shared_for(module, args)
    shared.base_step[0] = 200
    pending = runtime.snapshots.copy_of(shared.model.state_dict())
    first = next(iter(pending))
    pending[first] = pending[first] + 1.0  # a network other than the checkpoint's own
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    snapshot = {"pending_evaluations": [(100, pending)]}
    runtime.save_checkpoint(path, shared, args, 1.0, script="a3c_ff.py", snapshot=snapshot)
    if logged:
        (path.parent / "evaluations.csv").write_text(
            "global_step,wall_time_s,mean_return,std_return,episodes\n100,1.0,0.0,0.0,1\n"
        )
    seen = tmp_path / "evaluated.txt"
    evaluate = runtime.evaluation.evaluate_network

    def recorded(model, envs, step, *rest, **kwargs):
        weight = float(model.state_dict()[first].sum())
        with open(seen, "a") as f:
            f.write(f"{step} {weight!r}\n")
        return evaluate(model, envs, step, *rest, **kwargs)

    # (patched before the evaluator is forked: the evaluator's)
    monkeypatch.setattr(runtime.evaluation, "evaluate_network", recorded)
    code, err = main_exit(module, ["--resume", str(path)], monkeypatch, capsys)
    assert code == 0, err
    steps = evaluation_steps(path.parent)
    assert steps[0] == 100 and len(steps) == 2 and steps[1] >= 300, steps
    if logged:
        assert not seen.exists()  # the evaluator had nothing to take
    else:
        step, weight = seen.read_text().split("\n")[0].split()
        assert int(step) == 100 and float(weight) == float(pending[first].sum())


def test_a_run_evaluates_at_each_mark_and_once_at_its_end_and_resumed_changes_nothing(
    tmp_path, monkeypatch, capsys
):
    """One worker on Catch (an update every 15 steps here), T_max 90, an evaluation every 30
    steps: step 0, the marks 30 and 60, and the final evaluation at T_max, once (the mark that
    T_max itself reaches is the final one, not an evaluation of its own). Resumed, the run that
    ended exactly at T_max is finished: it says so and writes nothing."""
    from conftest import evaluation_steps

    module = load_script("a3c_ff")
    run_dir = tmp_path / "run"
    flags = ["--num-workers", "1", "--total-timesteps", "90", "--eval-interval", "30",
             "--eval-episodes", "1", "--log-interval", "60", "--run-dir", str(run_dir)]  # fmt: skip
    code, err = main_exit(module, flags, monkeypatch, capsys)
    assert code == 0, err
    assert evaluation_steps(run_dir) == [0, 30, 60, 90]
    files = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
    argv = ["--resume", str(run_dir / "checkpoint.pt")]
    code, _ = main_exit(module, argv, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0 and out.startswith("run run is finished: step 90"), out
    assert {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()} == files
