"""Unit tests of agents/a3c_ff.py: n-step returns, loss, clipping, the shared optimizers, init,
checkpoints and error reporting, against hand-computed values."""

import importlib.util
import math
import multiprocessing
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

SCRIPT = Path(__file__).resolve().parents[1] / "agents" / "a3c_ff.py"


@pytest.fixture(scope="module")
def a3c():
    spec = importlib.util.spec_from_file_location("a3c_ff", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["a3c_ff"] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def test_n_step_returns_bootstrap_and_terminal(a3c):
    rewards = np.array([1.0, 0.0, 2.0], dtype=np.float32)
    # G2 = 2 + 0.5 * 4 = 4, G1 = 0 + 0.5 * 4 = 2, G0 = 1 + 0.5 * 2 = 2
    np.testing.assert_allclose(a3c.n_step_returns(rewards, 4.0, 0.5), [2.0, 2.0, 4.0])
    # terminal: G2 = 2, G1 = 1, G0 = 1.5
    np.testing.assert_allclose(a3c.n_step_returns(rewards, 0.0, 0.5), [1.5, 1.0, 2.0])


def test_sample_action_inverse_cdf(a3c):
    probs = [0.2, 0.3, 0.5]
    assert [a3c.sample_action(probs, u) for u in (0.0, 0.19, 0.21, 0.49, 0.51, 0.999)] == [
        0, 0, 1, 1, 2, 2,
    ]  # fmt: skip
    assert a3c.sample_action([0.0, 1.0, 0.0], 0.0) == 1  # never an action of probability 0
    assert a3c.sample_action([0.5, 0.5], 0.9999999999) == 1


def test_a3c_loss_matches_hand_computation(a3c):
    log_probs = torch.tensor([[0.5, 0.5], [0.25, 0.75]]).log().requires_grad_()
    values = torch.tensor([1.0, 2.0], requires_grad=True)
    returns = torch.tensor([2.0, 1.0])
    actions = torch.tensor([0, 1])
    loss, policy_loss, value_loss, entropy = a3c.a3c_loss(
        log_probs, actions, values, returns, ent_coef=0.01, vf_coef=0.5
    )
    # advantages [1, -1]; policy = -(ln 0.5 * 1 + ln 0.75 * -1)
    expected_policy = -(math.log(0.5) - math.log(0.75))
    expected_entropy = math.log(2) - (0.25 * math.log(0.25) + 0.75 * math.log(0.75))
    expected_value = 0.5 * (1.0 + 1.0)
    assert policy_loss.item() == pytest.approx(expected_policy, rel=1e-6)
    assert entropy.item() == pytest.approx(expected_entropy, rel=1e-6)
    assert value_loss.item() == pytest.approx(expected_value, rel=1e-6)
    expected = expected_policy - 0.01 * expected_entropy + 0.5 * expected_value
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    loss.backward()
    # the advantage is not back-propagated: dL/dV = lambda_V * (V - G) only
    np.testing.assert_allclose(values.grad.numpy(), [-0.5, 0.5], rtol=1e-6)


def test_clip_gradients_modes(a3c):
    def grads():
        return [torch.tensor([30.0, 40.0]), torch.tensor([3.0, -50.0])]

    g = grads()
    norm = a3c.clip_gradients(g, "norm", 40.0)  # per tensor: [30, 40] has norm 50 -> x0.8
    assert norm == pytest.approx(math.sqrt(50**2 + 9 + 2500))
    np.testing.assert_allclose(g[0].numpy(), [24.0, 32.0], rtol=1e-5)
    np.testing.assert_allclose(g[1].numpy(), np.array([3.0, -50.0]) * 40 / math.sqrt(2509))
    g = grads()
    a3c.clip_gradients(g, "value", 40.0)
    np.testing.assert_allclose(torch.cat(g).numpy(), [30.0, 40.0, 3.0, -40.0])
    g = grads()
    total = math.sqrt(2500 + 2509)
    a3c.clip_gradients(g, "global-norm", 25.0)
    np.testing.assert_allclose(
        torch.cat(g).numpy(), np.array([30.0, 40.0, 3.0, -50.0]) * 25 / total, rtol=1e-5
    )
    g = grads()
    a3c.clip_gradients(g, "none", 1.0)
    np.testing.assert_allclose(torch.cat(g).numpy(), [30.0, 40.0, 3.0, -50.0])


def test_shared_rmsprop_step(a3c):
    param = torch.tensor([1.0, -1.0])
    opt = a3c.SharedRMSprop([param], decay=0.99, eps=0.1)
    opt.step([torch.tensor([2.0, 0.0])], lr=0.1)
    # ms = 0.01 * g^2 = [0.04, 0]; theta -= 0.1 * g / sqrt(ms + 0.1)
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [0.04, 0.0], rtol=1e-6)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(0.14), -1.0], rtol=1e-6)


