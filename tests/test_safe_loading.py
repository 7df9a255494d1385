"""Nothing the project loads from a file runs code: a checkpoint is a safetensors file and a
JSON document (a3c_runtime.checkpoint_file), which hold no objects. A checkpoint of the older
format (a torch zip) carrying a pickled object whose `__reduce__` would create a file, planted
in each part a checkpoint had and sealed as the project sealed its own, is refused in one line
by every entry point that reads checkpoints (the converter included), and the file is never
created. Checkpoints of the older format are refused naming the command that converts them;
converted, they load and resume as they were. Every field of the current format is checked (the
gate): a bad one is one line at every entry point."""

import importlib.util
import io
import pickle
import zipfile

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
from a3c_runtime.snapshots import copy_of, restored_state, saved_state
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
    args = tiny_args(module, envs_per_worker=2)  # as catch_worker_state's envs
    shared = shared_for(module, args)
    path = tmp_path_factory.mktemp("good") / "checkpoint.pt"
    snapshot = {
        "workers": {0: saved_state(catch_worker_state())},
        "pending_evaluations": [(1000, runtime.snapshots.copy_of(shared.model.state_dict()))],
    }
    runtime.save_checkpoint(path, shared, args, 1.0, "a3c_ff.py", snapshot)
    return path


def old_checkpoint(path, raw: dict, sealed: bool = True, form: str = "a3c-checkpoint-v2"):
    """raw (read_checkpoint's fields) written in the older format: a torch zip, sealed."""
    old = {k: v for k, v in raw.items() if k != "pending_steps"}
    old.update(format=form, network="ActorCritic")
    buffer = io.BytesIO()
    torch.save(old, buffer)
    path.write_bytes(convert_checkpoint.seal(buffer.getvalue()) if sealed else buffer.getvalue())


PLACES = {  # each part of a checkpoint, and a payload put there
    "args": lambda c, p: c["args"].update(exp_name=p),
    "model": lambda c, p: c["model"].update({"value.weight": p}),
    "optimizer": lambda c, p: c["optimizer"]["square_avg"].__setitem__(0, p),
    "worker state": lambda c, p: c["workers"][0].__setitem__(1, p),
    "pending evaluation": lambda c, p: c["pending_evaluations"].append((2000, p)),
    "a key of its own": lambda c, p: c.update(extra=p),
}


def planted(good, folder, place, marker):
    """A copy of the good checkpoint in the older format with the payload at place, sealed; its
    payload is live."""
    checkpoint = read_checkpoint(good)
    PLACES[place](checkpoint, Payload(marker))
    path = folder / "run" / "checkpoint.pt"
    path.parent.mkdir(parents=True)
    old_checkpoint(path, checkpoint)
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
        assert "is of the older format (a torch zip), which is not loaded" in err, err
    result = run_main(record_play.main, [str(path), "-o", str(tmp_path / "play.gif")])
    assert result.returncode == 2 and "is of the older format" in result.stderr
    assert result.stderr.count("\n") == 1, result.stderr
    result = run_main(convert_checkpoint.main, [str(path)])  # only v1's worker pickles unpickle
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "holds more than any checkpoint of the agent scripts" in result.stderr
    assert runtime.checkpoints.checkpoint_step(path) is None  # the closing hint's reader
    assert fault_injection().checkpoint_state(path) is None
    out = tmp_path / "sweep"  # a sweep (and compare, through it) finding it in a run's folder
    (out / "runs").mkdir(parents=True)
    path.parent.rename(out / "runs" / "run-0000")
    argv = [str(ROOT / "agents" / "a3c_ff.py"), "--out", str(out), "--runs", "1",
            "--total-timesteps", "1000", "--", "--env", "Catch-v0"]  # fmt: skip
    result = run_main(sweep.main, argv)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "older format" in result.stderr and "is not run-0000's" not in result.stderr
    assert "once it is converted, to resume run-0000, or move or remove" in result.stderr
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
    checkpoint["args"].update(seed=5, total_timesteps=1000, envs_per_worker=1)
    checkpoint["workers"] = {}
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
    planned = runtime.flags.resolve_precision("auto", 1)  # the sweep's run: one env per worker
    other = "fp32" if planned != "fp32" else "bf16-learn"
    checkpoint["args"].update(seed=11, total_timesteps=1000, num_workers=1, precision=other,
                              envs_per_worker=1)  # fmt: skip
    checkpoint["workers"] = {}
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


def same(a, b) -> bool:
    """Whether two checkpoint parts are equal: tensors by value, containers by their items."""
    if torch.is_tensor(a) or torch.is_tensor(b):
        return torch.is_tensor(a) and torch.is_tensor(b) and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def test_an_unsealed_v2_checkpoint_converted_keeps_its_worker_states(good, tmp_path):
    path = tmp_path / "checkpoint.pt"
    checkpoint = read_checkpoint(good)
    old_checkpoint(path, checkpoint, sealed=False)
    assert run_main(convert_checkpoint.main, [str(path)]).returncode == 0
    converted = read_checkpoint(path)
    assert converted["workers"].keys() == checkpoint["workers"].keys()
    for worker_id, state in checkpoint["workers"].items():
        assert same(converted["workers"][worker_id], state)
    assert same(converted["pending_evaluations"], checkpoint["pending_evaluations"])


