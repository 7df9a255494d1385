"""The benchmark scripts run and report what they promise. Their numbers are not checked here:
speed is measured by running the scripts themselves, never by timed tests. In process: each
script's main() with its command line."""

import importlib.util
import os
import re
import sys
from pathlib import Path

import a3c_runtime as runtime
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


def benchmark(name: str):
    """benchmarks/<name>.py as a module (once per session)."""
    key = f"benchmark_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, ROOT / "benchmarks" / f"{name}.py")
        sys.modules[key] = module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    return sys.modules[key]


class Result:
    def __init__(self, returncode: int, stdout: str, stderr: str):
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def run(script: str, *args: str, monkeypatch, capsys) -> Result:
    """`python benchmarks/<script> *args` from the repository root, in process."""
    name = Path(script).stem
    module = benchmark(name)
    monkeypatch.chdir(ROOT)
    monkeypatch.setattr(sys, "argv", [script, *args])
    threads = torch.get_num_threads()
    try:
        code = module.main() or 0
    except SystemExit as e:  # argparse's errors, or SystemExit("message")
        code = e.code
        if isinstance(code, str):
            print(code, file=sys.stderr)
            code = 1
    finally:  # a profile sets up this process as a worker: one thread, denormals flushed
        torch.set_num_threads(threads)
        torch.set_flush_denormal(False)
    out, err = capsys.readouterr()
    return Result(code, out, err)


def test_checkpoint_gate_times_the_loads_of_a_checkpoint_with_every_part(monkeypatch, capsys):
    result = run("checkpoint_gate.py", "--loads", "2", monkeypatch=monkeypatch, capsys=capsys)
    assert result.returncode == 0, result.stderr
    line = r"checkpoint gate: [\d.]+ ms a load of [\d.]+ MB \(2 loads\)\n"
    assert re.fullmatch(line, result.stdout), result.stdout


def test_env_throughput_reports_every_configuration(monkeypatch, capsys):
    result = run(
        "env_throughput.py",
        "--seconds",
        "0.05",
        "--repeats",
        "1",
        monkeypatch=monkeypatch,
        capsys=capsys,
    )
    assert result.returncode == 0, result.stderr
    assert "gym.make(Catch-v0)" in result.stdout
    for n in (1, 64, 1024):
        assert re.search(rf"N={n} grid copy=False +[\d,]+ +[\d,]+", result.stdout)


