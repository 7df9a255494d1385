"""a3c_tools.record_play: a checkpoint's agent playing one episode, written as a GIF of the
game's own screens."""

import a3c_runtime as runtime
import gymnasium as gym
import numpy as np
import pytest
from a3c_tools import record_play
from conftest import load_script, run_main, shared_for, tiny_args
from PIL import Image, ImageSequence

import catch_env  # noqa: F401  (registers Catch-v0)


def checkpoint_of(script: str, folder) -> str:
    module = load_script(script)
    args = tiny_args(module)
    path = folder / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script=f"{script}.py")
    return str(path)


def gif_frames(path) -> list[np.ndarray]:
    with Image.open(path) as image:
        return [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(image)]


@pytest.mark.parametrize("script", ["a3c_ff", "a3c_lstm"])
def test_a_whole_catch_episode_is_written_from_its_first_screen(script, tmp_path):
    """Every screen of the episode, the first the env's own after reset(seed), at Catch's
    10 steps per second; the LSTM's recurrent state is carried through the episode."""
    out = tmp_path / "play.gif"
    result = run_main(record_play.main, [checkpoint_of(script, tmp_path), "-o", str(out)])
    assert result.returncode == 0, result.stderr
    frames = gif_frames(out)
    env = gym.make("Catch-v0", render_mode="rgb_array")
    env.reset(seed=1)
    assert np.array_equal(frames[0], env.render())
    steps = 0
    while not any(env.step(0)[2:4]):
        steps += 1
    # the ball falls one row a step whatever the paddle does: the episode's length is fixed
    assert len(frames) == steps + 2
    assert f"{len(frames)} of the episode's {len(frames)} screens" in result.stdout
    with Image.open(out) as image:
        assert image.info["duration"] == 100 and image.info["loop"] == 0


def test_seconds_and_speed_cut_the_episode(tmp_path):
    checkpoint = checkpoint_of("a3c_ff", tmp_path)
    whole, part = tmp_path / "whole.gif", tmp_path / "part.gif"
    assert run_main(record_play.main, [checkpoint, "-o", str(whole)]).returncode == 0
    result = run_main(record_play.main, [checkpoint, "-o", str(part), "--speed", "2",
                                         "--seconds", "0.5"])  # fmt: skip
    assert result.returncode == 0, result.stderr
    every_other = gif_frames(whole)[::2][:5]
    assert [f.tobytes() for f in gif_frames(part)] == [f.tobytes() for f in every_other]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["{tmp}/missing.pt", "-o", "{tmp}/x.gif"], "does not exist"),
        (["{tmp}/bad.pt", "-o", "{tmp}/x.gif"], "is corrupt"),
        (["{tmp}/ok/checkpoint.pt", "-o", "{tmp}/x.png"], "--out must end in .gif"),
        (["{tmp}/ok/checkpoint.pt", "-o", "{tmp}/x.gif", "--speed", "0"], "--speed >= 1"),
    ],
)
def test_bad_input_is_one_line_and_exit_2_and_writes_nothing(argv, message, tmp_path):
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    (tmp_path / "ok").mkdir()
    checkpoint_of("a3c_ff", tmp_path / "ok")
    result = run_main(record_play.main, [a.format(tmp=tmp_path) for a in argv])
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1
    assert not list(tmp_path.glob("x.*"))
