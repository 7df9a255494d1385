"""Catch-v0: the Gymnasium contract, the thesis's rules, seeding, pickling and the vector env."""

import io
import os
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import catch_env
import catch_env.catch as catch_module
from catch_env import CatchEnv, CatchRules, CatchVectorEnv

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

GRID, PADDLE_ROW, EPISODE_LENGTH = 24, 19, 15
# Pixel p of the 84x84 frame shows cell floor(p * 24 / 84): nearest-neighbour upscaling.
PIXEL_CELL = np.arange(84) * 24 // 84


def play(env: gym.Env, actions, seed: int):
    """Run one episode's worth of `actions`; return observations, rewards and terminations."""
    obs, _ = env.reset(seed=seed)
    trajectory = [(obs, 0.0, False)]
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        assert not truncated
        trajectory.append((obs, reward, terminated))
        if terminated:
            break
    return trajectory


def grid_image(ball_row: int, ball_col: int, paddle: int) -> np.ndarray:
    """The expected 24x24 grid image, drawn by hand from the state."""
    grid = np.zeros((GRID, GRID), dtype=np.uint8)
    grid[PADDLE_ROW, paddle - 2 : paddle + 3] = 255
    grid[ball_row, ball_col] = 255
    return grid


# --- Registration and the Gymnasium contract ----------------------------------------------


def test_make_in_fresh_interpreter_with_module_prefix():
    code = "import gymnasium as g; print(g.make('catch_env:Catch-v0').reset(seed=0)[0].shape)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "(84, 84)"


@pytest.mark.parametrize("obs_type", ["pixels", "grid"])
def test_env_checker_passes_without_warnings(obs_type):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(gym.make("Catch-v0", obs_type=obs_type).unwrapped)
    assert [str(w.message) for w in caught] == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="DISPLAY is X11's (Linux)")