def v1_checkpoint(good, path, sealed: bool = False):
    """The good checkpoint as the scripts wrote it before safe loading: format v1, each
    worker's state pickled (and, before the seal, no zip comment)."""
    checkpoint = read_checkpoint(good)
    parts = catch_worker_state()
    checkpoint["workers"] = {0: [pickle.dumps(part) for part in parts]}
    old_checkpoint(path, checkpoint, sealed, form="a3c-checkpoint-v1")
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
    assert "is of the older format (a torch zip), which is not loaded" in err
    assert f"convert it: python -m a3c_tools.convert_checkpoint {path}" in err
    assert path.read_bytes() == before
    result = run_main(convert_checkpoint.main, [str(path)])
    assert result.returncode == 0 and result.stdout.startswith(f"converted {path}"), result.stderr
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob("*.a3c-partial"))
    assert runtime.checkpoints.read_checkpoint(str(path))[0]["format"] == "a3c-checkpoint-v4"
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
    assert again.returncode == 0 and "in the current format already" in again.stdout


def test_the_committed_checkpoints_load_safely():
    # results/ holds the committed ones (runs/ folders, ignored by git, hold runs in progress);
    # found on disk rather than by git, so that a copy of the tree without .git is tested too
    paths = [p for p in sorted(ROOT.glob("results/**/*.pt")) if "runs" not in p.parts]
    assert paths, "no committed checkpoint found"
    for path in paths:
        checkpoint = runtime.checkpoints.open_checkpoint(str(path))
        agent = load_script(checkpoint.script.removesuffix(".py")).AGENT
        assert runtime.checkpoints.for_agent(checkpoint, agent).model, path


def test_a_checkpoint_holds_tensors_and_a_json_document_only(good):
    """The file: safetensors' header (each tensor's dtype, shape and place), the document and
    the seal as its metadata, then the tensors' bytes; nothing else."""
    import json

    import safetensors

    with safetensors.safe_open(good, "pt") as f:
        metadata, names = f.metadata(), list(f.keys())  # noqa: SIM118
    assert sorted(metadata) == ["a3c", "sha256"]
    document = json.loads(metadata["a3c"])
    assert sorted(document) == ["args", "format", "global_step", "pending_steps", "script",
                                "wall_time", "workers"]  # fmt: skip
    assert document["pending_steps"] == [1000] and sorted(document["workers"]) == ["0"]
    assert {name.split("/")[0] for name in names} == {"model", "optimizer", "pending", "workers"}


# ------------------------------------------------------------------------------------------------
# The gate (a3c_runtime.checkpoints.open_checkpoint): a sealed checkpoint whose fields are wrong is
# refused in one line by every entry point, before anything is imported, created or started
# ------------------------------------------------------------------------------------------------
NAN, INF = float("nan"), float("inf")
LE, GE = "Input should be less than or equal to", "Input should be greater than or equal to"


def pending_step(checkpoint: dict, step) -> None:
    checkpoint["pending_evaluations"][0] = (step, checkpoint["pending_evaluations"][0][1])


def junk_generator(state: list) -> list:
    state[0] = {"bit_generator": {"bit_generator": "PCG64", "state": {"state": 1, "inc": 2},
                                  "has_uint32": 1, "uinteger": 7}}  # fmt: skip
    return state


