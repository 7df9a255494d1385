"""The thesis's preprocessing: `catch_env.wrappers.make_env` for Catch and for ALE ids."""

import numpy as np
import pytest

from catch_env.wrappers import (
    EpisodicLifeEnv,
    FireResetEnv,
    is_atari,
    make_env,
    observation_scale,
)


def find_wrapper(env, kind):
    while env is not None:
        if isinstance(env, kind):
            return env
        env = getattr(env, "env", None)
    return None


def test_catch_gives_a_stack_of_four_frames_cleared_on_reset():
    env = make_env("Catch-v0")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4, 84, 84) and obs.dtype == np.uint8
    # The first state of an episode repeats its first frame (no frames of another episode).
    assert all(np.array_equal(obs[0], frame) for frame in obs)
    for _ in range(15):
        previous = obs
        obs, reward, terminated, truncated, info = env.step(0)
        np.testing.assert_array_equal(obs[:3], previous[1:])  # action repeat 1: one new frame
    assert terminated and info["episode"]["l"] == 15 and info["episode"]["r"] == reward
    obs, _ = env.reset()
    assert all(np.array_equal(obs[0], frame) for frame in obs)


def test_catch_kwargs_pass_through():
    env = make_env("Catch-v0", obs_type="grid", grid_size=12)
    assert env.reset(seed=0)[0].shape == (4, 12, 12)


def test_is_atari_and_input_scale():
    assert not is_atari("Catch-v0")
    assert is_atari("BreakoutNoFrameskip-v4")
    assert observation_scale("Catch-v0") == 1.0
    assert observation_scale("PongNoFrameskip-v4") == pytest.approx(1 / 255)


def test_bad_frame_stack_is_rejected():
    with pytest.raises(ValueError, match="frame_stack"):
        make_env("Catch-v0", frame_stack=0)


def test_breakout_observations_and_fire_reset():
    env = make_env("BreakoutNoFrameskip-v4")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4, 84, 84) and obs.dtype == np.uint8
    assert find_wrapper(env, FireResetEnv) is not None
    assert find_wrapper(env, EpisodicLifeEnv) is None
    lives = env.unwrapped.ale.lives()
    for _ in range(2000):
        obs, reward, terminated, truncated, _ = env.step(0)  # never move: the ball is soon lost
        assert obs.shape == (4, 84, 84) and -1 <= reward <= 1
        if env.unwrapped.ale.lives() < lives:
            break
    # Without life loss as terminal, losing a life does not end the episode.
    assert env.unwrapped.ale.lives() == lives - 1 and not terminated


def test_rewards_are_clipped_but_the_recorded_score_is_raw():
    # Space Invaders scores 5 to 30 points an invader, so clipping shows at once.
    env = make_env("SpaceInvadersNoFrameskip-v4")
    env.reset(seed=0)
    rewards, score = [], None
    for _ in range(3000):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        rewards.append(reward)
        if terminated or truncated:
            score = info["episode"]["r"]
            break
    assert set(rewards) <= {0.0, 1.0} and max(rewards) == 1.0
    assert score is not None and score > sum(rewards)  # raw points, not clipped ones


def test_life_loss_as_terminal_continues_the_same_game():
    env = make_env("BreakoutNoFrameskip-v4", terminal_on_life_loss=True, noop_max=0)
    env.reset(seed=1)
    ale = env.unwrapped.ale
    assert ale.lives() == 5
    for _ in range(2000):
        _, _, terminated, _, _ = env.step(0)  # never move: the ball is soon lost
        if terminated:
            break
    assert terminated and ale.lives() == 4
    env.reset()
    assert ale.lives() == 4  # the game went on; it was not restarted