@pytest.mark.parametrize("unwrapped", [True, False], ids=["unwrapped", "made"])
def test_env_checker_passes_without_a_display(monkeypatch, unwrapped):
    """On a machine without a display (no DISPLAY, no SDL_VIDEODRIVER: a CI runner, ssh) the
    checker's "human" env shows nothing and says so once, rather than fail with a traceback."""
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"):
        monkeypatch.delenv(name, raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gym.make("Catch-v0")
        check_env(env.unwrapped if unwrapped else env)
    said = [str(w.message) for w in caught if "unwrapped" not in str(w.message)]
    assert len(said) == 1 and 'render_mode="human" shows nothing here: no display' in said[0]


def test_human_render_without_pygame_shows_nothing_and_says_so(monkeypatch):
    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame raises ImportError
    env = gym.make("Catch-v0", render_mode="human")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env.reset(seed=0)
        assert env.step(0)[1] == 0.0 and env.render() is None
    assert len(caught) == 1 and 'pip install "catch-env[human]"' in str(caught[0].message)
    env.close()


def test_spaces_and_action_meanings():
    env = gym.make("Catch-v0")
    assert env.observation_space == gym.spaces.Box(0, 255, (84, 84), np.uint8)
    assert env.action_space == gym.spaces.Discrete(3)
    assert env.unwrapped.get_action_meanings() == ["NOOP", "LEFT", "RIGHT"]
    grid_env = gym.make("Catch-v0", obs_type="grid")
    assert grid_env.observation_space.shape == (24, 24)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"grid_size": 9}, r"grid_size must be in \[10, 84\]"),
        ({"grid_size": 24.0}, "grid_size must be an integer"),
        ({"paddle_width": 4}, "paddle_width must be odd"),
        ({"paddle_width": 25}, r"paddle_width must be in \[1, 24\]"),
        ({"paddle_speed": 0}, r"paddle_speed must be in \[1, 23\]"),
        ({"obs_type": "rgb"}, r"obs_type must be one of \('pixels', 'grid'\)"),
        ({"render_mode": "ansi"}, "render_mode must be None or one of"),
    ],
)
# gym.make warns about an unknown render_mode before the env raises our error
@pytest.mark.filterwarnings("ignore:.*not in the possible render_modes:UserWarning")
def test_invalid_kwargs_raise_at_make_time_naming_the_valid_range(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("Catch-v0", **kwargs)


# --- The thesis's rules, by hand -----------------------------------------------------------


def test_first_step_follows_the_rules_by_hand():
    env = CatchEnv(obs_type="grid")
    env.reset(seed=3)
    row, col, vx, paddle = env.ball_row, env.ball_col, env.ball_vx, env.paddle
    assert row == 4 and 0 <= col < GRID and -2 <= vx <= 2 and 2 <= paddle <= 21
    obs, *_ = env.step(2)  # RIGHT
    expected_col = col + vx
    if expected_col > 23:
        expected_col = 23 - (expected_col - 23)
    if expected_col < 0:
        expected_col = -expected_col
    expected_paddle = paddle + 2 if paddle + 2 <= 21 else paddle
    assert (env.ball_row, env.ball_col, env.paddle) == (5, expected_col, expected_paddle)
    np.testing.assert_array_equal(obs, grid_image(5, expected_col, expected_paddle))


def test_wall_bounce_reflects_and_flips_speed():
    rules = CatchRules()
    assert rules.move_ball(22, 2) == (22, -2)  # 24 -> 23 - (24 - 23)
    assert rules.move_ball(23, 1) == (22, -1)
    assert rules.move_ball(1, -2) == (1, 2)  # -1 -> 1
    assert rules.move_ball(0, -1) == (1, 1)
    assert rules.move_ball(10, 0) == (10, 0)
    # The NumPy form gives the same answers.
    col, vx = rules.move_ball(np.array([22, 23, 1, 0, 10]), np.array([2, 1, -2, -1, 0]))
    assert col.tolist() == [22, 22, 1, 1, 10] and vx.tolist() == [-2, -1, 2, 1, 0]


def test_paddle_moves_two_cells_and_never_leaves_the_grid():
    rules = CatchRules()
    assert rules.move_paddle(10, -1) == 8 and rules.move_paddle(10, 1) == 12
    assert rules.move_paddle(3, -1) == 3  # would cover column -1
    assert rules.move_paddle(20, 1) == 20  # would cover column 24
    assert rules.move_paddle(4, -1) == 2 and rules.move_paddle(19, 1) == 21


def test_start_states_are_uniform_over_their_ranges():
    """The three U[0, 1) draws, evenly spread: every ball column 0..23, every speed -2..2 and
    every paddle centre 2..21 comes up equally often."""
    u = (np.arange(24 * 5 * 20) + 0.5) / (24 * 5 * 20)
    ball_col, ball_vx, paddle = CatchRules().start_state(np.stack([u, u, u], axis=-1))
    assert np.bincount(ball_col).tolist() == [100] * 24
    assert np.bincount(ball_vx + 2).tolist() == [480] * 5
    assert np.bincount(paddle).tolist() == [0, 0] + [120] * 20


def test_pixels_are_the_grid_upscaled_crisply():
    pixel_env, grid_env = CatchEnv(), CatchEnv(obs_type="grid")
    for seed in range(5):
        for (pixels, *_), (grid, *_) in zip(
            play(pixel_env, [1, 2, 0] * 5, seed), play(grid_env, [1, 2, 0] * 5, seed), strict=True
        ):
            np.testing.assert_array_equal(pixels, grid[np.ix_(PIXEL_CELL, PIXEL_CELL)])
            assert set(np.unique(pixels)) <= {0, 255}


def test_random_policy_catches_about_one_ball_in_five():
    env = gym.make("Catch-v0", obs_type="grid")
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    catches = 0
    for _ in range(2000):
        for _ in range(EPISODE_LENGTH):
            _, reward, terminated, _, _ = env.step(int(rng.integers(3)))
        assert terminated
        catches += reward
        env.reset()
    assert 0.17 < catches / 2000 < 0.23


# --- Invariants over random seeds and actions (hypothesis) ---------------------------------


@settings(max_examples=150, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    actions=st.lists(st.integers(0, 2), min_size=EPISODE_LENGTH, max_size=EPISODE_LENGTH),
    obs_type=st.sampled_from(["pixels", "grid"]),
)
def test_invariants(seed, actions, obs_type):
    env = CatchEnv(obs_type=obs_type)
    obs, _ = env.reset(seed=seed)
    for step, action in enumerate(actions, start=1):
        obs, reward, terminated, truncated, _ = env.step(action)
        # Ball and paddle stay on the grid; the ball falls one row per step.
        assert 0 <= env.ball_col < GRID and env.ball_row == 4 + step
        assert 2 <= env.paddle <= 21
        # The observation shows exactly the ball and paddle cells.
        expected = grid_image(env.ball_row, env.ball_col, env.paddle)
        if obs_type == "pixels":
            expected = expected[np.ix_(PIXEL_CELL, PIXEL_CELL)]
        np.testing.assert_array_equal(obs, expected)
        # Episodes last 15 steps; reward 1 exactly at a termination with the ball on the paddle.
        assert terminated == (step == EPISODE_LENGTH) and not truncated
        caught = terminated and abs(env.ball_col - env.paddle) <= 2
        assert reward == (1.0 if caught else 0.0)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)


