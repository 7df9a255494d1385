"""Issue 103: the values of a checkpoint's Catch games are data too. A worker's Catch state (the
balls' rows, columns and speeds, the paddles, the start draws, the canvas and the cells drawn on
it, the frame stacks) is checked against the states the games reach between two steps before
it reaches an env: a hand-edited value is refused in one line, exit 2, by --resume."""

import subprocess
import sys

import numpy as np
import pytest
import torch
from a3c_runtime.catch_state import catch_layout, catch_problem, part_at
from conftest import ROOT, load_script, main_exit, read_checkpoint, rewrite_checkpoint

import catch_env  # noqa: F401  (registers Catch-v0)


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


def arrays(checkpoint: dict) -> dict[str, torch.Tensor]:
    """Worker 0's Catch arrays by catch_layout's names (they share the checkpoint's tensors)."""
    return {name: part_at(checkpoint["workers"][0][1]["env"], name) for name in catch_layout()}


def set_pixel(tensor: torch.Tensor, value: int) -> None:
    tensor.view(-1)[tensor.numel() // 2 + 1] = value


EDITS = {  # (array, what is written into it, the line's end)
    "a ball below the board": ("env/ball_row", 30, "env/ball_row holds 30 (valid: 4 to 18)"),
    "a ball above its start": ("env/ball_row", -1, "env/ball_row holds -1 (valid: 4 to 18)"),
    "a ball on the paddle's row": ("env/ball_row", 19, "holds 19 (valid: 4 to 18)"),
    "a ball right of the board": ("env/ball_col", 24, "env/ball_col holds 24 (valid: 0 to 23)"),
    "a ball left of the board": ("env/ball_col", -3, "env/ball_col holds -3 (valid: 0 to 23)"),
    "a speed of 3": ("env/ball_vx", 3, "env/ball_vx holds 3 (valid: -2 to 2)"),
    "a paddle off the board": ("env/paddle", 22, "env/paddle holds 22 (valid: 2 to 21)"),
    "a paddle half off": ("env/paddle", 1, "env/paddle holds 1 (valid: 2 to 21)"),
    "a game waiting for its reset": ("env/_needs_reset", True, "env/_needs_reset holds True"),
    "a start draw of 1": ("env/_starts", 1.0, "env/_starts holds 1.0 (valid: 0 to 1)"),
    "a negative start draw": ("env/_starts", -0.5, "env/_starts holds -0.5"),
    "start draws used past the buffer": ("env/_starts_used", 65, "holds 65 (valid: 0 to 64)"),
    "start draws used negative": ("env/_starts_used", -1, "holds -1 (valid: 0 to 64)"),
    "an episode of 15 steps in course": ("lengths", 15, "lengths holds 15 (valid: 0 to 14)"),
    "a return of 2": ("returns", 2.0, "returns holds 2.0 (valid: 0 to 1)"),
    "a ball moved without its cells": ("env/ball_col", "moved", "env/drawn is not the cells"),
    "a drawn cell outside the canvas": ("env/drawn/0", 10**9, "env/drawn is not the cells"),
    "a stray pixel on the canvas": ("env/_obs", 255, "env/_obs is not the canvas"),
    "a grey pixel in an older frame": ("stack", 7, "stack holds a pixel that is neither"),
}


@pytest.mark.parametrize("edit", EDITS)
def test_a_hand_edited_catch_state_is_refused_in_one_line_by_resume(
    written, edit, tmp_path, monkeypatch, capsys
):
    checkpoint = read_checkpoint(written)
    name, value, message = EDITS[edit]
    array = arrays(checkpoint)[name]
    if value == "moved":  # another valid column, the canvas left as it was
        array[0] = (array[0] + 12) % 24
    elif name in ("env/_obs", "stack"):
        index = (0, 0) if name == "stack" else (0,)
        frame = array[index]
        flat = frame.view(-1)
        flat[int((flat == 0).nonzero()[len(flat) // 3])] = value  # a pixel that was 0
    else:
        array.view(-1)[-1] = value
    path = tmp_path / "checkpoint.pt"
    rewrite_checkpoint(path, checkpoint)
    code, err = main_exit(load_script("a3c_ff"), ["--resume", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"error: checkpoint {str(path)!r} is malformed: its workers/0/"), err
    assert message in err, err
    assert not (tmp_path / "evaluations.csv").exists()  # nothing started


def test_the_frames_a_worker_acts_on_are_its_games_stacks(written, tmp_path, monkeypatch, capsys):
    checkpoint = read_checkpoint(written)
    frames = checkpoint["workers"][0][2]
    frames[...] = frames.roll(1, dims=0)  # the games' stacks in another order
    path = tmp_path / "checkpoint.pt"
    rewrite_checkpoint(path, checkpoint)
    code, err = main_exit(load_script("a3c_ff"), ["--resume", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.endswith("its workers/0/frames are not the envs' stacks\n"), err


def test_every_state_the_games_reach_between_steps_passes():
    """The check refuses no state of the games: 3 games over 200 steps of random actions (every
    end and restart among them), and the states of an env made and reset afresh."""
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("Catch-v0", 3)
    obs, _ = envs.reset(seed=7)
    rng = np.random.default_rng(7)
    for t in range(201):
        state = envs.get_state()
        tensors = {name: torch.tensor(part_at(state, name)) for name in catch_layout()}
        assert catch_problem(tensors, torch.from_numpy(obs.copy())) is None, t
        obs, *_ = envs.step(rng.integers(0, 3, size=3))
