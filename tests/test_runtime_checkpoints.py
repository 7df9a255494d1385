"""a3c_runtime.checkpoints: a round trip of network, optimizer statistics and step, and every
bad checkpoint as a one-line UsageError (changed bytes included, before a tensor is read; one
of the older format, naming its converter); converted checkpoints from before a flag or the
script name still load."""

import json
import multiprocessing
import os
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import a3c_runtime as runtime
import pytest
import safetensors.torch
import torch
from conftest import (
    SCRIPTS,
    load_script,
    main_exit,
    read_checkpoint,
    rewrite_checkpoint,
    shared_for,
    tiny_args,
)
from pydantic import ValidationError

import catch_env  # noqa: F401  (registers Catch-v0)

OPTIMIZER_STATISTICS = {"rmsprop": ("square_avg",), "adam": ("exp_avg", "exp_avg_sq")}


def checkpoint_round_trip(module, name, folder: Path, optimizer: str):
    """Save a Shared whose optimizer statistics are non-zero, restore it into a fresh Shared with
    another initial network, and check that the network, statistics and step came back."""
    args = tiny_args(module, optimizer=optimizer)
    shared = shared_for(module, args)
    shared.steps[0] = 1234
    for i, key in enumerate(OPTIMIZER_STATISTICS[optimizer]):
        for j, statistic in enumerate(getattr(shared.optimizer, key)):
            statistic.copy_(torch.rand_like(statistic) + i + j + 1)  # non-zero, all different
    if optimizer == "adam":
        shared.optimizer.step_count.fill_(37)
    path = folder / optimizer / "checkpoint.pt"
    path.parent.mkdir()
    runtime.save_checkpoint(path, shared, args, wall_time=12.0, script=f"{name}.py")
    checkpoint = runtime.load_checkpoint(str(path), module.AGENT)
    assert checkpoint.global_step == 1234 and checkpoint.wall_time == 12.0
    assert checkpoint.script == f"{name}.py" and checkpoint.flags.optimizer == optimizer
    torch.manual_seed(123)  # another initial network
    fresh = shared_for(module, args)
    runtime.restore(fresh, checkpoint, args, str(path), module.AGENT)
    assert fresh.global_step() == 1234
    for p, q in zip(fresh.params, shared.params, strict=True):
        assert torch.equal(p, q)
    for key in OPTIMIZER_STATISTICS[optimizer]:
        restored, saved = getattr(fresh.optimizer, key), getattr(shared.optimizer, key)
        assert len(restored) == len(saved) == len(fresh.params)
        for r, s in zip(restored, saved, strict=True):
            assert (s != 0).all() and torch.equal(r, s), key
            assert r.is_shared()  # restored in place: the workers still share them
    if optimizer == "adam":
        assert fresh.optimizer.step_count.item() == 37 and fresh.optimizer.step_count.is_shared()
    return args, checkpoint, fresh, path


@pytest.mark.parametrize("name", SCRIPTS)
def test_checkpoint_round_trip_and_errors(name, tmp_path):
    module = load_script(name)
    checkpoint_round_trip(module, name, tmp_path, "adam")
    args, checkpoint, fresh, path = checkpoint_round_trip(module, name, tmp_path, "rmsprop")

    agent = module.AGENT
    with pytest.raises(runtime.UsageError, match="does not exist"):
        runtime.load_checkpoint(str(tmp_path / "missing.pt"), agent)
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(runtime.UsageError, match="corrupt"):
        runtime.load_checkpoint(str(tmp_path / "garbage.pt"), agent)
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(runtime.UsageError, match="older format .* convert it: python -m a3c_tools"):
        runtime.load_checkpoint(str(tmp_path / "other.pt"), agent)
    safetensors.torch.save_file({"weights": torch.ones(1)}, tmp_path / "other.pt")
    with pytest.raises(runtime.UsageError, match="not a checkpoint: its __metadata__: Field req"):
        runtime.load_checkpoint(str(tmp_path / "other.pt"), agent)
    elu = tiny_args(module, activation="elu")
    with pytest.raises(runtime.UsageError, match="--activation"):
        runtime.restore(fresh, checkpoint, elu, str(path), agent)
    checkpoint.model["value.weight"] = torch.zeros(5, 7)
    with pytest.raises(runtime.UsageError, match="does not fit") as error:
        runtime.restore(fresh, checkpoint, args, str(path), agent)
    assert "\n" not in str(error.value)


