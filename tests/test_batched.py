"""The batched backend (a3c_tools.batched) and its torch Catch (a3c_tools.torch_catch): the
torch env against catch_env's NumPy env game for game, and run i of the batched backend against
the script's own one-worker run with the same seed and flags, action for action and parameter
for parameter."""

import numpy as np
import pytest
import torch
from a3c_tools.torch_catch import NumpyStateView, TorchCatchVectorEnv
from hypothesis import given, settings
from hypothesis import strategies as st

from catch_env.wrappers import make_vector_env


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """One thread, as a worker's torch: small ops on a shared 2-core machine run fastest so."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# --- Catch-v0 in torch against catch_env's NumPy env -------------------------------------------


def play_both(seeds: list[int], steps: int, action_seed: int) -> None:
    """Step the torch env and the NumPy env (make_vector_env, as the scripts' workers make it)
    with the same seeds and random actions; every observation, reward, termination, final
    observation and episode statistic is the same."""
    numpy_envs = make_vector_env("Catch-v0", len(seeds))
    torch_envs = TorchCatchVectorEnv(len(seeds))
    obs, _ = numpy_envs.reset(seed=seeds)
    np.testing.assert_array_equal(torch_envs.reset(seed=seeds).numpy(), obs)
    rng = np.random.default_rng(action_seed)
    episodes = 0
    for _ in range(steps):
        actions = rng.integers(3, size=len(seeds))
        obs, rewards, terminated, truncated, info = numpy_envs.step(actions)
        t_obs, t_rewards, t_terminated, ended = torch_envs.step(torch.from_numpy(actions))
        np.testing.assert_array_equal(t_obs.numpy(), obs)
        np.testing.assert_array_equal(t_rewards.numpy(), rewards)
        np.testing.assert_array_equal(t_terminated.numpy(), terminated)
        np.testing.assert_array_equal(ended, terminated | truncated)
        if ended.any():
            episodes += int(ended.sum())
            for i in np.flatnonzero(ended):
                np.testing.assert_array_equal(torch_envs.final_obs[i].numpy(), info["final_obs"][i])
            episode = info["final_info"]["episode"]
            np.testing.assert_array_equal(
                torch_envs.final_returns.numpy()[ended], episode["r"][ended]
            )
            np.testing.assert_array_equal(
                torch_envs.final_lengths.numpy()[ended], episode["l"][ended]
            )
    assert episodes == len(seeds) * (steps // 15)


def test_torch_catch_plays_the_numpy_games_over_many_episodes():
    """8 games, 70 episodes each (more than one block of 64 start states per game)."""
    play_both([3, 1_000_003, 7, 2**31 - 1, 0, 42, 99, 12_345], 70 * 15, action_seed=0)


@settings(max_examples=15, deadline=None)
@given(
    seeds=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=5),
    episodes=st.integers(1, 5),
    action_seed=st.integers(0, 2**16),
)
def test_torch_catch_equals_the_numpy_env_for_any_seeds_and_actions(seeds, episodes, action_seed):
    play_both(seeds, episodes * 15 + 7, action_seed)


def test_a_torch_games_numpy_state_continues_in_the_numpy_env():
    """numpy_state(i) is game i as the script's one-game env holds it: set into a NumPy env, it
    plays on as the torch game does (frames, rewards, new games' start states); and
    set_numpy_state reads it back."""
    torch_envs = TorchCatchVectorEnv(3)
    torch_envs.reset(seed=[5, 6, 7])
    rng = np.random.default_rng(1)
    for _ in range(20):  # mid-episode, after an episode ended
        torch_envs.step(torch.from_numpy(rng.integers(3, size=3)))
    numpy_env = make_vector_env("Catch-v0", 1)
    numpy_env.reset(seed=0)
    numpy_env.set_state(NumpyStateView(torch_envs, 1).get_state())
    copy = TorchCatchVectorEnv(1)
    copy.reset(seed=0)
    copy.set_numpy_state(0, torch_envs.numpy_state(1))
    for _ in range(100):
        actions = rng.integers(3, size=3)
        t_obs, t_rewards, _, _ = torch_envs.step(torch.from_numpy(actions))
        obs, rewards, *_ = numpy_env.step(actions[1:2])
        c_obs, c_rewards, _, _ = copy.step(torch.from_numpy(actions[1:2]))
        np.testing.assert_array_equal(t_obs[1].numpy(), obs[0])
        np.testing.assert_array_equal(c_obs[0].numpy(), obs[0])
        assert t_rewards[1] == rewards[0] == c_rewards[0]
