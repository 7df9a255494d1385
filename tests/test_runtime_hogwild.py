"""a3c_runtime.hogwild: the shared optimizers against hand-computed steps, clipping, the
learning-rate schedule, statistics by name."""

import math
from types import SimpleNamespace

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
from conftest import FORK, load_script, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


def test_clip_gradients_modes():
    def grads():
        return [torch.tensor([30.0, 40.0]), torch.tensor([3.0, -50.0])]

    g = grads()
    norm = runtime.clip_gradients(g, "norm", 40.0)  # per tensor: [30, 40] has norm 50 -> x0.8
    assert norm == pytest.approx(math.sqrt(50**2 + 9 + 2500))
    np.testing.assert_allclose(g[0].numpy(), [24.0, 32.0], rtol=1e-5)
    np.testing.assert_allclose(g[1].numpy(), np.array([3.0, -50.0]) * 40 / math.sqrt(2509))
    g = grads()
    runtime.clip_gradients(g, "value", 40.0)
    np.testing.assert_allclose(torch.cat(g).numpy(), [30.0, 40.0, 3.0, -40.0])
    g = grads()
    total = math.sqrt(2500 + 2509)
    runtime.clip_gradients(g, "global-norm", 25.0)
    np.testing.assert_allclose(
        torch.cat(g).numpy(), np.array([30.0, 40.0, 3.0, -50.0]) * 25 / total, rtol=1e-5
    )
    g = grads()
    runtime.clip_gradients(g, "none", 1.0)
    np.testing.assert_allclose(torch.cat(g).numpy(), [30.0, 40.0, 3.0, -50.0])


def test_norm_clipping_scales_only_the_tensors_over_the_bound():
    under, over = torch.tensor([3.0, 4.0]), torch.tensor([0.0, 80.0])  # norms 5 and 80
    grads = [under.clone(), over.clone()]
    runtime.clip_gradients(grads, "norm", 40.0)
    np.testing.assert_allclose(grads[0].numpy(), [3.0, 4.0])  # not scaled up to norm 40
    np.testing.assert_allclose(grads[1].numpy(), [0.0, 40.0], rtol=1e-5)
    grads = [under.clone(), under.clone() * 2]  # global norm sqrt(125) < 25: unchanged
    runtime.clip_gradients(grads, "global-norm", 25.0)
    np.testing.assert_allclose(torch.cat(grads).numpy(), [3.0, 4.0, 6.0, 8.0])


def test_shared_rmsprop_step():
    param = torch.tensor([1.0, -1.0])
    opt = runtime.RMSprop([param], decay=0.99, eps=0.1)
    opt.step([torch.tensor([2.0, 0.0])], lr=0.1)
    # ms = 0.01 * g^2 = [0.04, 0]; theta -= 0.1 * g / sqrt(ms + 0.1)
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [0.04, 0.0], rtol=1e-6)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(0.14), -1.0], rtol=1e-6)


def test_shared_rmsprop_from_tensorflows_initial_mean_square():
    """--rms-init 1 (TensorFlow's RMSPropOptimizer): with a small eps the first step stays
    about lr * g instead of 10 lr per weight."""
    param = torch.tensor([1.0, -1.0])
    opt = runtime.RMSprop([param], decay=0.99, eps=1e-5, initial=1.0)
    opt.step([torch.tensor([2.0, 0.0])], lr=0.1)
    # ms = 0.99 * 1 + 0.01 * g^2 = [1.03, 0.99]; theta -= 0.1 * g / sqrt(ms + 1e-5)
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [1.03, 0.99], rtol=1e-6)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(1.03001), -1.0], rtol=1e-6)
    zero_start = torch.tensor([1.0])
    runtime.RMSprop([zero_start], decay=0.99, eps=1e-5).step([torch.tensor([2.0])], lr=0.1)
    assert zero_start.item() == pytest.approx(1.0 - 0.2 / math.sqrt(0.04001), abs=1e-6)  # 10 lr


def test_shared_adam_step():
    param = torch.tensor([1.0])
    opt = runtime.SharedAdam([param], beta1=0.9, beta2=0.99, eps=0.1)
    opt.step([torch.tensor([2.0])], lr=0.1)
    # m_hat = g, v_hat = g^2 after one step: theta -= 0.1 * 2 / sqrt(4 + 0.1)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(4.1)], rtol=1e-6)
    assert opt.step_count.item() == 1