# --- Bad input -----------------------------------------------------------------------------


@pytest.mark.parametrize("action", [3, -1, 1.0, "1", None, True, np.array([1]), np.array(1.0)])
def test_invalid_action_names_the_valid_actions_and_keeps_the_state(action):
    env = CatchEnv()
    obs, _ = env.reset(seed=0)
    state = (env.ball_row, env.ball_col, env.ball_vx, env.paddle)
    with pytest.raises(ValueError, match="0 NOOP, 1 LEFT, 2 RIGHT"):
        env.step(action)
    assert (env.ball_row, env.ball_col, env.ball_vx, env.paddle) == state
    # The game goes on exactly as if the bad call never happened.
    reference = CatchEnv()
    reference.reset(seed=0)
    np.testing.assert_array_equal(env.step(1)[0], reference.step(1)[0])


def test_numpy_integer_actions_are_accepted():
    """A numpy integer or 0-d array is the action it holds: the same game as Python ints."""
    env, reference = CatchEnv(), CatchEnv()
    env.reset(seed=0)
    reference.reset(seed=0)
    for action, same in ((np.int64(0), 0), (np.array(2), 2), (np.int8(1), 1)):
        np.testing.assert_array_equal(env.step(action)[0], reference.step(same)[0])
    assert env.paddle == reference.paddle


def test_step_before_reset_raises():
    with pytest.raises(RuntimeError, match="reset"):
        CatchEnv().step(0)


# --- Seeding, pickling, rendering ----------------------------------------------------------


def test_same_seed_same_actions_same_trajectory():
    actions = [0, 1, 2, 2, 1, 0, 1, 1, 2, 0, 0, 2, 1, 2, 0]
    first, second = play(CatchEnv(), actions, 42), play(CatchEnv(), actions, 42)
    for (obs_a, r_a, t_a), (obs_b, r_b, t_b) in zip(first, second, strict=True):
        np.testing.assert_array_equal(obs_a, obs_b)
        assert (r_a, t_a) == (r_b, t_b)
    starts = {tuple(play(CatchEnv(), [], s)[0][0].ravel().nonzero()[0][:3]) for s in range(20)}
    assert len(starts) > 10  # different seeds give different games


def test_reset_follows_the_np_random_convention():
    env = CatchEnv()
    env.reset(seed=7)
    assert env.np_random_seed == 7
    first_game = (env.ball_col, env.ball_vx, env.paddle)
    env.reset()  # no seed: the generator goes on, it is not reseeded
    env.reset(seed=7)
    assert (env.ball_col, env.ball_vx, env.paddle) == first_game


