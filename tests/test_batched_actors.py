"""--envs-per-worker K: each worker steps K envs, acts on all K with one batched forward and learns
from the K x t_max rollout in one update. Against hand-computed values: the n-step returns of K
envs (episodes ending mid-rollout or not), the batched loss as the sum of the per-env losses, the
LSTM's per-env resets; and every script end to end with K = 4 on Catch-v0 and on Breakout."""

import numpy as np
import pytest
import torch
from conftest import ALL_SCRIPTS, SCRIPTS, load_script, main_exit, shared_for, tiny_args
from hypothesis import given, settings
from hypothesis import strategies as st


@pytest.fixture(scope="module")
def a3c():
    return load_script("a3c_ff")


def test_n_step_returns_of_k_envs_with_an_episode_ending_mid_rollout(a3c):
    gamma = 0.5
    # env 0: its episode terminates at step 1 and the next one starts at step 2;
    # env 1: no episode ends; env 2: a time limit cuts its episode at step 0 (V(s_last) = 6)
    rewards = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 2.0], [2.0, 0.0, 0.0]], dtype=np.float32)
    dones = np.array([[False, False, True], [True, False, False], [False, False, False]])
    done_values = np.array([[0, 0, 6.0], [0, 0, 0], [0, 0, 0]], dtype=np.float32)
    bootstrap = np.array([4.0, 8.0, 2.0], dtype=np.float32)  # V(s_3) of each env
    returns = a3c.n_step_returns(rewards, dones, done_values, bootstrap, gamma)
    # env 0: G2 = 2 + 0.5 * 4 = 4 (the new episode); G1 = 0 + 0.5 * 0 = 0 (terminal);
    #        G0 = 1 + 0.5 * G1 = 1: nothing of the next episode leaks back
    # env 1: G2 = 0 + 0.5 * 8 = 4, G1 = 1 + 0.5 * 4 = 3, G0 = 0 + 0.5 * 3 = 1.5
    # env 2: G2 = 0 + 0.5 * 2 = 1, G1 = 2 + 0.5 * 1 = 2.5, G0 = 0 + 0.5 * 6 = 3 (truncated)
    expected = [[1.0, 1.5, 3.0], [0.0, 3.0, 2.5], [4.0, 4.0, 1.0]]
    np.testing.assert_allclose(returns, expected)
    assert returns.dtype == np.float32


def test_n_step_returns_of_one_env_are_the_thesis_s(a3c):
    """K = 1: G_i = r_i + gamma G_{i+1} from V(s_n), or from 0 after a terminal state."""
    rewards = np.array([[1.0], [0.0], [2.0]], dtype=np.float32)
    no_dones = np.zeros((3, 1), dtype=bool)
    zeros = np.zeros((3, 1), dtype=np.float32)
    returns = a3c.n_step_returns(rewards, no_dones, zeros, np.array([4.0]), 0.5)
    np.testing.assert_allclose(returns[:, 0], [2.0, 2.0, 4.0])
    terminal = no_dones.copy()
    terminal[2] = True
    returns = a3c.n_step_returns(rewards, terminal, zeros, np.array([4.0]), 0.5)
    np.testing.assert_allclose(returns[:, 0], [1.5, 1.0, 2.0])


def where_returns(rewards, dones, done_values, bootstrap, gamma):
    """The returns as the scripts computed them before they took tensors too (np.where)."""
    returns, g = np.empty_like(rewards), bootstrap
    for t in range(len(rewards) - 1, -1, -1):
        g = rewards[t] + gamma * np.where(dones[t], done_values[t], g)
        returns[t] = g
    return returns


@settings(max_examples=60, deadline=None)
@given(
    shape=st.tuples(st.integers(1, 6), st.integers(1, 5)),
    seed=st.integers(0, 2**32 - 1),
    gamma=st.floats(0.0, 1.0),
)
def test_n_step_returns_of_arrays_and_tensors_are_np_where_s_bit_for_bit(shape, seed, gamma):
    """The scripts' sum-of-products choice gives np.where's returns exactly, on NumPy arrays
    (a worker's) and on tensors (the batched backend's, on its device)."""
    a3c = load_script("a3c_ff")
    rng = np.random.default_rng(seed)
    rewards = rng.normal(size=shape).astype(np.float32)
    dones = rng.random(shape) < 0.3
    done_values = (rng.normal(size=shape) * (rng.random(shape) < 0.5)).astype(np.float32)
    bootstrap = rng.normal(size=shape[1]).astype(np.float32)
    expected = where_returns(rewards, dones, done_values, bootstrap, gamma)
    arrays = a3c.n_step_returns(rewards, dones, done_values, bootstrap, gamma)
    assert arrays.dtype == np.float32 and np.array_equal(arrays, expected)
    tensors = a3c.n_step_returns(*map(torch.as_tensor, (rewards, dones, done_values, bootstrap)),
                                 gamma)  # fmt: skip
    assert tensors.dtype == torch.float32 and np.array_equal(tensors.numpy(), expected)