def _step_in_child(opt, grad_value):
    opt.step([torch.full((3,), grad_value)], lr=0.01)


def test_shared_rmsprop_state_is_shared_between_processes():
    param = torch.zeros(3).share_memory_()
    opt = runtime.RMSprop([param], decay=0.99, eps=0.1)
    for grad_value in (1.0, 2.0):  # two processes, one after the other
        child = FORK.Process(target=_step_in_child, args=(opt, grad_value))
        child.start()
        child.join(30)
        assert child.exitcode == 0
    # both children's updates are visible here: ms = 0.99 * 0.01 * 1 + 0.01 * 4
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [0.0499] * 3, rtol=1e-5)
    first = 0.01 * 1 / math.sqrt(0.01 + 0.1)
    second = 0.01 * 2 / math.sqrt(0.0499 + 0.1)
    np.testing.assert_allclose(param.numpy(), [-(first + second)] * 3, rtol=1e-5)


def test_annealed_lr():
    args = SimpleNamespace(total_timesteps=1000, learning_rate=1e-3, anneal_lr=True)
    assert runtime.annealed_lr(args, 0) == pytest.approx(1e-3)
    assert runtime.annealed_lr(args, 250) == pytest.approx(7.5e-4)
    assert runtime.annealed_lr(args, 2000) == 0.0
    args.anneal_lr = False
    assert runtime.annealed_lr(args, 250) == pytest.approx(1e-3)


def test_worker_stats_are_added_to_by_name_in_shared_memory():
    args = SimpleNamespace(num_workers=2, optimizer="rmsprop", rms_decay=0.99, optim_eps=0.1)
    shared = runtime.Shared(torch.nn.Linear(2, 1), args, FORK)
    stats = shared.worker_stats(1)
    stats.add(episodes=2, return_sum=1.5)
    stats.add(episodes=1, grad_norm=0.25)
    row = dict(zip(runtime.Shared.STATS, shared.stats[1].tolist(), strict=True))
    assert row["episodes"] == 3 and row["return_sum"] == 1.5 and row["grad_norm"] == 0.25
    assert shared.stats[0].abs().sum() == 0  # worker 0's row is untouched
    with pytest.raises(KeyError):
        stats.add(episode=1)  # a misspelt name is an error, not a new statistic


def test_keep_running_until_stopped_or_signalled():
    args = SimpleNamespace(num_workers=1, optimizer="rmsprop", rms_decay=0.99, optim_eps=0.1)
    shared = runtime.Shared(torch.nn.Linear(2, 1), args, FORK)
    assert shared.keep_running()
    shared.signalled = True  # SIGTERM in this process
    assert not shared.keep_running()
    shared.signalled = False
    shared.stop.set()
    assert not shared.keep_running()


@pytest.mark.parametrize(("optimizer", "copies"), [("rmsprop", 2), ("adam", 3)])
def test_no_room_in_shared_memory_names_the_size_the_network_and_its_statistics_need(
    monkeypatch, optimizer, copies
):
    """The refusal's size is theta and the optimizer's statistics: (copies) x the network's
    bytes, in MiB (the slow tier makes the failure real, with a file size limit)."""
    module = load_script("a3c_ff")
    args = tiny_args(module, optimizer=optimizer)
    model = module.AGENT.build_network(3, args)
    bytes_ = sum(t.numel() * t.element_size() for t in model.state_dict().values())

    def full(*_):
        raise RuntimeError("No space left on device")

    monkeypatch.setattr(model, "share_memory", full)
    with pytest.raises(runtime.UsageError) as raised:
        runtime.Shared(model, args, FORK)
    size = copies * bytes_ / 2**20
    assert str(raised.value).startswith(
        f"cannot put the network and its optimizer statistics ({size:.1f} MiB) in shared "
        "memory: No space left on device; free space in /dev/shm"
    ), raised.value


def test_clipping_takes_a_scalar_parameters_gradient():
    # GLPQ's trainable temperature is a 0-d parameter: its gradient clips with the rest
    grads = [torch.tensor(30.0), torch.tensor([40.0, 0.0])]
    norm = runtime.clip_gradients(grads, "global-norm", 25.0)
    assert norm == pytest.approx(50.0)
    np.testing.assert_allclose([grads[0].item(), *grads[1].tolist()], [15.0, 20.0, 0.0], rtol=1e-5)
