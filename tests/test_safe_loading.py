"""Nothing the project loads from a file runs code: a checkpoint carrying a pickled object whose
`__reduce__` would create a file, planted in each part a checkpoint has and sealed as the
project seals its own, is refused in one line by every entry point that reads checkpoints, and
the file is never created. Checkpoints from before safe loading are refused naming the command
that converts them; converted, they load and resume as they were."""

import importlib.util
import io
import pickle
import zipfile

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
from a3c_runtime.snapshots import restored_state, saved_state
from a3c_tools import convert_checkpoint, record_play, sweep
from conftest import (
    ROOT,
    load_script,
    main_exit,
    read_checkpoint,
    rewrite_checkpoint,
    run_main,
    shared_for,
    tiny_args,
)

import catch_env  # noqa: F401  (registers Catch-v0)
from catch_env.wrappers import make_vector_env


class Payload:
    """Unpickled, it creates the file `marker` (builtins.open, as any callable could be)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def catch_worker_state() -> tuple:
    """A one-worker Catch run's state as its worker gives it: generator, envs, next frames."""
    envs = make_vector_env("Catch-v0", 2)
    obs, _ = envs.reset(seed=3)
    for t in range(5):
        obs, *_ = envs.step(np.array([t % 3, 1]))
    return np.random.default_rng(7), envs, obs.copy()


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A real a3c_ff.py checkpoint with every part a checkpoint can have."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    shared = shared_for(module, args)
    path = tmp_path_factory.mktemp("good") / "checkpoint.pt"
    snapshot = {
        "workers": {0: saved_state(catch_worker_state())},
        "pending_evaluations": [(1000, runtime.snapshots.copy_of(shared.model.state_dict()))],
    }
    runtime.save_checkpoint(path, shared, args, 1.0, "a3c_ff.py", snapshot)
    return path


PLACES = {  # each part of a checkpoint, and a payload put there
    "args": lambda c, p: c["args"].update(exp_name=p),
    "model": lambda c, p: c["model"].update({"value.weight": p}),
    "optimizer": lambda c, p: c["optimizer"]["square_avg"].__setitem__(0, p),
    "worker state": lambda c, p: c["workers"][0].__setitem__(1, p),
    "pending evaluation": lambda c, p: c["pending_evaluations"].append((2000, p)),
    "a key of its own": lambda c, p: c.update(extra=p),
}


def planted(good, folder, place, marker):
    """A copy of the good checkpoint with the payload at place, sealed; its payload is live."""
    checkpoint = read_checkpoint(good)
    PLACES[place](checkpoint, Payload(marker))
    path = folder / "run" / "checkpoint.pt"
    path.parent.mkdir(parents=True)
    rewrite_checkpoint(path, checkpoint)
    torch.load(path, weights_only=False)  # what an unsafe loader would do: the file appears
    assert marker.exists()
    marker.unlink()
    return path