@pytest.fixture(scope="module")
def ff_checkpoints(tmp_path_factory) -> tuple[Path, Path]:
    """An a3c_ff.py checkpoint, and the same without the script name (as written before the
    name was stored, and converted)."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    folder = tmp_path_factory.mktemp("ff")
    new, old = folder / "new" / "checkpoint.pt", folder / "old" / "checkpoint.pt"
    for path, script in ((new, "a3c_ff.py"), (old, "")):
        path.parent.mkdir()
        runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script=script)
    checkpoint = read_checkpoint(old)
    checkpoint["script"] = ""
    rewrite_checkpoint(old, checkpoint)
    return new, old


@pytest.mark.parametrize("name", [s for s in SCRIPTS if s != "a3c_ff"])
@pytest.mark.parametrize("mode", ["--resume", "--evaluate"])
def test_another_scripts_checkpoint_is_refused_naming_its_script(
    name, mode, ff_checkpoints, monkeypatch, capsys
):
    new, old = ff_checkpoints
    module = load_script(name)
    code, err = main_exit(module, [mode, str(new)], monkeypatch, capsys)
    assert code == 2 and "was written by a3c_ff.py, not " + name in err
    assert err.count("\n") == 1, err
    # one written before checkpoints named their script: its network does not fit
    code, err = main_exit(module, [mode, str(old)], monkeypatch, capsys)
    if name in ("a3c_ss", "a3c_ww", "a3c_lws"):  # their networks refuse already at a flag or key
        assert code == 2 and err.count("\n") == 1, err
    else:
        assert code == 2 and "does not fit this network (is it another script's?)" in err, err
        assert err.count("\n") == 1, err
    assert not list(new.parent.glob("events.*"))  # nothing written into the old run


def test_an_old_checkpoint_of_the_same_script_still_loads(ff_checkpoints):
    _, old = ff_checkpoints
    module = load_script("a3c_ff")
    checkpoint = runtime.load_checkpoint(str(old), module.AGENT)
    args = tiny_args(module)
    shared = shared_for(module, args)
    runtime.restore(shared, checkpoint, args, str(old), module.AGENT)
    assert shared.global_step() == checkpoint.global_step
    for key, value in shared.model.state_dict().items():
        assert torch.equal(value, checkpoint.model[key]), key


def test_evaluating_an_old_checkpoint_of_another_network_is_a_usage_error(ff_checkpoints):
    # no script name to refuse it by: the tensors of another shape give the one-line message
    _, old = ff_checkpoints
    module = load_script("a3c_ss")
    with pytest.raises(runtime.UsageError, match="does not fit this network: model/"):
        runtime.evaluate(module.AGENT, module.Args(evaluate=str(old), eval_episodes=1))


@pytest.mark.parametrize("name", ["a3c_ss", "a3c_ww"])
def test_checkpoints_from_before_conv_layout_hold_the_final_network(name, tmp_path, capsys):
    """Such checkpoints have no --conv-layout: the script's checkpoint_defaults say "final"."""
    module = load_script(name)
    args = tiny_args(module, conv_layout="final")
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="")
    checkpoint = read_checkpoint(path)
    del checkpoint["args"]["conv_layout"]  # as written before the flag
    rewrite_checkpoint(path, checkpoint)
    loaded = runtime.load_checkpoint(str(path), module.AGENT)
    runtime.restore(shared_for(module, args), loaded, args, str(path), module.AGENT)
    with pytest.raises(runtime.UsageError, match="--conv-layout final, not ff"):
        default = tiny_args(module)
        runtime.restore(shared_for(module, default), loaded, default, str(path), module.AGENT)
    evaluate = module.Args(evaluate=str(path), eval_episodes=1)
    assert len(runtime.evaluate(module.AGENT, evaluate)) == 1
    assert "over 1 episodes" in capsys.readouterr().out


