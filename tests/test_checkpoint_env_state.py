"""Issue 103: the values of a checkpoint's Catch games are data too. A worker's Catch games are
stored as what their next steps depend on (positions, episode sums and generators in the
document, typed and bounded by a3c_runtime.catch_state's CatchGames; the start draws and the
stacks' older frames, as bits, in tensors): a hand-edited value outside what the games reach is
refused in one line, exit 2, by --resume; the canvas and each stack's newest frame are drawn
from the positions on load, so no file can make them disagree."""

import json
import subprocess
import sys

import hypothesis
import numpy as np
import pytest
import safetensors.torch
import torch
from a3c_runtime.catch_state import (
    PCG64_BYTES,
    CatchGames,
    generator_bytes,
    generator_state,
    loaded_games,
    stored_games,
)
from a3c_runtime.checkpoint_file import sealed
from a3c_runtime.snapshots import arrays_of, tensors_of
from a3c_tools import convert_checkpoint
from conftest import ROOT, load_script, main_exit, read_checkpoint, rewrite_checkpoint, run_main

from catch_env.wrappers import make_vector_env


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """A real one-worker Catch run's checkpoint: three games, stopped in mid-episode."""
    run = tmp_path_factory.mktemp("catch") / "run"
    command = [sys.executable, "agents/a3c_ff.py", "--env", "Catch-v0", "--num-workers", "1",
               "--envs-per-worker", "3", "--t-max", "7", "--total-timesteps", "200",
               "--eval-interval", "100", "--eval-episodes", "2", "--run-dir", str(run)]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    return run / "checkpoint.pt"


LE, GE = "less than or equal to", "greater than or equal to"
EDITS = {  # (the array of the env's state, the value written in game 2, the schema's words)
    "a ball below the board": ("ball_row", 30, f"ball_row/2: Input should be {LE} 18"),
    "a ball above its start": ("ball_row", -1, f"ball_row/2: Input should be {GE} 4"),
    "a ball on the paddle's row": ("ball_row", 19, f"ball_row/2: Input should be {LE} 18"),
    "a ball right of the board": ("ball_col", 24, f"ball_col/2: Input should be {LE} 23"),
    "a ball left of the board": ("ball_col", -3, f"ball_col/2: Input should be {GE} 0"),
    "a speed of 3": ("ball_vx", 3, f"ball_vx/2: Input should be {LE} 2"),
    "a paddle off the board": ("paddle", 22, f"paddle/2: Input should be {LE} 21"),
    "a paddle half off": ("paddle", 1, f"paddle/2: Input should be {GE} 2"),
    "draws used past the buffer": ("_starts_used", 65, f"starts_used/2: Input should be {LE} 64"),
    "start draws used negative": ("_starts_used", -1, f"starts_used/2: Input should be {GE} 0"),
    "an episode of 15 steps in course": ("lengths", 15, f"lengths/2: Input should be {LE} 14"),
    "a return of 2": ("returns", 2.0, f"returns/2: Input should be {LE} 1"),
    "a start draw of 1": ("_starts", 1.0, "workers/0/starts holds a draw outside [0, 1)"),
    "a negative start draw": ("_starts", -0.5, "workers/0/starts holds a draw outside [0, 1)"),
}  # fmt: skip


def worker_env(checkpoint: dict) -> dict:
    return checkpoint["workers"][0][1]["env"]