DEFECTS = {  # a sealed checkpoint changed as a careless or hostile writer would, and the line
    # (`evil`: the absolute path of a script that, imported, creates a file)
    "a key missing": (lambda c, evil: c.pop("args"), "is malformed: its args: Field required"),
    "a step of another type": (lambda c, evil: c.update(global_step="1000"),
                               "is malformed: its global_step: Input should be a valid integer"),
    "a flag of another type": (lambda c, evil: c["args"].update(learning_rate="fast"),
                               "its flag learning_rate: Input should be a valid number"),
    "a module to import as its env": (lambda c, evil: c["args"].update(env="this:Catch-v0"),
                                      "holds the env 'this:Catch-v0': a module"),
    "an unknown env": (lambda c, evil: c["args"].update(env="Nope-v9"),
                       "an unknown env id; valid:"),
    "an env that is no game": (lambda c, evil: c["args"].update(env="CartPole-v1"),
                               "not an env of the scripts; valid:"),
    "NaN weights": (lambda c, evil: c["model"]["value.weight"].fill_(NAN),
                    "its model/value.weight holds NaN or inf (the run diverged)"),
    "inf weights": (lambda c, evil: c["model"]["policy.bias"].fill_(INF),
                    "its model/policy.bias holds NaN or inf (the run diverged)"),
    "one NaN among finite weights": (
        lambda c, evil: c["model"]["value.weight"].view(-1)[1:2].fill_(NAN),
        "its model/value.weight holds NaN or inf"),
    "an absolute path as its script": (lambda c, evil: c.update(script=evil),
                                       "not an agent script"),
    "a path up as its script": (lambda c, evil: c.update(script="../" * 40 + evil[1:]),
                                "not an agent script"),
    "a path up after a3c_ff.py as its script": (
        lambda c, evil: c.update(script="a3c_ff.py/" + "../" * 40 + evil[1:]),
        "not an agent script"),
    "a million workers": (lambda c, evil: c["args"].update(num_workers=10**6),
                          f"its args/num_workers: {LE} 1024"),
    "a million evaluation episodes": (lambda c, evil: c["args"].update(eval_episodes=10**6),
                                      f"its args/eval_episodes: {LE} 10000"),
    "no workers": (lambda c, evil: c["args"].update(num_workers=0),
                   f"its args/num_workers: {GE} 1"),
    "a pending evaluation of another network": (
        lambda c, evil: c["pending_evaluations"].append((2000, {"w": torch.zeros(2)})),
        "does not fit this network (is it another script's?): pending/1/"),
    "a worker by name": (lambda c, evil: c["workers"].update({"w": copy_of(c["workers"][0])}),
                         "is corrupt or not a checkpoint: its workers/w/"),
    # issue 103: fields that passed, or failed later with a traceback
    "a step of 10**30": (lambda c, evil: c.update(global_step=10**30),
                         "is malformed: its global_step: Input should be less than or equal"),
    "a NaN mean square": (lambda c, evil: c["optimizer"]["square_avg"][0].view(-1)[0:1].fill_(NAN),
                          "its optimizer/square_avg/0 holds NaN or inf"),
    "a negative mean square": (lambda c, evil: c["optimizer"]["square_avg"][1].fill_(-1.0),
                               "its optimizer statistic optimizer/square_avg/1 is negative"),
    "a mean square of another shape": (
        lambda c, evil: c["optimizer"]["square_avg"].__setitem__(0, torch.zeros(3)),
        "does not fit this network: optimizer/square_avg/0: ('F32', (3,)) in it"),
    "a worker numbered -5 with a junk generator": (
        lambda c, evil: c["workers"].update({-5: junk_generator(copy_of(c["workers"][0]))}),
        "is corrupt or not a checkpoint: its workers/-5/"),
    "an env stack of another shape": (
        lambda c, evil: c["workers"][0].__setitem__(2, torch.zeros(3, 4, 84, 84).byte()),
        "does not fit this network: workers/0/frames: ('BOOL', (3, 3, 84, 84)) in it"),
    "an env state of another env count": (
        lambda c, evil: c["workers"][0][1]["env"]["env"]["rngs"].pop(),
        "workers/0/generators: ('U8', (1, 37)) in it, ('U8', (2, 37)) here"),
    "a NaN flag": (lambda c, evil: c["args"].update(learning_rate=NAN),
                   "is malformed: its args/learning_rate: Value error, not a bool"),
    "an infinite flag": (lambda c, evil: c["args"].update(ent_coef=-INF),
                         "is malformed: its args/ent_coef: Value error"),
    "an LSTM of 10**9 cells": (lambda c, evil: c["args"].update(lstm_cells=10**9),
                               f"its args/lstm_cells: {LE} 16384"),
    "10**9 prototypes": (lambda c, evil: c["args"].update(prototypes_per_action=10**9),
                         f"its args/prototypes_per_action: {LE} 4096"),
    "10**9 LWS kernels": (lambda c, evil: c["args"].update(lws_kcps=10**9),
                          f"its args/lws_kcps: {LE} 4096"),
    "10**9 LWS maps": (lambda c, evil: c["args"].update(lws_second_layer_maps=10**9),
                       f"its args/lws_second_layer_maps: {LE} 4096"),
    "10**9 where maps": (lambda c, evil: c["args"].update(ww_where_maps=10**9),
                         f"its args/ww_where_maps: {LE} 4096"),
    "a pending step of True": (
        lambda c, evil: pending_step(c, True),
        "is malformed: its pending_steps/0: Input should be a valid integer"),
    "a negative pending step": (
        lambda c, evil: pending_step(c, -5),
        "is malformed: its pending_steps/0: Input should be greater than or equal to 0"),
    "a network name": (lambda c, evil: c.update(network="x" * 10_000),
                       "is malformed: its network: Extra inputs are not permitted"),
    "an optimizer of none": (lambda c, evil: c["args"].update(optimizer="sgd"),
                             "its flag optimizer: Input should be 'rmsprop' or 'adam'"),
}  # fmt: skip
# the defects of issue 103 (tests/test_safe_loading.py's own run of them against 952b51b fails
# each of them: passed, a traceback, or another line)
ISSUE_103 = list(DEFECTS)[list(DEFECTS).index("a step of 10**30") :]


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
    rewrite_checkpoint(path, checkpoint, checked=False)
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
    assert code == 2 and err.count("\n") == 1 and "is of the older format" in err, err
    result = run_main(convert_checkpoint.main, [str(path)])  # the one reader of zips
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "its members declare 67,108,864 bytes, more than the" in result.stderr