@pytest.mark.parametrize("render_mode", [None, "rgb_array", "human"])
def test_pickle_round_trip_continues_the_same_game(render_mode):
    env = CatchEnv(render_mode=render_mode)
    env.reset(seed=5)
    env.step(1)
    if render_mode is not None:
        env.render()
    clone = pickle.loads(pickle.dumps(env))
    for action in [2, 2, 0, 1]:
        obs_a, r_a, t_a, *_ = env.step(action)
        obs_b, r_b, t_b, *_ = clone.step(action)
        np.testing.assert_array_equal(obs_a, obs_b)
        assert (r_a, t_a) == (r_b, t_b)
    if render_mode is not None:
        clone.render()
    env.close()
    clone.close()


def test_rgb_array_render_is_the_frame_in_three_channels():
    env = gym.make("Catch-v0", render_mode="rgb_array")
    obs, _ = env.reset(seed=1)
    frame = env.render()
    assert frame.shape == (84, 84, 3) and frame.dtype == np.uint8
    for channel in range(3):
        np.testing.assert_array_equal(frame[:, :, channel], obs)
    grid_env = gym.make("Catch-v0", render_mode="rgb_array", obs_type="grid")
    grid_env.reset(seed=1)
    np.testing.assert_array_equal(grid_env.render(), frame)


def test_human_render_opens_lazily_and_close_releases_it():
    env = gym.make("Catch-v0", render_mode="human")
    assert env.unwrapped._window is None
    env.reset(seed=0)
    assert env.unwrapped._window is not None
    env.step(0)
    env.close()
    assert env.unwrapped._window is None


# --- The vector env ------------------------------------------------------------------------


def test_make_vec_uses_the_numpy_vector_env():
    envs = gym.make_vec("Catch-v0", num_envs=4)
    assert isinstance(envs.unwrapped, CatchVectorEnv)
    assert envs.observation_space.shape == (4, 84, 84)
    assert envs.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP


@pytest.mark.parametrize("obs_type", ["pixels", "grid"])
def test_vector_env_equals_sync_vector_env_of_single_envs(obs_type):
    n, steps = 5, 70  # several episodes, crossing autoresets
    vector = gym.make_vec("Catch-v0", num_envs=n, obs_type=obs_type)
    sync = gym.make_vec("Catch-v0", num_envs=n, vectorization_mode="sync", obs_type=obs_type)
    rng = np.random.default_rng(0)
    obs_v, _ = vector.reset(seed=123)
    obs_s, _ = sync.reset(seed=123)
    np.testing.assert_array_equal(obs_v, obs_s)
    for step in range(steps):
        if step == 40:  # reseeding mid-run and resetting part-way through an episode
            obs_v, _ = vector.reset(seed=9)
            obs_s, _ = sync.reset(seed=9)
            np.testing.assert_array_equal(obs_v, obs_s)
        actions = rng.integers(0, 3, n)
        out_v, out_s = vector.step(actions), sync.step(actions)
        for got, expected in zip(out_v[:4], out_s[:4], strict=True):
            np.testing.assert_array_equal(got, expected)
    # An unseeded reset continues every env's own generator, as N single envs would.
    np.testing.assert_array_equal(vector.reset()[0], sync.reset()[0])


def test_vector_env_rewards_only_the_games_that_end():
    """Games at different rows (reset at different steps): a step rewards 1 exactly where a game
    ends with its ball within paddle_width // 2 of the paddle's centre, never a game whose ball
    is over the paddle higher up."""
    envs = CatchVectorEnv(num_envs=8, obs_type="grid")
    envs.reset(seed=0)
    rng = np.random.default_rng(0)
    over_the_paddle_early = 0
    for step in range(1, 60):
        if step < 8:  # game i starts at step i
            envs.reset(options={"reset_mask": np.arange(8) == step})
        _, rewards, terminated, _, _ = envs.step(rng.integers(0, 3, 8))
        over = np.abs(envs.ball_col - envs.paddle) <= 2
        np.testing.assert_array_equal(rewards, (terminated & over).astype(np.float32))
        if terminated.any():
            over_the_paddle_early += int((over & ~terminated).sum())
    assert over_the_paddle_early > 0  # the case this test is about came up


