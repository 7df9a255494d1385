"""The thesis's preprocessing: `catch_env.wrappers.make_env` for Catch and for ALE ids."""

import subprocess
import sys

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


def test_catch_vector_env_matches_a_same_step_sync_vector_env_of_make_env():
    """make_vector_env("Catch-v0", N): Catch's NumPy vector env under FrameStackVectorEnv, frame
    for frame what Gymnasium's SyncVectorEnv of make_env envs gives with same-step autoreset:
    observations, rewards, ends, the last observation and the statistics of ended episodes."""
    from gymnasium.vector import AutoresetMode, SyncVectorEnv

    from catch_env.wrappers import FrameStackVectorEnv, make_vector_env

    num_envs = 5
    ours = make_vector_env("Catch-v0", num_envs)
    assert isinstance(ours, FrameStackVectorEnv)
    assert ours.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    reference = SyncVectorEnv(
        [lambda: make_env("Catch-v0")] * num_envs, autoreset_mode=AutoresetMode.SAME_STEP
    )
    obs, _ = ours.reset(seed=3)
    expected, _ = reference.reset(seed=3)
    assert obs.shape == (num_envs, 4, 84, 84) and ours.single_observation_space.shape == (4, 84, 84)
    np.testing.assert_array_equal(obs, expected)
    rng = np.random.default_rng(0)
    ended_episodes = 0
    for _ in range(40):
        actions = rng.integers(0, 3, num_envs)
        obs, rewards, terminated, truncated, info = ours.step(actions)
        expected, ref_rewards, ref_terminated, ref_truncated, ref_info = reference.step(actions)
        np.testing.assert_array_equal(obs, expected)
        np.testing.assert_array_equal(rewards, ref_rewards)
        np.testing.assert_array_equal(terminated, ref_terminated)
        np.testing.assert_array_equal(truncated, ref_truncated)
        if terminated.any():
            ended = ref_info["_final_obs"]
            np.testing.assert_array_equal(info["_final_obs"], ended)
            mine, theirs = info["final_obs"][ended], ref_info["final_obs"][ended]
            np.testing.assert_array_equal(np.stack(mine), np.stack(theirs))
            for key in ("r", "l"):
                np.testing.assert_array_equal(
                    info["final_info"]["episode"][key][ended],
                    ref_info["final_info"]["episode"][key][ended],
                )
            ended_episodes += int(ended.sum())
        else:
            assert info == {}
    assert ended_episodes == 2 * num_envs  # episodes of 15 steps end at steps 15 and 30


def test_atari_vector_env_resets_ended_episodes_in_the_same_step():
    pytest.importorskip("ale_py")
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("BreakoutNoFrameskip-v4", 2, terminal_on_life_loss=True)
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (2, 4, 84, 84) and obs.dtype == np.uint8
    for _ in range(2000):
        obs, _, terminated, truncated, info = envs.step(np.array([0, 0]))  # NOOP: lives are lost
        if terminated.any():
            break
    assert terminated.any(), "no life lost in 2000 steps of NOOP"
    i = int(np.flatnonzero(terminated)[0])
    # the episode's last stack is kept; the returned one is the next episode's first
    assert info["final_obs"][i].shape == (4, 84, 84)
    assert all(np.array_equal(obs[i][0], frame) for frame in obs[i])
    envs.close()