def test_shared_adam_step(a3c):
    param = torch.tensor([1.0])
    opt = a3c.SharedAdam([param], beta1=0.9, beta2=0.99, eps=0.1)
    opt.step([torch.tensor([2.0])], lr=0.1)
    # m_hat = g, v_hat = g^2 after one step: theta -= 0.1 * 2 / sqrt(4 + 0.1)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(4.1)], rtol=1e-6)
    assert opt.step_count.item() == 1


def _step_in_child(opt, grad_value):
    opt.step([torch.full((3,), grad_value)], lr=0.01)


def test_shared_rmsprop_state_is_shared_between_processes(a3c):
    param = torch.zeros(3).share_memory_()
    opt = a3c.SharedRMSprop([param], decay=0.99, eps=0.1)
    ctx = multiprocessing.get_context("fork")
    for grad_value in (1.0, 2.0):  # two processes, one after the other
        child = ctx.Process(target=_step_in_child, args=(opt, grad_value))
        child.start()
        child.join(30)
        assert child.exitcode == 0
    # both children's updates are visible here: ms = 0.99 * 0.01 * 1 + 0.01 * 4
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [0.0499] * 3, rtol=1e-5)
    first = 0.01 * 1 / math.sqrt(0.01 + 0.1)
    second = 0.01 * 2 / math.sqrt(0.0499 + 0.1)
    np.testing.assert_allclose(param.numpy(), [-(first + second)] * 3, rtol=1e-5)


def test_weight_init_schemes(a3c):
    torch.manual_seed(0)
    for scheme in ("torch", "he", "uniform-sqrt3"):
        args = a3c.Args(weight_init=scheme, bias_init=0.01 if scheme == "he" else None)
        model = a3c.ActorCritic(3, args)
        conv1 = model.torso[0]
        fan_in = 4 * 8 * 8
        w = conv1.weight.detach()
        if scheme == "torch":
            assert w.abs().max() <= 1 / math.sqrt(fan_in)
            assert conv1.bias.abs().max() <= 1 / math.sqrt(fan_in)
            assert conv1.bias.abs().max() > 0
        elif scheme == "he":
            std = math.sqrt(2 / fan_in)
            assert w.abs().max() <= 2 * std + 1e-6
            assert w.std().item() == pytest.approx(std * 0.88, rel=0.1)  # 2-sigma truncation
            assert torch.all(conv1.bias == 0.01)
        else:
            bound = math.sqrt(3 / fan_in)
            assert w.abs().max() <= bound
            assert w.abs().max() > 0.9 * bound
            assert torch.all(conv1.bias == 0)


def test_network_shapes_and_scaling(a3c):
    obs = torch.full((5, 4, 84, 84), 255, dtype=torch.uint8)
    raw = a3c.ActorCritic(3, a3c.Args(scale_obs=False))
    scaled = a3c.ActorCritic(3, a3c.Args(scale_obs=True))
    scaled.load_state_dict(raw.state_dict())
    log_probs, values = raw(obs)
    assert log_probs.shape == (5, 3) and values.shape == (5,)
    np.testing.assert_allclose(log_probs.exp().sum(1).detach().numpy(), 1.0, rtol=1e-5)
    assert not torch.allclose(scaled(obs)[1], values)  # 1/255 scaling changes the output
    assert torch.allclose(scaled(obs)[1], raw(torch.ones(5, 4, 84, 84))[1], atol=1e-5)


def _raise_in_child(a3c, shared):
    a3c.run_process("worker 7", shared, lambda: 1 / 0)


def test_run_process_reports_exceptions(a3c):
    ctx = multiprocessing.get_context("fork")
    shared = SimpleNamespace(errors=ctx.SimpleQueue())
    child = ctx.Process(target=_raise_in_child, args=(a3c, shared))
    child.start()
    child.join(30)
    assert child.exitcode == 1
    name, trace = shared.errors.get()
    assert name == "worker 7" and "ZeroDivisionError" in trace