def fault_injection():
    spec = importlib.util.spec_from_file_location(
        "fault_injection", ROOT / "benchmarks" / "fault_injection.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("place", PLACES)
def test_a_payload_anywhere_in_a_checkpoint_never_runs(place, good, tmp_path, monkeypatch, capsys):
    marker = tmp_path / "pwned"
    path = planted(good, tmp_path, place, marker)
    before = path.read_bytes()
    module = load_script("a3c_ff")
    for mode in ("--resume", "--evaluate"):
        code, err = main_exit(module, [mode, str(path), "--num-workers", "1"], monkeypatch, capsys)
        assert code == 2 and err.count("\n") == 1, (mode, err)
        assert "cannot be loaded safely: it holds more than data" in err, err
    result = run_main(record_play.main, [str(path), "-o", str(tmp_path / "play.gif")])
    assert result.returncode == 2 and "cannot be loaded safely" in result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    result = run_main(convert_checkpoint.main, [str(path)])  # only v1's worker pickles unpickle
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert runtime.checkpoints.checkpoint_step(path) is None  # the closing hint's reader
    assert fault_injection().checkpoint_state(path) is None
    out = tmp_path / "sweep"  # a sweep (and compare, through it) finding it in a run's folder
    (out / "runs").mkdir(parents=True)
    path.parent.rename(out / "runs" / "run-0000")
    argv = [str(ROOT / "agents" / "a3c_ff.py"), "--out", str(out), "--runs", "1",
            "--total-timesteps", "1000", "--", "--env", "Catch-v0"]  # fmt: skip
    result = run_main(sweep.main, argv)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "is not run-0000's to resume" in result.stderr and "loaded safely" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["runs"]  # nothing written
    assert (out / "runs" / "run-0000" / "checkpoint.pt").read_bytes() == before
    assert not marker.exists()


def test_a_sweep_resumes_only_its_runs_own_checkpoint(good, tmp_path):
    """A checkpoint of another seed in a run's folder: refused, naming the seed, nothing run."""
    out = tmp_path / "sweep"
    argv = [str(ROOT / "agents" / "a3c_ff.py"), "--out", str(out), "--runs", "1",
            "--total-timesteps", "1000", "--seed", "11"]  # fmt: skip
    (out / "runs" / "run-0000").mkdir(parents=True)
    checkpoint = read_checkpoint(good)
    checkpoint["args"].update(seed=5, total_timesteps=1000)
    rewrite_checkpoint(out / "runs" / "run-0000" / "checkpoint.pt", checkpoint)
    result = run_main(sweep.main, argv)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "--seed 5, not 11" in result.stderr, result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["runs"]


def test_a_sweep_resumes_its_runs_checkpoint_made_on_a_host_of_other_precision(good, tmp_path):
    """--precision auto resolves by the CPU at K > 1 (bf16 with native bf16, fp32 without): the
    run's checkpoint from a host that resolved it otherwise is still the run's own."""
    out = tmp_path / "sweep"
    (out / "runs" / "run-0000").mkdir(parents=True)
    checkpoint = read_checkpoint(good)
    planned = runtime.flags.resolve_precision("auto", checkpoint["args"]["envs_per_worker"])
    other = "fp32" if planned != "fp32" else "bf16-learn"
    checkpoint["args"].update(seed=11, total_timesteps=1000, num_workers=1, precision=other)
    path = out / "runs" / "run-0000" / "checkpoint.pt"
    rewrite_checkpoint(path, checkpoint)
    script = str(ROOT / "agents" / "a3c_ff.py")
    config = {"samples": [], "fixed_flags": [], "total_timesteps": 1000, "seed": 11}
    run = sweep.plan_runs(config, 1)[0]
    assert sweep.foreign_checkpoint(script, run, path.parent) is None
    checkpoint["args"].update(seed=5)  # another run's, all the same
    rewrite_checkpoint(path, checkpoint)
    refused = sweep.foreign_checkpoint(script, run, path.parent)
    assert refused is not None and "--seed 5, not 11" in refused


def test_an_unsealed_safe_checkpoint_converted_keeps_its_worker_states(good, tmp_path):
    path = tmp_path / "checkpoint.pt"
    checkpoint = read_checkpoint(good)
    torch.save(checkpoint, path)  # the safe form, but no seal
    assert run_main(convert_checkpoint.main, [str(path)]).returncode == 0
    converted = runtime.checkpoints.read_checkpoint(str(path))
    assert converted["workers"].keys() == checkpoint["workers"].keys()
    for worker_id, state in checkpoint["workers"].items():
        assert repr(converted["workers"][worker_id]) == repr(state)


def v1_checkpoint(good, path, sealed: bool = False):
    """The good checkpoint as the scripts wrote it before safe loading: format v1, each
    worker's state pickled (and, before the seal, no zip comment)."""
    checkpoint = read_checkpoint(good)
    parts = catch_worker_state()
    checkpoint.update(format="a3c-checkpoint-v1",
                      workers={0: [pickle.dumps(part) for part in parts]})  # fmt: skip
    if sealed:
        rewrite_checkpoint(path, checkpoint)
    else:
        torch.save(checkpoint, path)
    return parts


@pytest.mark.parametrize("sealed", [False, True], ids=["before the seal", "sealed"])
def test_an_old_checkpoint_is_refused_naming_the_command_that_converts_it(
    sealed, good, tmp_path, monkeypatch, capsys
):
    path = tmp_path / "checkpoint.pt"
    parts = v1_checkpoint(good, path, sealed)
    before = path.read_bytes()
    code, err = main_exit(load_script("a3c_ff"), ["--resume", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    said = "was written before checkpoints were safe to load" if sealed else "carries no seal"
    assert said in err
    assert f"convert it: python -m a3c_tools.convert_checkpoint {path}" in err
    assert path.read_bytes() == before
    result = run_main(convert_checkpoint.main, [str(path)])
    assert result.returncode == 0 and result.stdout.startswith(f"converted {path}"), result.stderr
    assert zipfile.ZipFile(path).comment.startswith(runtime.checkpoints.SEAL_PREFIX)
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob("*.a3c-partial"))
    assert read_checkpoint(path)["format"] == runtime.checkpoints.CHECKPOINT_FORMAT
    checkpoint = runtime.load_checkpoint(str(path), load_script("a3c_ff").AGENT)
    for key, value in read_checkpoint(good)["model"].items():
        assert torch.equal(checkpoint.model[key], value), key
    # the worker's state, converted, goes on as the pickled one would have
    rng, envs, obs = parts
    fresh_envs = make_vector_env("Catch-v0", 2)
    fresh_envs.reset(seed=0)
    fresh = (np.random.default_rng(0), fresh_envs, np.zeros_like(obs))
    rng2, envs2, obs2 = restored_state(checkpoint.workers[0], fresh)
    assert np.array_equal(obs2, obs) and rng2.random() == rng.random()
    for t in range(30):
        actions = np.array([t % 3, (t * 7) % 3])
        for a, b in zip(envs2.step(actions)[:4], envs.step(actions)[:4], strict=True):
            assert np.array_equal(a, b)
    again = run_main(convert_checkpoint.main, [str(path)])
    assert again.returncode == 0 and "in the safe form already" in again.stdout


def test_the_committed_checkpoints_load_safely():
    # results/ holds the committed ones (runs/ folders, ignored by git, hold runs in progress);
    # found on disk rather than by git, so that a copy of the tree without .git is tested too
    paths = [p for p in sorted(ROOT.glob("results/**/*.pt")) if "runs" not in p.parts]
    assert paths, "no committed checkpoint found"
    for path in paths:
        checkpoint = runtime.checkpoints.read_checkpoint(str(path))
        assert checkpoint["format"] == runtime.checkpoints.CHECKPOINT_FORMAT, path


def test_what_a_worker_state_saves_is_data(good):
    """The safe form holds tensors, numbers, strings, lists, tuples and dicts only."""
    allowed = (torch.Tensor, int, float, str, bool, type(None))

    def data_only(value):
        if isinstance(value, dict):
            return all(data_only(k) and data_only(v) for k, v in value.items())
        if isinstance(value, (list, tuple)):
            return all(data_only(v) for v in value)
        return isinstance(value, allowed)

    assert data_only(read_checkpoint(good))
    buffer = io.BytesIO(good.read_bytes())
    assert isinstance(torch.load(buffer, weights_only=True)["workers"][0][1], dict)


# ------------------------------------------------------------------------------------------------
# The gate (a3c_runtime.checkpoints.open_checkpoint): a sealed checkpoint whose fields are wrong is
# refused in one line by every entry point, before anything is imported, created or started
# ------------------------------------------------------------------------------------------------
DEFECTS = {  # a sealed checkpoint changed as a careless or hostile writer would, and the line
    # (`evil`: the absolute path of a script that, imported, creates a file)
    "a key missing": (lambda c, evil: c.pop("args"), "is malformed: it has no 'args'"),
    "a step of another type": (lambda c, evil: c.update(global_step="1000"),
                               "is malformed: its 'global_step' is a str"),
    "a flag of another type": (lambda c, evil: c["args"].update(learning_rate="fast"),
                               "its --learning-rate 'fast' is not float"),
    "a module to import as its env": (lambda c, evil: c["args"].update(env="this:Catch-v0"),
                                      "holds the env 'this:Catch-v0': a module"),
    "an unknown env": (lambda c, evil: c["args"].update(env="Nope-v9"),
                       "an unknown env id; valid:"),
    "an env that is no game": (lambda c, evil: c["args"].update(env="CartPole-v1"),
                               "not an env of the scripts; valid:"),
    "NaN weights": (lambda c, evil: c["model"]["value.weight"].fill_(float("nan")),
                    "the network has non-finite weights"),
    "inf weights": (lambda c, evil: c["model"]["policy.bias"].fill_(float("inf")),
                    "the network has non-finite weights"),
    "one NaN among finite weights": (
        lambda c, evil: c["model"]["value.weight"].view(-1)[1:2].fill_(float("nan")),
        "the network has non-finite weights (NaN or inf in value.weight"),
    "a complex tensor": (lambda c, evil: c["model"].update(
                             {"value.weight": c["model"]["value.weight"] * (1 + 1j)}),
                         "its 'model' holds a complex-valued tensor"),
    "an absolute path as its script": (lambda c, evil: c.update(script=evil),
                                       "not an agent script"),
    "a path up as its script": (lambda c, evil: c.update(script="../" * 40 + evil[1:]),
                                "not an agent script"),
    "a path up after a3c_ff.py as its script": (
        lambda c, evil: c.update(script="a3c_ff.py/" + "../" * 40 + evil[1:]),
        "not an agent script"),
    "a million workers": (lambda c, evil: c["args"].update(num_workers=10**6),
                          "asks for --num-workers 1000000 (valid"),
    "a million evaluation episodes": (lambda c, evil: c["args"].update(eval_episodes=10**6),
                                      "asks for --eval-episodes 1000000"),
    "no workers": (lambda c, evil: c["args"].update(num_workers=0),
                   "asks for --num-workers 0 (valid"),
    "a pending evaluation of another network": (
        lambda c, evil: c["pending_evaluations"].append((2000, {"w": torch.zeros(2)})),
        "its 'pending_evaluations' are not (step, its network) pairs"),
    "a worker by name": (lambda c, evil: c["workers"].update({"w": []}),
                         "its 'workers' are not each worker's state by its number"),
}  # fmt: skip


def started(*args, **kwargs):
    raise AssertionError("a run was started")


def refusals(path, tmp_path, monkeypatch, capsys) -> dict[str, str]:
    """Each entry point's line for the checkpoint at path: --evaluate, --resume, record_play,
    convert_checkpoint, a sweep's resume and compare's, each asserted to exit 2 in one line,
    leaving the checkpoint and its folder as they were and running nothing."""
    from a3c_tools import compare

    before, listing = path.read_bytes(), sorted(path.parent.iterdir())
    module = load_script("a3c_ff")
    monkeypatch.setattr("a3c_runtime.a3c.Supervisor", started)
    monkeypatch.setattr(sweep, "execute_run", started)
    lines = {}
    for mode in ("--evaluate", "--resume"):
        code, lines[mode] = main_exit(module, [mode, str(path)], monkeypatch, capsys)
        assert code == 2 and lines[mode].count("\n") == 1, (mode, lines[mode])
    gif = tmp_path / "play.gif"
    for name, main, argv in (
        ("record_play", record_play.main, [str(path), "-o", str(gif)]),
        ("convert_checkpoint", convert_checkpoint.main, [str(path)]),
    ):
        result = run_main(main, argv)
        assert result.returncode == 2 and result.stderr.count("\n") == 1, (name, result.stderr)
        lines[name] = result.stderr
    assert not gif.exists()
    assert path.read_bytes() == before and sorted(path.parent.iterdir()) == listing
    ff = str(ROOT / "agents" / "a3c_ff.py")
    for name, main, out, argv in (
        ("sweep", sweep.main, tmp_path / "sweep",
         [ff, "--out", str(tmp_path / "sweep"), "--runs", "1", "--total-timesteps", "1000"]),
        ("compare", compare.main, tmp_path / "cmp" / "base",
         [ff, ff, "--other-flags", "--activation elu", "--runs", "3", "--steps", "500", "--cpus",
          "2", "--out", str(tmp_path / "cmp")]),
    ):  # fmt: skip
        run_dir = out / "runs" / "run-0000"
        run_dir.mkdir(parents=True)
        (run_dir / "checkpoint.pt").write_bytes(before)
        result = run_main(main, argv)
        assert result.returncode == 2 and result.stderr.count("\n") == 1, (name, result.stderr)
        assert "is not run-0000's to resume" in result.stderr, result.stderr
        assert (run_dir / "checkpoint.pt").read_bytes() == before
        lines[name] = result.stderr
    return lines


@pytest.mark.parametrize("defect", DEFECTS)
def test_a_checkpoint_with_a_bad_field_is_one_line_at_every_entry_point(
    defect, good, tmp_path, monkeypatch, capsys
):
    change, said = DEFECTS[defect]
    marker, evil = tmp_path / "imported", tmp_path / "evil.py"
    evil.write_text(f"open({str(marker)!r}, 'w').close()\n")
    checkpoint = read_checkpoint(good)
    change(checkpoint, str(evil))
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    rewrite_checkpoint(path, checkpoint)
    lines = refusals(path, tmp_path, monkeypatch, capsys)
    assert not marker.exists()  # a script the checkpoint names was never imported
    for entry, line in lines.items():
        assert said in line, (entry, line)
    agent = load_script("a3c_ff").AGENT
    assert runtime.checkpoints.checkpoint_step(path, agent) is None  # the closing hint's reader


def test_an_archive_declaring_more_than_it_holds_is_refused_before_inflating(
    tmp_path, monkeypatch, capsys
):
    """A small zip that inflates to far more (here 64 MiB from some 64 KiB): refused by the
    sizes its members declare, nothing inflated."""
    path = tmp_path / "checkpoint.pt"
    with (
        zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive,
        archive.open("archive/data.pkl", "w") as member,
    ):
        for _ in range(64):
            member.write(bytes(1 << 20))
    assert path.stat().st_size < 1 << 20

    def inflating(*args, **kwargs):
        raise AssertionError("a member was inflated")

    monkeypatch.setattr(zipfile.ZipExtFile, "read", inflating)
    code, err = main_exit(load_script("a3c_ff"), ["--evaluate", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert "its members declare 67,108,864 bytes, more than the" in err, err