def test_vector_env_copy_false_returns_its_buffer():
    envs = CatchVectorEnv(num_envs=3, copy=False)
    first, _ = envs.reset(seed=0)
    second, *_ = envs.step(np.zeros(3, dtype=np.int64))
    assert first is second
    copied = CatchVectorEnv(num_envs=3)
    assert copied.reset(seed=0)[0] is not copied.step(np.zeros(3, dtype=np.int64))[0]


def test_vector_env_reset_mask_resets_only_those_envs():
    envs = CatchVectorEnv(num_envs=3, obs_type="grid")
    envs.reset(seed=0)
    for _ in range(5):
        envs.step(np.zeros(3, dtype=np.int64))
    envs.reset(options={"reset_mask": np.array([False, True, False])})
    assert envs.ball_row.tolist() == [9, 4, 9]


@pytest.mark.parametrize(
    "actions", [np.array([0, 1]), np.array([0, 1, 3]), np.array([0.0, 1.0, 2.0]), [[0, 1, 2]]]
)
def test_vector_env_invalid_actions_raise_and_keep_the_state(actions):
    envs = CatchVectorEnv(num_envs=3)
    obs, _ = envs.reset(seed=0)
    before = (envs.ball_row.copy(), envs.ball_col.copy(), envs.paddle.copy(), obs.copy())
    with pytest.raises(ValueError, match="0 NOOP, 1 LEFT, 2 RIGHT"):
        envs.step(actions)
    after = (envs.ball_row, envs.ball_col, envs.paddle, envs._obs)
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a, b)


def test_vector_env_pickles_mid_episode():
    envs = CatchVectorEnv(num_envs=4)
    envs.reset(seed=1)
    envs.step(np.array([1, 2, 0, 1]))
    clone = pickle.loads(pickle.dumps(envs))
    actions = np.array([2, 2, 1, 0])
    np.testing.assert_array_equal(envs.step(actions)[0], clone.step(actions)[0])


@pytest.mark.parametrize(
    "seed", [5, np.int64(5), np.int32(5), [5, 6, 7, 8], (5, 6, 7, 8), np.arange(5, 9)]
)
def test_vector_env_seeds_as_gymnasiums_vector_envs_do(seed):
    """An integer seed s (a NumPy one too) seeds env i with s + i; a sequence, one per env."""
    expected, _ = gym.make_vec("Catch-v0", num_envs=4, vectorization_mode="sync").reset(seed=5)
    obs, _ = gym.make_vec("Catch-v0", num_envs=4).reset(seed=seed)
    np.testing.assert_array_equal(obs, expected)


@pytest.mark.parametrize(
    ("seed", "error", "message"),
    [
        (5.0, gym.error.Error, "Seed must be a python integer, actual type: <class 'float'>"),
        ("5", gym.error.Error, "Seed must be a python integer, actual type: <class 'str'>"),
        (-1, gym.error.Error, "Seed must be greater or equal to zero, actual value: -1"),
        ([1, 2, 3], ValueError, "the length must match num_envs=4 but got length=3"),
        ([1, 2, 3, 4.0], gym.error.Error, "Seed must be a python integer"),
    ],
)
def test_vector_env_refuses_a_bad_seed_as_gymnasium_does(seed, error, message):
    envs = gym.make_vec("Catch-v0", num_envs=4)
    with pytest.raises(error) as raised:
        envs.reset(seed=seed)
    assert message in str(raised.value)
    if isinstance(seed, float):  # the single env's own message, word for word
        with pytest.raises(error) as single:
            gym.make("Catch-v0").reset(seed=seed)
        assert str(single.value) == str(raised.value)


