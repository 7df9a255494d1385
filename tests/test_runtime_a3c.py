"""a3c_runtime.a3c end to end: agents/a3c_ff.py run as a subprocess on tiny budgets with 2
workers, the run machinery as a user meets it (resume, signals, a killed worker, --evaluate,
bad flags); the in-process tests of each module are the other tests/test_runtime_*.py."""

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import (
    AGENTS,
    ROOT,
    TINY,
    load_script,
    main_exit,
    read_checkpoint,
    read_evaluations,
    run_script,
)

pytestmark = pytest.mark.slow
SCRIPT = AGENTS / "a3c_ff.py"


def run(*flags: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return run_script("a3c_ff", *flags, timeout=timeout)


def start(*flags: str) -> tuple[subprocess.Popen, dict[str, int]]:
    """Start a long run in its own process group; return it and its processes' pids."""
    process = subprocess.Popen(
        [sys.executable, str(SCRIPT), *flags],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        start_new_session=True,
    )
    for line in process.stdout:
        if line.startswith("pids: "):
            pids = {m[0]: int(m[1]) for m in re.findall(r"(\w+ ?\d*) (\d+)", line[6:])}
            return process, pids
    raise AssertionError(f"no pids line; stderr: {process.stderr.read()}")


def wait_for_progress(process: subprocess.Popen) -> None:
    """Wait for the first progress line, so that every worker has started learning."""
    for line in process.stdout:
        if line.startswith("step "):
            return
    raise AssertionError(f"no progress line; stderr: {process.stderr.read()}")


def assert_all_gone(pids: dict[str, int]) -> None:
    deadline = time.time() + 10
    for name, pid in pids.items():
        while os.path.exists(f"/proc/{pid}") and time.time() < deadline:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(") ")[1].startswith("Z"):  # zombie: exited, not yet reaped
                    break
            time.sleep(0.05)
        else:
            assert not os.path.exists(f"/proc/{pid}"), f"{name} (pid {pid}) still runs"


@pytest.fixture(scope="module")
def short_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    run_dir = tmp_path_factory.mktemp("a3c") / "run"
    flags = ["--total-timesteps", "3000", "--eval-interval", "1000", "--run-dir", str(run_dir)]
    result = run(*TINY, *flags, "--checkpoint-interval", "1000")
    return run_dir, result


def test_short_run_writes_evaluations_events_and_checkpoint(short_run):
    run_dir, result = short_run
    assert result.returncode == 0, result.stderr
    rows = read_evaluations(run_dir)
    assert list(rows[0]) == ["global_step", "wall_time_s", "mean_return", "std_return", "episodes"]
    steps = [int(r["global_step"]) for r in rows]
    assert steps[0] == 0 and steps[-1] >= 3000 and steps == sorted(steps)
    assert len(rows) >= 3  # step 0, about 1000, 2000 and the final one
    assert all(0.0 <= float(r["mean_return"]) <= 1.0 and r["episodes"] == "5" for r in rows)
    assert list(run_dir.glob("events.out.tfevents.*"))
    checkpoint = read_checkpoint(run_dir / "checkpoint.pt")
    assert checkpoint["global_step"] == steps[-1]
    summary = result.stdout.strip().splitlines()[-1]
    assert summary.startswith("done: final eval") and "SPS" in summary, result.stdout
    # the wall time counts the final evaluation, and the time spent evaluating is reported
    minutes, seconds = map(int, re.search(r"wall time (\d+)m(\d+)s \(evaluations \d+m\d+s\)",
                                          summary).groups())  # fmt: skip
    assert 60 * minutes + seconds >= int(float(rows[-1]["wall_time_s"])), summary
    assert re.search(r"step [\d,]+/3,000 .*\| SPS [\d,]+ \| return .* \| ETA", result.stdout)


def test_tensorboard_scalars(short_run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    run_dir, _ = short_run
    events = EventAccumulator(str(run_dir))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    expected = {"charts/SPS", "charts/episodic_return", "eval/mean_return", "losses/policy_loss",
                "losses/value_loss", "losses/entropy", "losses/grad_norm"}  # fmt: skip
    assert expected <= tags, tags


def test_resume_continues_global_step(short_run, tmp_path):
    run_dir, _ = short_run
    old = read_checkpoint(run_dir / "checkpoint.pt")
    before = old["global_step"]
    copy = tmp_path / "checkpoint.pt"
    copy.write_bytes((run_dir / "checkpoint.pt").read_bytes())
    old_rows = read_evaluations(run_dir)
    (tmp_path / "evaluations.csv").write_bytes((run_dir / "evaluations.csv").read_bytes())
    # an evaluation interval past the end: the resumed run's only new evaluation is the final
    # one, so every progress line shows the first run's last evaluation (with 1,000, one at about
    # step 4,000 could come before the first progress line)
    result = run(*TINY, "--resume", str(copy), "--total-timesteps", "5000",
                 "--eval-interval", "1000000")  # fmt: skip
    assert result.returncode == 0, result.stderr
    # the continued run is named, and its progress shows its last evaluation until the next
    lines = result.stdout.splitlines()
    # the flags given with --resume that change how long it runs and evaluates, announced
    assert lines[:2] == ["eval_interval 1,000 -> 1,000,000", "total_timesteps 3,000 -> 5,000"]
    assert lines[2].startswith(f"resuming run {tmp_path.name} at step {before:,}"), lines[2]
    progress = [line for line in lines if line.startswith("step ")]
    assert progress, result.stdout
    last = old_rows[-1]
    assert f"eval {float(last['mean_return']):.3f} @ {int(last['global_step']):,}" in progress[0]
    # the checkpoint's folder is the default run folder: its evaluations.csv goes on
    rows = read_evaluations(tmp_path)[len(old_rows) :]
    steps = [int(r["global_step"]) for r in rows]
    assert len(steps) == 1 and steps[0] >= 5000, "a resumed run must not start again at step 0"
    after = read_checkpoint(copy)
    assert after["global_step"] == steps[-1]
    # wall time continues too: the evaluations' wall_time_s count from the first run's start
    assert after["wall_time"] > old["wall_time"]
    assert after["wall_time"] <= float(rows[-1]["wall_time_s"])  # saved before the final eval
    # the closing line gives the run's whole wall time, and this part's beside it
    total, part = re.search(r"wall time (\S+) \(this part (\S+), its evaluations \S+\)",
                            lines[-1]).groups()  # fmt: skip
    seconds = lambda text: 60 * int(text.split("m")[0]) + int(text.split("m")[1][:-1])  # noqa: E731
    assert seconds(total) >= int(old["wall_time"]) + seconds(part) - 1, lines[-1]


@pytest.mark.parametrize(
    ("signum", "group"),
    [(signal.SIGINT, True), (signal.SIGTERM, False), (signal.SIGTERM, True)],
    ids=["SIGINT to the group", "SIGTERM", "SIGTERM to the group"],
)
def test_signal_writes_checkpoint_and_exits_zero(tmp_path, signum, group):
    process, pids = start(*TINY, "--total-timesteps", "10000000", "--run-dir", str(tmp_path))
    wait_for_progress(process)
    # SIGINT as a terminal sends it (to the whole group); SIGTERM as `kill` does, or to the
    # whole group as a batch system or `docker stop` do (the workers then end early, too)
    if group:
        os.killpg(process.pid, signum)
    else:
        process.send_signal(signum)
    stdout, stderr = process.communicate(timeout=30)
    assert process.returncode == 0, stderr
    assert f"stopped by {signal.Signals(signum).name}" in stdout
    checkpoint = read_checkpoint(tmp_path / "checkpoint.pt")
    assert checkpoint["global_step"] > 0
    assert_all_gone(pids)


def test_killed_worker_stops_the_run_with_an_error(tmp_path):
    process, pids = start(*TINY, "--total-timesteps", "10000000", "--run-dir", str(tmp_path))
    wait_for_progress(process)
    os.kill(pids["worker 1"], signal.SIGKILL)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 1
    assert f"worker 1 (pid {pids['worker 1']}) was killed by SIGKILL" in stderr
    assert_all_gone(pids)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--grad-clip-mode", "sideways"], "norm"),  # tyro's: a value outside a Literal
        (["--t-max", "0"], "error: --t-max must be >= 1 (got 0)\n"),  # ours: one line
    ],
)
def test_the_command_exits_2_on_a_bad_flag(flags, message):
    """The entry point's exit code and message, once per kind of error (every flag check is
    tested in process in test_runtime_flags.py)."""
    result = run(*flags, timeout=60)
    assert result.returncode == 2 and result.stdout == ""
    assert message in result.stderr if message == "norm" else result.stderr == message