@pytest.mark.slow
def test_a3c_throughput_compares_a_variant_with_a3c_ff_at_every_setting(monkeypatch, capsys):
    result = run(
        "a3c_throughput.py", "agents/a3c_lstm.py", "--seconds", "1", "--no-baseline",
        "--eval-episodes", "1", "--envs-per-worker", "1", "2", "--precision", "bf16",
        "--replay", "on", "off",
        monkeypatch=monkeypatch, capsys=capsys,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = re.findall(
        r"^(a3c_\w+) +(\d+) +(\w+) +(on|off) +- +([\d,]+) +[\d,]+ +\d+% ", result.stdout, re.M
    )
    assert {row[:4] for row in rows} == {
        (name, k, "bf16", replay)
        for name in ("a3c_ff", "a3c_lstm")
        for k in ("1", "2")
        for replay in ("on", "off")
    }
    # a 1-s window on a slow or busy CPU can end before the first update: the benchmark then
    # says so (its ratios are nan) rather than reporting a rate; a zero without that note fails
    steps = [int(row[4].replace(",", "")) for row in rows]
    assert all(steps) or "saw no step in its window" in result.stdout
    assert re.search(r"a3c_lstm: [\d.]+ MFLOP per env step", result.stdout)


@pytest.mark.slow
def test_a3c_throughput_compares_the_atari_backends_with_the_two_ceilings(monkeypatch, capsys):
    pytest.importorskip("ale_py")
    # 2 s per measurement: a start-up slowed by the tests beside it can take all of 1 s
    result = run(
        "a3c_throughput.py", "--env", "BreakoutNoFrameskip-v4", "--seconds", "2",
        "--no-baseline", "--envs-per-worker", "2", "1", "--precision", "bf16", "--eval-episodes",
        "1", "--env-backend", "native", "python", "--env-threads", "1", "2", "--ceilings",
        monkeypatch=monkeypatch, capsys=capsys,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    for k in (2, 1):
        rows = re.findall(rf"^a3c_ff +{k} +bf16 +script +(\S+) +([\d,]+) ", result.stdout, re.M)
        assert [row[0] for row in rows] == ["native/1", "native/2", "python"]
    assert re.search(r"'python', 1\): [\d.]+x$", result.stdout, re.M)  # against native/1
    # one bound per K, its network ceiling measured at that K, each setting against its own
    block = (r"emulator ([\d,]+) steps/s .* network ([\d,]+) \(a3c_ff on Catch-v0, K=(\d+) "
             r".* = ([\d,]+) steps/s\n((?:  a3c_ff .*\n)+)")  # fmt: skip
    blocks = re.findall(block, result.stdout)
    assert [block[2] for block in blocks] == ["2", "1"]
    for emulator, network, k, bound, lines in blocks:
        emulator, network, bound = (int(x.replace(",", "")) for x in (emulator, network, bound))
        assert abs(bound - 1 / (1 / emulator + 1 / network)) <= 2  # (printed rounded)
        assert re.findall(r"a3c_ff \((\d+), ", lines) == [k] * 3
        assert len(re.findall(r"% of that bound", lines)) == 3


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["agents/no_such_script.py"], "no such script"),
        (["README.md"], "is not an A3C agent script"),
        (["--seconds", "0"], "--seconds must be > 0"),
        (["--envs-per-worker", "0"], "--envs-per-worker must be >= 1"),
        (["--env", "NoSuchEnv-v0"], "unknown --env"),
        (["--env-threads", "0"], "--env-threads must be >= 1"),
        (["--ceilings"], "--ceilings needs an ALE game"),
    ],
)
def test_a3c_throughput_rejects_bad_input(args, message, monkeypatch, capsys):
    result = run("a3c_throughput.py", *args, monkeypatch=monkeypatch, capsys=capsys)
    assert result.returncode != 0
    assert message in result.stderr


def test_a3c_step_profile_reports_every_phase(monkeypatch, capsys):
    result = run("a3c_step_profile.py", "--seconds", "1", monkeypatch=monkeypatch, capsys=capsys)
    assert result.returncode == 0, result.stderr
    shares = re.findall(r"^[a-z ]+ +[\d.]+ us/step +([\d.]+)%$", result.stdout, re.M)
    assert len(shares) == 7
    assert abs(sum(map(float, shares)) - 100) < 0.5

    def number(pattern: str) -> float:
        return float(re.search(pattern, result.stdout)[1].replace(",", ""))

    measured = number(r"([\d,]+) steps/s in one process")
    # the network's phases are only part of a step: the ceiling lies above the measured speed
    assert number(r"at most ([\d,]+) steps/s") > measured


def test_a3c_step_profile_whose_window_ends_before_a_step_measures_up_to_one(monkeypatch, capsys):
    """A window shorter than building the envs and the first update (a loaded host) once gave
    0 steps and a division by zero: the window opens when the loop starts and the loop goes on
    to its first update."""
    result = run(
        "a3c_step_profile.py", "--seconds", "0.001", monkeypatch=monkeypatch, capsys=capsys
    )
    assert result.returncode == 0, result.stderr
    steps = int(re.search(r": ([\d,]+) env steps", result.stdout)[1].replace(",", ""))
    assert steps >= 20  # one update of --t-max 20
    assert len(re.findall(r"^[a-z ]+ +[\d.]+ us/step", result.stdout, re.M)) == 7