def _save_under_a_file_size_limit(path: Path, limit: int, errors) -> None:
    import resource

    module = load_script("a3c_ff")
    args = tiny_args(module)
    shared = shared_for(module, args)
    shared.steps[0] = 99
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # Python ignores SIGXFSZ
    try:
        runtime.save_checkpoint(path, shared, args, 2.0, script="a3c_ff.py")
    except runtime.WriteFailed as e:
        errors.put(str(e))


def test_a_failed_checkpoint_write_keeps_the_last_one_and_leaves_no_partial_file(tmp_path):
    """A real failure: the file-size limit (RLIMIT_FSIZE) below a checkpoint's size. In a
    spawned child: a forked one can hang in its first torch op when the parent's threads
    held a lock at the fork (a test process has run many torch ops by then)."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    shared = shared_for(module, args)
    shared.steps[0] = 42
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared, args, 1.0, script="a3c_ff.py")
    size = path.stat().st_size
    spawn = multiprocessing.get_context("spawn")
    errors = spawn.SimpleQueue()
    child = spawn.Process(target=_save_under_a_file_size_limit, args=(path, size // 2, errors))
    child.start()
    child.join(120)
    assert child.exitcode == 0
    assert errors.get() == f"could not write {path}: File too large"
    assert runtime.load_checkpoint(str(path), module.AGENT).global_step == 42
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def changed_copies(path: Path, folder: Path) -> dict[str, Path]:
    """Copies of the checkpoint at path, each changed as a disk or a person might change it."""
    data = path.read_bytes()
    middle = len(data) // 2
    flipped = data[:middle] + bytes(b ^ 0xFF for b in data[middle : middle + 64])
    flipped += data[middle + 64 :]
    # a byte of the document (the JSON in the header): its step, 0 -> 1
    header = data.replace(b'\\"global_step\\":0', b'\\"global_step\\":1', 1)
    assert header != data
    changed = {
        "flipped": flipped,
        "header": header,
        "truncated": data[: len(data) // 3],
        "truncated in its header": data[:100],
        "foreign": b"PK\x03\x04" + bytes(100),  # a zip (torch's format before this one)
        "empty": b"",
    }
    copies = {}
    for name, content in changed.items():
        (folder / name).mkdir()
        copies[name] = folder / name / "checkpoint.pt"
        copies[name].write_bytes(content)
    return copies


CHANGES = ("flipped", "header", "truncated", "truncated in its header", "foreign", "empty")
MESSAGES = {
    "flipped": "is corrupt: its bytes do not match the SHA-256 it was written with",
    "header": "is corrupt: its bytes do not match the SHA-256 it was written with",
    "truncated": "is corrupt: its bytes do not match the SHA-256 it was written with",
    "truncated in its header": "is corrupt or not a checkpoint: its header declares",
    "foreign": "is of the older format (a torch zip), which is not loaded; if you trust it, "
    "convert it: python -m a3c_tools.convert_checkpoint",
    "empty": "is corrupt or not a checkpoint: its header declares 0 bytes (the file has 0)",
}


@pytest.mark.parametrize("change", CHANGES)
def test_a_changed_checkpoint_is_refused_before_a_tensor_is_read(change, ff_checkpoints, tmp_path):
    new, _ = ff_checkpoints
    path = changed_copies(new, tmp_path)[change]
    with pytest.raises(runtime.UsageError, match=re.escape(MESSAGES[change])) as error:
        runtime.load_checkpoint(str(path), load_script("a3c_ff").AGENT)
    assert "\n" not in str(error.value)
    assert runtime.checkpoints.checkpoint_step(path) is None  # never offered for --resume


@pytest.mark.parametrize("mode", ["--resume", "--evaluate"])
def test_resume_and_evaluate_refuse_a_changed_checkpoint_and_leave_it(
    mode, ff_checkpoints, tmp_path, monkeypatch, capsys
):
    new, _ = ff_checkpoints
    module = load_script("a3c_ff")
    for change, path in changed_copies(new, tmp_path).items():
        before = path.read_bytes()
        code, err = main_exit(module, [mode, str(path), "--num-workers", "1"], monkeypatch, capsys)
        assert code == 2 and MESSAGES[change] in err and err.count("\n") == 1, (change, err)
        assert path.read_bytes() == before  # not trained on, not overwritten
        assert sorted(p.name for p in path.parent.iterdir()) == ["checkpoint.pt"]


def test_a_sealed_checkpoint_loads(ff_checkpoints):
    """A safetensors file: its tensors flat, its document and seal in the header's metadata."""
    new, _ = ff_checkpoints
    with safetensors.safe_open(new, "pt") as f:
        metadata = f.metadata()
        assert all(name.startswith(("model/", "optimizer/")) for name in f.keys())  # noqa: SIM118
    assert sorted(metadata) == ["a3c", "sha256"]
    assert json.loads(metadata["a3c"])["format"] == runtime.checkpoints.CHECKPOINT_FORMAT
    checkpoint = runtime.load_checkpoint(str(new), load_script("a3c_ff").AGENT)
    assert checkpoint.flags == tiny_args(load_script("a3c_ff"))
    assert runtime.checkpoints.checkpoint_step(new) == 0