def test_vector_env_beyond_memory_is_one_clear_error():
    """2**24 envs need some 900 GiB: refused before anything is allocated, in one line."""
    with pytest.raises(MemoryError) as error:
        gym.make_vec("Catch-v0", num_envs=2**24)
    message = str(error.value)
    assert message.startswith("num_envs=16777216 needs about ") and "of memory available" in message
    assert "\n" not in message


@pytest.mark.parametrize(("obs_type", "side"), [("pixels", 84), ("grid", 24)])
def test_the_memory_estimate_counts_the_frames_and_the_start_buffer(monkeypatch, obs_type, side):
    """Per env: its frames (side x side bytes each) and its start buffer (3 int64 per start)."""
    monkeypatch.setattr(catch_module, "available_memory", lambda: 1000)
    per_env = catch_module.VECTOR_FRAMES_PER_ENV * side**2 + 4096 * 3 * 8
    with pytest.raises(MemoryError) as error:
        CatchVectorEnv(num_envs=3, obs_type=obs_type, start_buffer=4096)
    sizes = f"about {catch_module.format_bytes(3 * per_env)} "
    sizes += f"({catch_module.format_bytes(per_env)} per env)"
    assert sizes in str(error.value), (sizes, str(error.value))


def test_package_exports():
    assert catch_env.ACTION_MEANINGS == ("NOOP", "LEFT", "RIGHT")


@pytest.mark.parametrize("name", ["ball_col", "_starts"])
def test_the_vector_envs_state_with_an_array_of_another_shape_is_refused_unchanged(name):
    """set_state checks each array's shape against its own, not only the number of envs."""
    envs = gym.make_vec("Catch-v0", num_envs=3).unwrapped
    envs.reset(seed=4)
    before = envs.get_state()
    state = envs.get_state()
    state[name] = state[name][..., :-1]  # the same envs, one array a column short
    with pytest.raises(ValueError, match=f"state '{name}' has shape"):
        envs.set_state(state)
    after = envs.get_state()
    for key in CatchVectorEnv._STATE_ARRAYS:
        assert np.array_equal(before[key], after[key]), key
    assert before["rngs"] == after["rngs"]


def test_the_vector_envs_state_goes_on_where_it_was_taken_its_canvas_drawn_from_it():
    """An env set to another's state shows its frame and then steps as it does: the canvas,
    which the state leaves out, is drawn from the balls and paddles (what the env itself drew
    before is erased)."""
    source, target = (gym.make_vec("Catch-v0", num_envs=3).unwrapped for _ in range(2))
    source.reset(seed=1)
    target.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(7):
        source.step(rng.integers(0, 3, 3))
        target.step(rng.integers(0, 3, 3))
    target.set_state(source.get_state())
    assert np.array_equal(target._obs, source._obs)
    for _ in range(40):
        actions = rng.integers(0, 3, 3)
        for mine, theirs in zip(target.step(actions)[:4], source.step(actions)[:4], strict=True):
            assert np.array_equal(mine, theirs)


@pytest.mark.parametrize(
    ("meminfo_kib", "limit", "used", "expected"),
    [
        (8 << 20, "max", 1 << 30, 8 << 30),  # no container limit: MemAvailable
        (8 << 20, str(3 << 30), 1 << 30, 2 << 30),  # the limit less what the cgroup uses
        (1 << 20, str(3 << 30), 1 << 30, 1 << 30),  # whichever is lower
        (8 << 20, str(1 << 30), 2 << 30, 0),  # over its limit: no room, never negative
    ],
)
def test_available_memory_is_the_lower_of_the_machines_and_the_containers(
    monkeypatch, meminfo_kib, limit, used, expected
):
    files = {
        "/proc/meminfo": f"MemTotal: {16 << 20} kB\nMemAvailable: {meminfo_kib} kB\n",
        "/sys/fs/cgroup/memory.max": f"{limit}\n",
        "/sys/fs/cgroup/memory.current": f"{used}\n",
    }
    monkeypatch.setattr(catch_module, "open", lambda path: io.StringIO(files[path]), raising=False)
    assert catch_module.available_memory() == expected