@pytest.mark.parametrize("edit", EDITS)
def test_a_hand_edited_catch_state_is_refused_in_one_line_by_resume(
    written, edit, tmp_path, monkeypatch, capsys
):
    checkpoint = read_checkpoint(written)
    name, value, message = EDITS[edit]
    state = worker_env(checkpoint)
    (state if name in ("lengths", "returns") else state["env"])[name].view(-1)[-1] = value
    path = tmp_path / "checkpoint.pt"
    rewrite_checkpoint(path, checkpoint, checked=False)
    code, err = main_exit(load_script("a3c_ff"), ["--resume", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"error: checkpoint {str(path)!r}"), err
    assert err.rstrip().endswith(message), err
    assert not (tmp_path / "evaluations.csv").exists()  # nothing started


def test_a_moved_ball_is_drawn_where_it_is(written, tmp_path):
    """The canvas and the newest frame are not in the file: a ball moved to another valid
    column loads drawn at that column, on the canvas and in the frames the worker acts on."""
    checkpoint = read_checkpoint(written)
    inner = worker_env(checkpoint)["env"]
    inner["ball_col"][0] = (inner["ball_col"][0] + 12) % 24
    path = tmp_path / "checkpoint.pt"
    rewrite_checkpoint(path, checkpoint)
    loaded = read_checkpoint(path)
    frames, state = loaded["workers"][0][2], worker_env(loaded)
    envs = make_vector_env("Catch-v0", 3)
    envs.set_state(arrays_of(state))
    canvas = envs.env.unwrapped._obs
    assert np.array_equal(frames[:, -1].numpy(), canvas) and torch.equal(frames, state["stack"])
    assert not torch.equal(frames[0, -1], read_checkpoint(written)["workers"][0][2][0, -1])


def test_every_state_the_games_reach_between_steps_is_stored_and_loaded_exactly():
    """No state of the games is refused or changed: 3 games over 200 steps of random actions
    (every end and restart among them), from a fresh reset on, each stored, validated by the
    schema and loaded back equal to the env's own state and frames."""
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("Catch-v0", 3)
    obs, _ = envs.reset(seed=7)
    rng = np.random.default_rng(7)
    for t in range(201):
        state = tensors_of(envs.get_state())
        games, tensors = stored_games(state, torch.from_numpy(obs.copy()))
        CatchGames.model_validate(games)
        loaded, frames = loaded_games(games, tensors)
        assert torch.equal(frames, torch.from_numpy(obs)), t
        assert torch.equal(loaded["stack"], state["stack"]), t
        for key in ("returns", "lengths"):
            assert torch.equal(loaded[key], state[key].to(loaded[key].dtype)), (t, key)
        for key, value in state["env"].items():
            same = value == loaded["env"][key] if key == "rngs" else torch.equal(
                value.to(loaded["env"][key].dtype), loaded["env"][key])  # fmt: skip
            assert same, (t, key)
        obs, *_ = envs.step(rng.integers(0, 3, size=3))


def as_v3(v4: bytes) -> bytes:
    """A checkpoint in v3's layout, as the scripts wrote it before v4: each worker's Catch arrays
    (the canvas among them) as tensors under env/, its generators' words in the document in
    decimal, an optimizer_name beside the flags."""
    tensors = safetensors.torch.load(v4)
    header = json.loads(v4[8 : 8 + int.from_bytes(v4[:8], "little")])
    document = json.loads(header["__metadata__"]["a3c"])

    def decimal(stored: torch.Tensor) -> dict:
        state = generator_state(stored)
        return {**state, "state": {k: str(v) for k, v in state["state"].items()}}

    workers = {}
    for worker_id, games in document["workers"].items():
        prefix = f"workers/{worker_id}/"
        own = {n[len(prefix) :]: tensors.pop(n) for n in list(tensors) if n.startswith(prefix)}
        workers[worker_id] = {"generator": decimal(own.pop("generator")), "env": None}
        if games is not None:
            state, frames = loaded_games(games, own)
            workers[worker_id]["env"] = [decimal(g) for g in own["generators"]]
            inner = {k: v for k, v in state["env"].items() if k != "rngs"}
            arrays = {**{f"env/{k}": state[k] for k in ("stack", "returns", "lengths")},
                      **{f"env/env/{k}": v for k, v in inner.items()},
                      "env/env/_obs": frames[:, -1].clone(), "frames": frames}  # fmt: skip
            tensors.update({prefix + k: v.contiguous() for k, v in arrays.items()})
    document.update(format="a3c-checkpoint-v3", workers=workers,
                    optimizer_name=document["args"]["optimizer"])  # fmt: skip
    return sealed(tensors, document)  # (v3's seal was v4's)


def test_a_v3_checkpoint_is_refused_naming_its_converter_which_converts_it_exactly(
    written, tmp_path, monkeypatch, capsys
):
    """v3 (the Catch arrays, canvas included, as tensors) is not loaded; convert_checkpoint
    writes it as v4, and what it writes loads to the very state v4 holds."""
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(as_v3(written.read_bytes()))
    code, err = main_exit(load_script("a3c_ff"), ["--resume", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert "is of the older format (a3c-checkpoint-v3), which is not loaded" in err, err
    result = run_main(convert_checkpoint.main, [str(path)])
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(f"converted {path} (a3c-checkpoint-v3, step "), result.stdout
    converted, original = read_checkpoint(path), read_checkpoint(written)
    assert converted["format"] == "a3c-checkpoint-v4"
    assert same(converted, original)
    damaged = bytearray(as_v3(written.read_bytes()))
    damaged[-5] ^= 1  # a flipped bit among the tensors' bytes
    path.write_bytes(damaged)
    result = run_main(convert_checkpoint.main, [str(path)])
    expected = "is corrupt: its bytes do not match the SHA-256 it was written with\n"
    assert result.returncode == 2 and result.stderr == f"error: checkpoint {str(path)!r} {expected}"
    assert path.read_bytes() == damaged


def same(a: object, b: object) -> bool:
    if torch.is_tensor(a):
        return torch.is_tensor(b) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


@pytest.mark.parametrize(
    ("script", "flag", "value", "owner"),
    [
        (script, flag, value, owner)
        for script, moved in convert_checkpoint.MOVED_FLAGS.items()
        for (flag, value), owner in moved.items()
    ],  # fmt: skip
)
def test_a_thesis_scripts_checkpoint_with_a_chapter_8_flag_converts_as_its_scripts(
    script, flag, value, owner
):
    fields = {"script": script, "args": {flag: value, "env": "Catch-v0"}}
    assert convert_checkpoint.attributed(fields)["script"] == owner
    other = {"script": script, "args": {flag: not value if value is True else "other"}}
    assert convert_checkpoint.attributed(other)["script"] == script


@hypothesis.given(hypothesis.strategies.binary(min_size=PCG64_BYTES, max_size=PCG64_BYTES))
def test_every_value_a_generator_tensor_holds_is_a_pcg64_state(data):
    """A generator is stored as its bytes: any file's are a state NumPy's PCG64 takes and draws
    from, and a real state's bytes come back as they were."""
    state = generator_state(torch.tensor(list(data), dtype=torch.uint8))
    rng = np.random.Generator(np.random.PCG64())
    rng.bit_generator.state = state
    rng.random(3)
    assert generator_bytes(rng.bit_generator.state).shape == (PCG64_BYTES,)
    real = np.random.default_rng(int.from_bytes(data[:8], "little")).bit_generator.state
    assert generator_state(generator_bytes(real)) == real


def test_the_writer_refuses_a_generator_no_pcg64_state_is():
    with pytest.raises(ValueError, match="a MT19937 generator is not a PCG64 one"):
        generator_bytes(np.random.MT19937(1).state)
    state = np.random.default_rng(1).bit_generator.state
    with pytest.raises(OverflowError):
        generator_bytes({**state, "state": {**state["state"], "inc": 2**200}})