def test_an_atari_env_prints_nothing_to_stderr():
    # ALE prints a banner at its Info log level for the first emulator of a process; a fresh
    # interpreter, because this one may have made an emulator already
    pytest.importorskip("ale_py")
    code = (
        "from catch_env.wrappers import make_env; make_env('BreakoutNoFrameskip-v4').reset(seed=0)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0 and done.stderr == "", done.stderr


@pytest.mark.parametrize("num_envs", [0, -1, 1.5, True])
def test_make_vector_env_rejects_a_bad_num_envs(num_envs):
    from catch_env.wrappers import make_vector_env

    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        make_vector_env("Catch-v0", num_envs)


def test_catch_vector_env_reset_mask_resets_only_those_envs():
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("Catch-v0", 3)
    envs.reset(seed=0)
    for _ in range(5):
        obs, *_ = envs.step(np.zeros(3, dtype=np.int64))
    before = obs.copy()
    obs, _ = envs.reset(options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(obs[[0, 2]], before[[0, 2]])  # untouched stacks
    assert all(np.array_equal(obs[1][0], frame) for frame in obs[1])  # a fresh, cleared stack
    assert not np.array_equal(obs[1], before[1])


def step_both(native, python, actions):
    """Step the native and the Python vector env with the same actions; assert the frames,
    rewards, ends and ended episodes' final observations and statistics are equal."""
    obs, rewards, terminated, truncated, info = native.step(actions)
    ref_obs, ref_rewards, ref_terminated, ref_truncated, ref_info = python.step(actions)
    largest = int(np.abs(obs.astype(np.int16) - ref_obs).max())
    np.testing.assert_array_equal(rewards, ref_rewards)
    np.testing.assert_array_equal(terminated, ref_terminated)
    np.testing.assert_array_equal(truncated, ref_truncated)
    ended = terminated | truncated
    if ended.any():
        np.testing.assert_array_equal(info["_final_obs"], ref_info["_final_obs"])
        for i in np.flatnonzero(ended):
            np.testing.assert_array_equal(info["final_obs"][i], ref_info["final_obs"][i])
        episodes = info["final_info"]["_episode"]
        np.testing.assert_array_equal(episodes, ref_info["final_info"]["_episode"])
        for key in ("r", "l"):
            np.testing.assert_array_equal(
                info["final_info"]["episode"][key][episodes],
                ref_info["final_info"]["episode"][key][episodes],
            )
    else:
        assert info == {}  # (the Python path's also holds each env's lives and frame numbers)
    return largest, int(ended.sum()), int(info["final_info"]["_episode"].sum()) if info else 0


@pytest.mark.slow
@pytest.mark.parametrize(
    ("env_id", "steps"), [("BreakoutNoFrameskip-v4", 1200), ("PongNoFrameskip-v4", 3600)]
)
def test_native_atari_vector_env_matches_the_python_path_frame_for_frame(env_id, steps):
    # Without the two random or differently timed parts (ALE's no-op draws, and FIRE on reset:
    # one frame natively, one 4-frame action in FireResetEnv), the two paths give the same
    # frames: the same emulator, the same max-pool and the same 84x84 resize.
    pytest.importorskip("ale_py")
    from catch_env.wrappers import AtariNativeVectorEnv, make_vector_env

    options = {"noop_max": 0, "fire_reset": False}
    native = make_vector_env(env_id, 3, **options)
    python = make_vector_env(env_id, 3, backend="python", **options)
    assert isinstance(native, AtariNativeVectorEnv)
    assert native.single_observation_space == python.single_observation_space
    assert native.single_action_space == python.single_action_space
    obs, _ = native.reset(seed=5)
    ref_obs, _ = python.reset(seed=5)
    np.testing.assert_array_equal(obs, ref_obs)  # the first frame, repeated
    rng = np.random.default_rng(0)
    largest, games = 0, 0
    for _ in range(steps):
        step = step_both(native, python, rng.integers(0, native.single_action_space.n, 3))
        largest, games = max(largest, step[0]), games + step[2]
    assert largest == 0
    assert games >= 2, "too few games ended to compare their final observations and scores"
    native.close()
    python.close()


def test_native_atari_vector_env_differences_are_the_stated_ones():
    pytest.importorskip("ale_py")
    from catch_env.wrappers import make_vector_env

    # FIRE on reset: one frame natively (ALE's episode frame number 1 after the reset), one
    # action of 4 frames in FireResetEnv; the games then run apart.
    native = make_vector_env("BreakoutNoFrameskip-v4", 1, noop_max=0)
    _, info = native.env.reset(seed=0)  # the C++ env's own info
    assert info["episode_frame_number"][0] == 1
    python = make_env("BreakoutNoFrameskip-v4", noop_max=0)
    python.reset(seed=0)
    assert python.unwrapped.ale.getEpisodeFrameNumber() == 4
    native.close()
    # terminal_on_life_loss: the native game goes on from the frame of the lost life (no
    # no-op action first); the stack is cleared and the game not reset.
    native = make_vector_env(
        "BreakoutNoFrameskip-v4", 1, noop_max=0, fire_reset=False, terminal_on_life_loss=True
    )
    obs, _ = native.reset(seed=0)
    for _ in range(2000):
        obs, _, terminated, _, info = native.step(np.array([1]))  # FIRE, then lose the ball
        if terminated.any():
            break
    assert terminated[0] and not info["final_info"]["_episode"][0]  # a life, not the game
    assert all(np.array_equal(obs[0][0], frame) for frame in obs[0])
    np.testing.assert_array_equal(info["final_obs"][0][-1], obs[0][-1])
    native.close()


def test_native_atari_vector_env_keeps_the_raw_score_and_clips_rewards():
    pytest.importorskip("ale_py")
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("PongNoFrameskip-v4", 2)
    envs.reset(seed=0)
    rewards, scores = [], []
    for _ in range(5000):
        _, reward, terminated, truncated, info = envs.step(np.zeros(2, dtype=np.int64))
        rewards.append(reward)
        if info:
            scores += list(info["final_info"]["episode"]["r"][info["final_info"]["_episode"]])
        if len(scores) >= 2:
            break
    assert set(np.unique(np.concatenate(rewards))) <= {-1.0, 0.0, 1.0}
    assert scores and all(score == -21.0 for score in scores)  # NOOP loses 0:21


def test_make_vector_env_rejects_a_bad_backend():
    from catch_env.wrappers import make_vector_env

    with pytest.raises(ValueError, match="backend must be 'native' or 'python'"):
        make_vector_env("BreakoutNoFrameskip-v4", 2, backend="cpp")


@pytest.mark.parametrize("seed", [0, 2**31 - 1, 2**32 - 1])
def test_native_atari_vector_env_takes_any_gymnasium_seed(seed):
    # the agents' process seeds fill 32 bits; ALE's seeds are C ints
    pytest.importorskip("ale_py")
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("BreakoutNoFrameskip-v4", 2)
    first, _ = envs.reset(seed=seed)
    first = first.copy()
    again, _ = envs.reset(seed=seed)
    np.testing.assert_array_equal(first, again)
    envs.close()


def test_native_atari_frames_are_the_python_paths_over_a_few_steps():
    """The fast tier's share of the frame-for-frame comparison (the slow tier plays 1,200 and
    3,600 steps): both paths max-pool the last two frames of each skip, so over 100 steps of
    Breakout, where the ball moves between them, their frames agree."""
    pytest.importorskip("ale_py")
    from catch_env.wrappers import make_vector_env

    options = {"noop_max": 0, "fire_reset": False}
    native = make_vector_env("BreakoutNoFrameskip-v4", 2, **options)
    python = make_vector_env("BreakoutNoFrameskip-v4", 2, backend="python", **options)
    native.reset(seed=5)
    python.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(100):
        largest = step_both(native, python, rng.integers(0, 4, 2))[0]
        assert largest == 0
    native.close()
    python.close()


@pytest.mark.parametrize("backend", ["native", "python"])
def test_a_lost_point_is_minus_one_after_clipping(backend):
    """Pong's rewards are -1 and +1 points: clipping to [-1, 1] keeps a lost point's -1 (a
    clip to [0, 1] would hide every loss from the agent)."""
    pytest.importorskip("ale_py")
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("PongNoFrameskip-v4", 2, backend=backend)
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    lowest = 0.0
    for _ in range(400):  # a random player loses its first point in well under 400 steps
        _, rewards, *_ = envs.step(rng.integers(0, 6, 2))
        lowest = min(lowest, float(rewards.min()))
        if lowest < 0:
            break
    envs.close()
    assert lowest == -1.0


@pytest.mark.parametrize("part", ["stack", "returns", "lengths"])
def test_the_frame_stacks_state_of_another_shape_is_refused(part):
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("Catch-v0", 3)  # Catch's vector env under FrameStackVectorEnv
    envs.reset(seed=4)
    state = envs.get_state()
    state[part] = np.asarray(state[part])[..., :-1]  # one column short
    with pytest.raises(ValueError, match=f"state '{part}' has shape"):
        envs.set_state(state)