def test_the_closing_hint_does_not_offer_a_changed_checkpoint(ff_checkpoints, tmp_path):
    from a3c_runtime.a3c import resume_hint

    new, _ = ff_checkpoints
    agent = load_script("a3c_ff").AGENT
    path = changed_copies(new, tmp_path)["flipped"]
    hint = resume_hint(agent, path.parent)
    assert "does not verify (corrupt); start the run again" in hint and "--resume" not in hint
    (tmp_path / "good").mkdir()
    (tmp_path / "good" / "checkpoint.pt").write_bytes(new.read_bytes())
    assert "(step 0) survives; resume: " in resume_hint(agent, tmp_path / "good")


def test_the_closing_hint_of_a_run_whose_folder_was_removed_says_so(ff_checkpoints, tmp_path):
    """The folder deleted mid-run took the checkpoints written there: the line says the folder
    was removed, not that no checkpoint was written."""
    from a3c_runtime.a3c import resume_hint

    new, _ = ff_checkpoints
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "checkpoint.pt").write_bytes(new.read_bytes())  # written during the run
    agent = load_script("a3c_ff").AGENT
    assert "survives" in resume_hint(agent, run_dir)
    (run_dir / "checkpoint.pt").unlink()
    run_dir.rmdir()  # the user removes the folder
    hint = resume_hint(agent, run_dir)
    assert "no checkpoint was written" not in hint, hint
    assert f"the run folder {run_dir} was removed during the run, with the checkpoints" in hint
    assert "start the run again: python " in hint


@pytest.mark.parametrize("folder", ["left by the dead run", "removed during the run"])
def test_the_command_the_closing_hint_offers_starts_the_run_again(folder, tmp_path, monkeypatch):
    """The command after `start the run again:`, pasted into a shell, starts the run with its
    own flags, in a --run-dir it named emptied of the dead run's files first, and also when the
    folder was removed during the run (no `rm -r` of a missing folder, which fails and stops it)."""
    from a3c_runtime.a3c import resume_hint

    run_dir = tmp_path / "run"
    if folder == "left by the dead run":
        run_dir.mkdir()
        (run_dir / "evaluations.csv").write_text("global_step\n")
    argv = ["agents/a3c_ff.py", "--seed", "3", "--run-dir", str(run_dir)]
    monkeypatch.setattr(sys, "argv", argv)
    hint = resume_hint(load_script("a3c_ff").AGENT, run_dir)
    command = hint.split("start the run again: ", 1)[1]
    stub = tmp_path / "bin" / "python"  # the run's start, as this shell finds it: its argv
    stub.parent.mkdir()
    stub.write_text(
        '#!/bin/sh\n[ -e "$RUN_DIR" ] && echo there > "$STARTED" || echo gone > '
        '"$STARTED"\necho "$@" >> "$STARTED"\n'
    )
    stub.chmod(0o755)
    started = tmp_path / "started"
    env = {**os.environ, "PATH": f"{stub.parent}:{os.environ['PATH']}", "STARTED": str(started),
           "RUN_DIR": str(run_dir)}  # fmt: skip
    result = subprocess.run(["sh", "-c", command], env=env, capture_output=True, text=True)
    assert result.returncode == 0 and started.exists(), (command, result.stderr)
    assert started.read_text().splitlines() == [
        "gone",  # no folder of the dead run's left
        " ".join(argv),  # the run's own command, started
    ]