def test_corrupt_checkpoint_is_rejected(tmp_path, monkeypatch, capsys):
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(b"\x00garbage")
    code, err = main_exit(load_script("a3c_ff"), ["--resume", str(path)], monkeypatch, capsys)
    assert code == 2 and "corrupt" in err and err.count("\n") == 1


@pytest.mark.parametrize("policy", [[], ["--eval-greedy"]])
def test_evaluate_mode_prints_scores(short_run, policy, monkeypatch, capsys):
    run_dir, _ = short_run
    argv = ["--evaluate", str(run_dir / "checkpoint.pt"), "--eval-episodes", "3", *policy]
    code, err = main_exit(load_script("a3c_ff"), argv, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0, err
    assert len(re.findall(r"^episode \d: score [01]$", out, re.M)) == 3
    assert re.search(r"mean score [\d.]+ \+- [\d.]+ over 3 episodes", out)


def test_capture_video(tmp_path):
    pytest.importorskip("moviepy")
    flags = ["--total-timesteps", "500", "--eval-interval", "1000", "--capture-video"]
    result = run(*TINY, *flags, "--run-dir", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert len(list((tmp_path / "videos").glob("*.mp4"))) >= 2  # step 0 and the final one


def resume_line(text: str) -> re.Match:
    """The closing line of a run that ended before T_max."""
    last = text.strip().splitlines()[-1]
    match = re.fullmatch(
        r"checkpoint (\S+) \(step ([\d,]+)\) survives; resume: python (\S+) --resume (\S+)", last
    )
    assert match, last
    return match


def test_a_stopped_run_names_its_checkpoint_and_the_resume_command(tmp_path):
    process, pids = start(*TINY, "--total-timesteps", "10000000", "--run-dir", str(tmp_path))
    wait_for_progress(process)
    process.send_signal(signal.SIGTERM)
    stdout, _ = process.communicate(timeout=30)
    match = resume_line(stdout)
    step = read_checkpoint(tmp_path / "checkpoint.pt")["global_step"]
    assert int(match[2].replace(",", "")) == step
    assert Path(ROOT, match[1]).resolve() == (tmp_path / "checkpoint.pt").resolve()


def test_a_killed_worker_names_the_surviving_checkpoint(tmp_path):
    process, pids = start(*TINY, "--total-timesteps", "10000000", "--checkpoint-interval",
                          "2000", "--run-dir", str(tmp_path))  # fmt: skip
    while not (tmp_path / "checkpoint.pt").exists():
        time.sleep(0.1)
    os.kill(pids["worker 0"], signal.SIGKILL)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 1
    match = resume_line(stderr)
    assert int(match[2].replace(",", "")) >= 2000
    assert_all_gone(pids)


def test_resume_of_a_run_still_training_is_refused_naming_its_pid(tmp_path):
    process, pids = start(*TINY, "--total-timesteps", "10000000", "--checkpoint-interval",
                          "1000", "--run-dir", str(tmp_path))  # fmt: skip
    while not (tmp_path / "checkpoint.pt").exists():
        time.sleep(0.1)
    second = run("--resume", str(tmp_path / "checkpoint.pt"))
    process.send_signal(signal.SIGTERM)
    process.communicate(timeout=30)
    assert second.returncode == 2
    assert f"is in use by process {process.pid} " in second.stderr
    assert second.stderr.count("\n") == 1, second.stderr


def test_resume_keeps_the_runs_flags(tmp_path, monkeypatch, capsys):
    a3c = load_script("a3c_ff")
    argv = [*TINY, "--total-timesteps", "1000", "--learning-rate", "3e-4", "--t-max", "5",
            "--eval-interval", "500", "--run-dir", str(tmp_path)]  # fmt: skip
    code, err = main_exit(a3c, argv, monkeypatch, capsys)
    assert code == 0, err
    checkpoint = str(tmp_path / "checkpoint.pt")
    argv = ["--resume", checkpoint, "--total-timesteps", "2000", "--num-workers", "2"]
    code, err = main_exit(a3c, argv, monkeypatch, capsys, keep_out=True)
    assert code == 0, err
    assert "total_timesteps 1,000 -> 2,000" in capsys.readouterr().out
    args = read_checkpoint(checkpoint)["args"]
    assert (args["learning_rate"], args["t_max"], args["total_timesteps"]) == (3e-4, 5, 2000)
    code, err = main_exit(
        a3c, ["--resume", checkpoint, "--learning-rate", "0.5"], monkeypatch, capsys
    )
    assert code == 2
    assert err.startswith("error: --learning-rate 0.5 differs from the run's 0.0003")


def _mount_tmpfs(path: Path, size: int) -> bool:
    path.mkdir()
    result = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                            capture_output=True)  # fmt: skip
    return result.returncode == 0


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a small tmpfs needs root")
def test_a_full_disk_ends_the_run_cleanly_keeping_the_last_checkpoint(tmp_path):
    """A real full disk: a tmpfs with room for one checkpoint and the logs, not for two."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, 16 << 20):  # an A3C FF checkpoint is 10.6 MB
        pytest.skip("mount -t tmpfs is not permitted here")
    try:
        process, pids = start(*TINY, "--total-timesteps", "10000000", "--checkpoint-interval",
                              "1000", "--runs-root", str(disk))  # fmt: skip
        _, stderr = process.communicate(timeout=120)
        (run_dir,) = disk.iterdir()
        assert process.returncode == 1
        lines = stderr.strip().splitlines()
        assert (
            lines[-2] == f"error: could not write {run_dir}/checkpoint.pt: No space left on device"
        )
        match = resume_line(stderr)
        step = read_checkpoint(run_dir / "checkpoint.pt")["global_step"]
        assert step >= 1000 and int(match[2].replace(",", "")) == step
        assert not list(run_dir.glob("*.tmp"))
        assert_all_gone(pids)
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a small tmpfs needs root")
def test_a_failed_tensorboard_write_ends_the_run_in_one_line(tmp_path):
    """A real full disk that the TensorBoard events fill first: a 16 KB tmpfs, no checkpoint
    before the end, progress scalars every 0.1 s."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, 16 << 10):
        pytest.skip("mount -t tmpfs is not permitted here")
    try:
        flags = [*TINY, "--total-timesteps", "10000000", "--log-interval", "0.1",
                 "--checkpoint-interval", "1000000000", "--eval-interval", "1000000000",
                 "--run-dir", str(disk / "run")]  # fmt: skip
        process, pids = start(*flags)
        _, stderr = process.communicate(timeout=180)
        assert process.returncode == 1
        (events,) = (disk / "run").glob("events.out.tfevents.*")
        assert stderr.strip().splitlines() == [
            f"error: could not write {events}: No space left on device",
            # the command names the folder: the fresh attempt must not mix with this one
            f"no checkpoint was written in {disk / 'run'}; start the run again: rm -r -- "
            f"{disk / 'run'} && python {SCRIPT} " + " ".join(flags),
        ], stderr
        assert_all_gone(pids)
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _limit_file_size() -> None:
    import resource

    limit = 4 << 20  # below the FC layer's 5.3 MB: torch's shared-memory files hit it
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # Python ignores SIGXFSZ


def test_no_room_for_the_shared_network_is_one_line_and_creates_nothing(tmp_path):
    """A real failure: a file size limit (ulimit -f) below the network's largest tensor, which
    torch puts in a shared-memory file before any run folder exists."""
    run_dir = tmp_path / "run"
    result = subprocess.run(
        [sys.executable, str(AGENTS / "a3c_ff.py"), *TINY, "--run-dir", str(run_dir)],
        capture_output=True, text=True, timeout=120, cwd=ROOT, preexec_fn=_limit_file_size,
    )  # fmt: skip
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("error: cannot put the network and its optimizer statistics (10.")
    assert line.endswith("free space in /dev/shm or raise the file size limit (ulimit -f)")
    assert not run_dir.exists()


# a progress line every 0.2 s: the SIGKILL case waits for the first, and on an idle machine the
# whole run takes a few seconds (the default 5 s interval printed none before it ended)
EXACT = ["--num-workers", "1", "--total-timesteps", "6000", "--eval-interval", "1000",
         "--checkpoint-interval", "500", "--eval-episodes", "5",
         "--envs-per-worker", "4", "--log-interval", "0.2"]  # fmt: skip


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    """One worker, Catch: the run the interrupted ones must end as."""
    run_dir = tmp_path_factory.mktemp("exact") / "run"
    result = run(*EXACT, "--run-dir", str(run_dir))
    assert result.returncode == 0, result.stderr
    return run_dir


def evaluations_of(run_dir: Path) -> list[tuple[str, str, str]]:
    """(step, mean, std) of each evaluation: what must repeat (not its wall time)."""
    return [
        (r["global_step"], r["mean_return"], r["std_return"]) for r in read_evaluations(run_dir)
    ]


@pytest.mark.parametrize("fault", ["SIGINT", "SIGTERM", "SIGKILL of the main process"])
def test_an_interrupted_run_resumed_is_the_run_not_interrupted(uninterrupted, tmp_path, fault):
    """With one worker, a run stopped after a checkpoint (a signal, or its main process killed)
    and resumed ends with the same weights, bit for bit, and the same evaluations (steps and
    scores) as the run that went on: every evaluation and checkpoint is taken at its step, and
    the checkpoint holds the worker's generator, envs and frames (a3c_runtime.snapshots).
    The main process is killed with its evaluator stopped (SIGSTOP), the evaluations it was
    handed piling up in its pipe: continued, the evaluator ends with the rest of the run. A
    finished run resumed again changes nothing."""
    run_dir = tmp_path / "run"
    process, pids = start(*EXACT, "--run-dir", str(run_dir))
    killed = "SIGKILL" in fault
    if killed:  # (once it runs: every process is set up by then)
        wait_for_progress(process)
        os.kill(pids["evaluator"], signal.SIGSTOP)
    while not (run_dir / "checkpoint.pt").exists():
        time.sleep(0.05)
    time.sleep(0.5)  # somewhere after the first checkpoint, between marks
    os.kill(process.pid, signal.SIGKILL if killed else getattr(signal, fault))
    process.communicate(timeout=30)
    if killed:
        os.kill(pids["evaluator"], signal.SIGCONT)
    assert_all_gone(pids)
    step = read_checkpoint(run_dir / "checkpoint.pt")["global_step"]
    assert 0 < step < 6000, step
    resumed = run("--resume", str(run_dir / "checkpoint.pt"))
    assert resumed.returncode == 0, resumed.stderr
    assert f"resuming run run at step {step:,}" in resumed.stdout
    assert evaluations_of(run_dir) == evaluations_of(uninterrupted)
    ours = read_checkpoint(run_dir / "checkpoint.pt")
    theirs = read_checkpoint(uninterrupted / "checkpoint.pt")
    assert ours["global_step"] == theirs["global_step"] == 6000
    for key, value in theirs["model"].items():
        assert torch.equal(ours["model"][key], value), key
    for ours_stat, theirs_stat in zip(
        ours["optimizer"]["square_avg"], theirs["optimizer"]["square_avg"], strict=True
    ):
        assert torch.equal(ours_stat, theirs_stat)
    if fault == "SIGTERM":  # finished: resumed again, it says so and changes nothing
        files = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
        again = run("--resume", str(run_dir / "checkpoint.pt"))
        assert again.returncode == 0 and again.stderr == "", again.stderr
        assert again.stdout.startswith("run run is finished: step 6,000"), again.stdout
        assert len(again.stdout.strip().splitlines()) == 1, again.stdout
        assert {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()} == files


def start_with_the_evaluator_behind(
    run_dir: Path, total_timesteps: int
) -> tuple[subprocess.Popen, dict[str, int], list[str]]:
    """A run (an evaluation every 500 steps) whose evaluator is held still (SIGSTOP) once the
    workers learn, until the console says it is behind; the run, its pids and the lines seen."""
    flags = ["--num-workers", "2", "--envs-per-worker", "4", "--total-timesteps",
             str(total_timesteps), "--eval-interval", "500", "--eval-episodes", "2",
             "--log-interval", "1", "--run-dir", str(run_dir)]  # fmt: skip
    process, pids = start(*flags)
    wait_for_progress(process)
    os.kill(pids["evaluator"], signal.SIGSTOP)
    seen = []  # held until the note comes (past LATE = 2 waiting), however slow the workers
    for line in process.stdout:
        seen.append(line)
        if re.match(r"note: the evaluator is \d+ evaluations behind the training", line):
            break
    return process, pids, seen


def test_a_stalled_evaluator_skips_nothing_and_is_announced(tmp_path):
    """The evaluator held still (SIGSTOP) while the workers train: the copies of theta taken at
    the marks wait for it, the console says it is behind, and every evaluation is taken, in
    order, at its step."""
    run_dir = tmp_path / "run"
    process, pids, seen = start_with_the_evaluator_behind(run_dir, 12000)
    os.kill(pids["evaluator"], signal.SIGCONT)
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 0, stderr
    assert seen and seen[-1].startswith("note: the evaluator is"), "".join(seen) + stdout
    steps = [int(row["global_step"]) for row in read_evaluations(run_dir)]
    marks = list(range(0, 12000, 500))
    assert len(steps) == len(marks) + 1 and steps == sorted(steps), steps
    assert all(mark <= step < mark + 500 for mark, step in zip(marks, steps, strict=False))
    assert steps[-1] >= 12000


def test_a_run_stopped_while_its_evaluator_is_behind_exits_keeping_what_it_waits_for(tmp_path):
    """SIGTERM while the evaluator is held still (SIGSTOP) with the copies of theta taken at
    the marks waiting for it: the run ends (the requests it never read do not hold the main
    process at its exit) and its checkpoint keeps them, to be taken when it is resumed."""
    process, pids, _ = start_with_the_evaluator_behind(tmp_path, 10_000_000)
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 0, stderr
    assert "stopped by SIGTERM" in stdout and "survives; resume:" in stdout, stdout
    checkpoint = read_checkpoint(tmp_path / "checkpoint.pt")
    logged = {int(row["global_step"]) for row in read_evaluations(tmp_path)}
    waiting = [step for step, _ in checkpoint["pending_evaluations"]]
    assert waiting and not logged & set(waiting), (waiting, logged)
    assert_all_gone(pids)