def test_checkpoint_round_trip_and_errors(a3c, tmp_path):
    import catch_env  # noqa: F401

    args = a3c.resolve_defaults(a3c.Args(num_workers=1))
    shared = a3c.Shared(args, 3, multiprocessing.get_context("fork"))
    shared.steps[0] = 1234
    shared.optimizer.square_avg[0].fill_(0.5)
    path = tmp_path / "checkpoint.pt"
    a3c.save_checkpoint(path, shared, args, wall_time=12.0)
    checkpoint = a3c.load_checkpoint(str(path))
    assert checkpoint["global_step"] == 1234 and checkpoint["wall_time"] == 12.0

    fresh = a3c.Shared(args, 3, multiprocessing.get_context("fork"))
    a3c.restore(fresh, checkpoint, args, str(path))
    assert fresh.global_step() == 1234
    assert torch.all(fresh.optimizer.square_avg[0] == 0.5)
    for p, q in zip(fresh.params, shared.params, strict=True):
        assert torch.equal(p, q)

    with pytest.raises(a3c.UsageError, match="does not exist"):
        a3c.load_checkpoint(str(tmp_path / "missing.pt"))
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(a3c.UsageError, match="corrupt"):
        a3c.load_checkpoint(str(tmp_path / "garbage.pt"))
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(a3c.UsageError, match="not a checkpoint written by this script"):
        a3c.load_checkpoint(str(tmp_path / "other.pt"))
    elu = a3c.resolve_defaults(a3c.Args(num_workers=1, activation="elu"))
    with pytest.raises(a3c.UsageError, match="--activation"):
        a3c.restore(fresh, checkpoint, elu, str(path))
    checkpoint["model"]["policy.weight"] = torch.zeros(5, 256)
    with pytest.raises(a3c.UsageError, match="does not fit"):
        a3c.restore(fresh, checkpoint, args, str(path))


def test_defaults_and_validation(a3c):
    import catch_env  # noqa: F401

    catch = a3c.resolve_defaults(a3c.Args())
    assert (catch.total_timesteps, catch.eval_interval, catch.scale_obs) == (
        1_000_000,
        50_000,
        False,
    )
    assert catch.grad_clip == 40.0 and catch.learning_rate == 7e-4
    assert a3c.resolve_defaults(a3c.Args(grad_clip_mode="global-norm")).grad_clip == 25.0
    atari = a3c.resolve_defaults(a3c.Args(env="BreakoutNoFrameskip-v4"))
    assert (atari.total_timesteps, atari.eval_interval, atari.scale_obs) == (10**8, 10**6, True)
    with pytest.raises(a3c.UsageError, match="--gamma must be in"):
        a3c.resolve_defaults(a3c.Args(gamma=1.5))
    with pytest.raises(a3c.UsageError, match="unknown --env"):
        a3c.resolve_defaults(a3c.Args(env="Nope-v0"))


def test_annealed_lr(a3c):
    args = a3c.Args(total_timesteps=1000, learning_rate=1e-3)
    assert a3c.annealed_lr(args, 0) == pytest.approx(1e-3)
    assert a3c.annealed_lr(args, 250) == pytest.approx(7.5e-4)
    assert a3c.annealed_lr(args, 2000) == 0.0
    args.anneal_lr = False
    assert a3c.annealed_lr(args, 250) == pytest.approx(1e-3)


def test_worker_learns_in_process_and_keeps_no_autograd_history(a3c):
    import os

    import catch_env  # noqa: F401

    args = a3c.resolve_defaults(a3c.Args(num_workers=1, total_timesteps=300))
    shared = a3c.Shared(args, 3, multiprocessing.get_context("fork"))
    shared.evaluator_ready.set()
    before = [p.detach().clone() for p in shared.params]
    a3c.worker(0, shared, args, os.getppid())
    assert 300 <= shared.global_step() < 300 + args.t_max
    assert shared.stats[0, 0] >= 300 // 15  # Catch episodes are 15 steps
    assert not any(torch.equal(p, q) for p, q in zip(before, shared.params, strict=True))
    # logging the losses must not chain each rollout's graph onto the stats (a memory leak)
    assert shared.stats.grad_fn is None and not shared.stats.requires_grad