@pytest.mark.parametrize(
    ("argv0", "shown"), [("agents/a3c_ff.py", "agents/a3c_ff.py"), ("-c", "agents/a3c_ff.py"),
                         ("/elsewhere/a3c_ff.py", "/elsewhere/a3c_ff.py")]
)  # fmt: skip
def test_the_closing_hint_starts_the_run_again_with_its_own_command(
    tmp_path, monkeypatch, argv0, shown
):
    """With no checkpoint, the command offered is the run's own: its script once (as it was
    called, or agents/<script> when it was not called by name), then every flag it was given;
    a --run-dir it named is removed first, so the new attempt does not mix with the dead one."""
    from a3c_runtime.a3c import resume_hint

    agent = load_script("a3c_ff").AGENT
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    monkeypatch.setattr(sys, "argv", [argv0, "--seed", "3", "--run-dir", str(run_dir)])
    hint = resume_hint(agent, run_dir)
    again = f"python {shown} --seed 3 --run-dir {run_dir}"
    assert hint == f"no checkpoint was written in {run_dir}; start the run again: rm -r -- " \
        f"{run_dir} && {again}"  # fmt: skip
    monkeypatch.setattr(sys, "argv", [argv0, "--seed", "3"])
    assert resume_hint(agent, run_dir).endswith(f"start the run again: python {shown} --seed 3")


@pytest.mark.parametrize("mode", ["--resume", "--evaluate"])
def test_a_folder_for_a_checkpoint_names_the_checkpoint_in_it(
    mode, ff_checkpoints, tmp_path, monkeypatch, capsys
):
    new, _ = ff_checkpoints
    run = tmp_path / "runs" / "x"
    run.mkdir(parents=True)
    module = load_script("a3c_ff")
    monkeypatch.chdir(tmp_path)
    code, err = main_exit(module, [mode, "runs/x"], monkeypatch, capsys)
    assert (
        code == 2 and err == "error: checkpoint 'runs/x' is a folder, and holds no checkpoint.pt\n"
    )
    (run / "checkpoint.pt").write_bytes(new.read_bytes())
    code, err = main_exit(module, [mode, "runs/x"], monkeypatch, capsys)
    assert code == 2, err
    expected = f"is a folder: pass its checkpoint, {mode} runs/x/checkpoint.pt\n"
    assert err == "error: checkpoint 'runs/x' " + expected
    # nothing created: no lock file in the folder or beside it
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["x"]
    assert sorted(p.name for p in run.iterdir()) == ["checkpoint.pt"]


def test_a_checkpoint_of_another_network_names_its_first_four_missing_keys():
    module = load_script("a3c_ff")
    model = module.AGENT.build_network(3, tiny_args(module))
    names = list(model.state_dict())
    for kept, shown in ((names[:-4], names[-4:]), (names[:-5], names[-5:-1])):
        checkpoint = SimpleNamespace(model={k: model.state_dict()[k] for k in kept})
        with pytest.raises(runtime.UsageError) as raised:
            runtime.checkpoints.load_network(model, checkpoint, "c.pt")
        more = " ..." if len(names) - len(kept) > 4 else ""
        assert str(raised.value).endswith(f"missing: {', '.join(shown)}{more}"), raised.value


def test_a_fields_type_is_checked_against_its_annotation_through_annotated():
    """tyro's Annotated[T, ...] flags: the value is checked against T, not the metadata."""
    import dataclasses
    import typing

    @dataclasses.dataclass
    class Args:
        n: typing.Annotated[int, "a tyro note"] = 1
        precision: typing.Annotated[typing.Literal["fp32", "auto"], "note"] = "fp32"

    flags = runtime.checkpoints.flags_type(Args)
    flags.validate_python({"n": 3, "precision": "auto"})
    for bad in ({"n": "3"}, {"n": 3.5}, {"precision": "bf16"}):
        with pytest.raises(ValidationError):
            flags.validate_python(bad)