@pytest.mark.parametrize("name", ["a3c_ff", "a3c_glpq"])
def test_the_batched_loss_is_the_sum_of_the_per_env_losses(name):
    """One forward over the n x K states (step-major, as the worker's buffer) gives the sum of
    the K envs' own losses, and the same gradients."""
    module = load_script(name)
    torch.manual_seed(0)
    args = tiny_args(module)
    model = module.AGENT.build_network(3, args)
    params = list(model.parameters())
    steps, envs = 5, 3
    obs = torch.randint(0, 256, (steps, envs, 4, 84, 84), dtype=torch.uint8)
    actions = torch.randint(0, 3, (steps, envs))
    returns = torch.randn(steps, envs)

    log_probs, values = model(obs.flatten(0, 1))
    batched = module.a3c_loss(log_probs, actions.flatten(), values, returns.flatten(), 0.01, 0.5)
    batched_grads = torch.autograd.grad(batched[0], params)

    per_env = []
    for k in range(envs):
        log_probs, values = model(obs[:, k])
        per_env.append(module.a3c_loss(log_probs, actions[:, k], values, returns[:, k], 0.01, 0.5))
    for batched_term, *env_terms in zip(batched, *per_env, strict=True):
        torch.testing.assert_close(batched_term, sum(env_terms), rtol=1e-5, atol=1e-5)
    summed_grads = torch.autograd.grad(sum(loss[0] for loss in per_env), params)
    for batched_grad, summed_grad in zip(batched_grads, summed_grads, strict=True):
        # float32 sums in another order (Catch's frames are unscaled: large gradients)
        scale = float(summed_grad.abs().max())
        torch.testing.assert_close(batched_grad, summed_grad, rtol=1e-3, atol=1e-4 * scale)


@pytest.mark.parametrize("name", ALL_SCRIPTS)
def test_sample_actions_inverse_cdf_per_row(name):
    """Every script's own copy of sample_actions, on K rows and on one (K = 1)."""
    a3c = load_script(name)
    assert a3c.sample_actions(np.array([[0.2, 0.3, 0.5]]), np.array([0.9])).tolist() == [2]
    probs = np.array([[0.2, 0.3, 0.5]] * 6)
    uniforms = np.array([0.0, 0.19, 0.21, 0.49, 0.51, 0.999])
    assert a3c.sample_actions(probs, uniforms).tolist() == [0, 0, 1, 1, 2, 2]
    rows = np.array([[0.0, 1.0, 0.0], [0.5, 0.5, 0.0], [1.0, 0.0, 0.0]])
    # never an action of probability 0, whatever u
    assert a3c.sample_actions(rows, np.array([0.0, 0.9999999999, 0.9999999999])).tolist() == [
        1, 1, 0,
    ]  # fmt: skip


def test_sample_actions_follow_the_probabilities(a3c):
    rng = np.random.default_rng(0)
    probs = np.array([[0.1, 0.6, 0.3], [0.7, 0.0, 0.3]])
    counts = np.zeros((2, 3))
    for _ in range(20_000):
        actions = a3c.sample_actions(probs, rng.random(2))
        counts[[0, 1], actions] += 1
    np.testing.assert_allclose(counts / 20_000, probs, atol=0.015)
    assert counts[1, 1] == 0


@pytest.mark.parametrize("start", [1, 2])  # 1: the rollout's second step
def test_lstm_episode_starts_restart_each_env_from_the_zero_state(start):
    """A replay over two envs where env 0's episode starts anew at step `start` gives, for env 0
    from that step on, what a fresh replay of those steps from zeros gives, and leaves env 1
    alone."""
    lstm = load_script("a3c_lstm")
    torch.manual_seed(3)
    net = lstm.ActorCritic(3, lstm.Args())
    obs = torch.randint(0, 256, (4, 2, 4, 84, 84), dtype=torch.uint8)
    state = (torch.randn(2, 256), torch.randn(2, 256))
    starts = torch.zeros(4, 2, dtype=torch.bool)
    starts[start, 0] = True
    log_probs, values, _ = net(obs, state, starts)
    fresh_log_probs, fresh_values, _ = net(obs[start:, :1], net.initial_state(1))
    torch.testing.assert_close(log_probs[start:, 0], fresh_log_probs[:, 0], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(values[start:, 0], fresh_values[:, 0], rtol=1e-4, atol=1e-5)
    plain_log_probs, _, _ = net(obs, state)
    torch.testing.assert_close(log_probs[:, 1], plain_log_probs[:, 1])  # env 1 unchanged
    torch.testing.assert_close(log_probs[:start, 0], plain_log_probs[:start, 0])  # before it
    assert not torch.allclose(log_probs[start:, 0], plain_log_probs[start:, 0])


@pytest.mark.parametrize("name", SCRIPTS)
def test_worker_with_k_envs_ends_a_rollout_where_every_episode_ends(name, one_thread):
    """t_max 8 against Catch's 15-step episodes, which end together in the K envs: rollouts of
    8 steps that bootstrap from V(s_8), then of 7 that end with every episode (as the thesis's
    K = 1 rollout ends with its episode): 3 x (8 + 7 + 8 + 7 + 8) = 114 steps from 96 asked."""
    module = load_script(name)
    args = tiny_args(module, total_timesteps=96, t_max=8, envs_per_worker=3)
    shared = shared_for(module, args)
    module.worker(0, shared, args)
    assert shared.global_step() == 114
    stats = shared.stats[0]
    assert torch.isfinite(stats).all()
    assert stats[3] == 5  # updates
    assert stats[0] == 3 * 2  # 38 steps per env: its episodes end at steps 15 and 30


def test_bad_envs_per_worker_exits_2_in_one_line(tmp_path, monkeypatch, capsys):
    argv = ["--envs-per-worker", "0", "--run-dir", str(tmp_path / "run")]
    code, err = main_exit(load_script("a3c_ff"), argv, monkeypatch, capsys)
    assert code == 2
    assert err.strip() == "error: --envs-per-worker must be >= 1 (got 0)"
    assert not (tmp_path / "run").exists()