@pytest.mark.slow
def test_fault_injection_resumes_runs_without_losing_a_checkpoint(monkeypatch, capsys):
    # one trial, the hardest fault: each fault's own run is tested in test_runtime_a3c.py
    result = run(
        "fault_injection.py", "--trials", "1", "--total-timesteps", "20000",
        "--faults", "SIGKILL main", monkeypatch=monkeypatch, capsys=capsys,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    assert (
        "faults survived 1/1; checkpoints lost or unloadable 0; partial files 0; orphan "
        "processes 0" in result.stdout
    )


def test_the_fault_injection_knows_every_closing_hint(tmp_path, monkeypatch):
    """Its pattern matches each line a run that ended early can close with: a checkpoint that
    survives, none written (the command naming its folder or not), one that does not verify."""
    from a3c_runtime.a3c import resume_hint
    from conftest import load_script, shared_for, tiny_args

    pattern = benchmark("fault_injection").HINT
    module = load_script("a3c_ff")
    agent = module.AGENT
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    hints = []
    for argv in (["a3c_ff.py", "--seed", "2"], ["a3c_ff.py", "--run-dir", str(run_dir)]):
        monkeypatch.setattr(sys, "argv", argv)
        hints.append(resume_hint(agent, run_dir))  # no checkpoint
    args = tiny_args(module)
    runtime.save_checkpoint(run_dir / "checkpoint.pt", shared_for(module, args), args, 1.0,
                            "a3c_ff.py")  # fmt: skip
    hints.append(resume_hint(agent, run_dir))  # one that survives
    data = (run_dir / "checkpoint.pt").read_bytes()
    (run_dir / "checkpoint.pt").write_bytes(data[:100] + bytes([data[100] ^ 1]) + data[101:])
    hints.append(resume_hint(agent, run_dir))  # one that does not verify
    assert "rm -r -- " in hints[1] and "survives" in hints[2] and "not verify" in hints[3]
    for hint in hints:
        assert re.match(pattern, hint), hint


def test_batched_throughput_reports_each_batch(monkeypatch, capsys):
    """A batch of 2 runs for half a second (CPU), each convolution form, no process backend."""
    result = run(
        "batched_throughput.py",
        *("--runs", "2", "--seconds", "0.5", "--process-runs", "0"),
        *("--conv-form", "grouped", "matmul"),
        monkeypatch=monkeypatch,
        capsys=capsys,
    )
    assert result.returncode == 0, result.stderr
    assert "process backend" not in result.stdout
    for form in ("grouped", "matmul"):
        assert re.search(rf"batched N=2 \({form} convolutions\): [\d,]+ run-steps/s, [\d.]+ ms an "
                         r"update; one evaluation \(N x 50 episodes\) [\d.]+ s; .* thesis-scale "
                         r"line .* [\d.]+ min", result.stdout)  # fmt: skip


@pytest.mark.slow
def test_batched_throughput_reports_each_batch_against_the_process_backend(monkeypatch, capsys):
    """One process-backend run of a few seconds, and a batch of 2 runs for 1 s (CPU)."""
    result = run(
        "batched_throughput.py",
        *("--runs", "2", "--seconds", "1", "--process-runs", "1", "--process-seconds", "8"),
        monkeypatch=monkeypatch,
        capsys=capsys,
    )
    assert result.returncode == 0, result.stderr
    assert re.search(r"process backend: 1 one-worker runs side by side: [\d,]+ run-steps/s",
                     result.stdout)  # fmt: skip
    assert re.search(r"batched N=2 \(grouped convolutions\): [\d,]+ run-steps/s = [\d.]+x the "
                     r"process backend",
                     result.stdout)  # fmt: skip


def test_batched_profile_times_and_profiles_a_batch(monkeypatch, capsys):
    """A batch of 2 runs of A3C FF (CPU): its lockstep rate, then the profiler's table."""
    result = run(
        "batched_profile.py",
        *("--runs", "2", "--updates", "1"),
        monkeypatch=monkeypatch,
        capsys=capsys,
    )
    assert result.returncode == 0, result.stderr
    assert re.search(r"N=2: built in [\d.]+ s; [\d,]+ steps/s \(lockstep\), [\d,]+ run-steps/s, "
                     r"[\d.]+ ms an update of [\d.]+ steps", result.stdout)  # fmt: skip
    assert "Self CPU time total" in result.stdout


@pytest.mark.parametrize("script", ["batched_throughput.py", "batched_profile.py"])
def test_the_batched_benchmarks_time_the_backends_own_device_settings(script, monkeypatch, capsys):
    """They set up torch as train_batched does (on a GPU: no TF32, which cuDNN's convolutions
    would otherwise use) before they build a batch."""
    module = benchmark(Path(script).stem)
    calls = []
    built = module.BatchedA3C

    def building(*args, **kwargs):
        assert calls, "a batch was built before the device was set up"
        return built(*args, **kwargs)

    monkeypatch.setattr(module, "set_up_device", calls.append)
    monkeypatch.setattr(module, "BatchedA3C", building)
    flags = {"batched_throughput.py": ("--seconds", "0.2", "--process-runs", "0"),
             "batched_profile.py": ("--updates", "1", "--no-profile")}[script]  # fmt: skip
    result = run(script, "--runs", "1", *flags, monkeypatch=monkeypatch, capsys=capsys)
    assert result.returncode == 0, result.stderr
    assert calls == ["cpu"]


def test_the_process_backends_runs_keep_the_callers_pythonpath(monkeypatch, tmp_path):
    """On the lent GPU machine the wheels it lacks are on PYTHONPATH: the runs must see them."""
    module = benchmark("batched_throughput")
    envs = []

    class Run:
        returncode = 0

        def __init__(self, command, env, **kwargs):
            envs.append(env)

        def communicate(self):
            return "| SPS 100 |", ""

    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    monkeypatch.setattr(module.subprocess, "Popen", Run)
    assert module.measure_processes(2, 1.0) == 200.0
    for env in envs:
        entries = env["PYTHONPATH"].split(os.pathsep)
        assert str(tmp_path) in entries and "" not in entries


@pytest.mark.parametrize(
    ("flags", "says"),
    [
        (["--script", "agents/a3c_nope.py"], "argument --script: invalid choice: 'a3c_nope.py'"),
        (["--runs", "0"], "--runs and --updates must be >= 1"),
        (["--runs", "1", "--", "--t-max", "x"], "do not parse: Error parsing --t-max"),
    ],
)
def test_batched_profile_refuses_bad_input_in_one_line(flags, says, monkeypatch, capsys):
    result = run("batched_profile.py", *flags, monkeypatch=monkeypatch, capsys=capsys)
    assert result.returncode == 2 and says in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


IN_GIT = (ROOT / ".git").exists()  # (not in the mutation check's copy of the tree)


@pytest.mark.skipif(not IN_GIT, reason="needs the repository's git checkout")
def test_against_commit_reports_both_trees_figures_and_their_ratio(tmp_path, monkeypatch, capsys):
    """Both trees run the command by turns (here one that prints the number of files in the
    tree's benchmarks/), and the report gives each tree's figure per round, their means and the
    ratio; the worktree is removed after."""
    command = f"{sys.executable} -c \"import os; print('files:', len(os.listdir('benchmarks')))\""
    out = tmp_path / "report.txt"
    flags = ["HEAD", "--rounds", "2", "--out", str(out)]
    flags += ["--measure", "files", r"^files: (\d+)", command]
    result = run("against_commit.py", *flags, monkeypatch=monkeypatch, capsys=capsys)
    assert result.returncode == 0, result.stderr
    files = len(os.listdir(ROOT / "benchmarks"))
    line = result.stdout.splitlines()[-1]
    assert line.startswith("files: HEAD ") and f"this tree {files}, {files} (mean {files})" in line
    assert re.search(r"ratio \d\.\d{3}$", line)
    assert out.read_text().splitlines()[-1] == line
    worktrees = os.popen(f"git -C {ROOT} worktree list").read()
    assert str(tmp_path) not in worktrees and "/base " not in worktrees


@pytest.mark.skipif(not IN_GIT, reason="needs the repository's git checkout")
def test_against_commit_names_a_command_that_prints_no_figure(monkeypatch, capsys):
    result = run("against_commit.py", "HEAD", "--rounds", "1", "--measure", "x", r"^never (\d+)",
                 "true", monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert result.returncode == 1
    assert "printed no line matching '^never (\\\\d+)'" in result.stderr


def test_against_commit_refuses_an_out_whose_folder_does_not_exist_before_any_run(
    tmp_path, monkeypatch, capsys
):
    out = tmp_path / "missing" / "report.txt"
    result = run("against_commit.py", "HEAD", "--out", str(out), "--measure", "x", r"^(\d+)",
                 "false", monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert result.returncode == 2 and f"--out {out}: its folder does not exist" in result.stderr
    assert not out.parent.exists()
