"""Unit tests of agents/a3c_ff.py's algorithm: the loss, init and the network, against
hand-computed values (n-step returns and sampling: tests/test_batched_actors.py; the runtime's
pieces: tests/test_runtime_*.py)."""

import math

import numpy as np
import pytest
import torch
from conftest import ALL_SCRIPTS, load_script


@pytest.fixture(scope="module")
def a3c():
    return load_script("a3c_ff")


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


@pytest.mark.parametrize("name", ALL_SCRIPTS)
@pytest.mark.parametrize(
    ("scheme", "bias"),
    [("torch", None), ("torch", 0.01), ("he", None), ("he", 0.01), ("variance-scaling", None),
     ("uniform-sqrt3", None)],
)  # fmt: skip
def test_every_scripts_init_gives_each_layer_its_schemes_weights(name, scheme, bias):
    """Each script's own copy of init_parameters (the thesis 6.3.3 schemes, A.1.3's biases) on a
    conv and a linear layer, by their fan-in: He's N(0, 2 / fan_in) truncated at 2 sigma (std
    0.88 sigma); TensorFlow's variance scaling, N(0, 2.6 / fan_in) truncated at 2 sigma (std
    0.88 sqrt(1.3) sigma: He's variance); U(+-sqrt(3 / fan_in)); or torch's default as it is."""
    torch.manual_seed(0)
    probe = torch.nn.Sequential(torch.nn.Conv2d(4, 64, 8), torch.nn.Linear(512, 64))
    default = [(layer.weight.clone(), layer.bias.clone()) for layer in probe]
    load_script(name).init_parameters(probe, scheme, bias)
    for layer, (default_weight, default_bias) in zip(probe, default, strict=True):
        fan_in = layer.weight[0].numel()
        w = layer.weight.detach()
        if scheme in ("he", "variance-scaling"):
            sigma = math.sqrt((2.6 if scheme == "variance-scaling" else 2) / fan_in)
            assert w.abs().max() <= 2 * sigma + 1e-6
            assert w.std().item() == pytest.approx(0.88 * sigma, rel=0.05)
        elif scheme == "uniform-sqrt3":
            bound = math.sqrt(3 / fan_in)
            assert 0.99 * bound < w.abs().max() <= bound
            assert w.std().item() == pytest.approx(bound / math.sqrt(3), rel=0.05)
        else:
            assert torch.equal(w, default_weight)
        expected_bias = (
            default_bias if bias is None and scheme == "torch" else torch.full((64,), bias or 0.0)
        )
        assert torch.equal(layer.bias.detach(), expected_bias)


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


@pytest.mark.parametrize("name", ALL_SCRIPTS)
def test_the_loss_form_is_read_by_value_not_identity(name):
    """A form read back from a checkpoint is an equal string, not the same object: it must
    give the same loss as the literal (an `is` comparison would fall through to the other)."""
    a3c_loss = load_script(name).a3c_loss
    log_probs = torch.log(torch.tensor([[0.2, 0.8], [0.6, 0.4]]))
    inputs = (log_probs, torch.tensor([1, 0]), torch.tensor([0.5, -0.2]), torch.tensor([1.0, 0.3]))
    for form in ("code", "text"):
        read_back = "".join(list(form))  # equal, not identical
        assert read_back is not form
        expected = a3c_loss(*inputs, 0.01, 0.5, form)
        got = a3c_loss(*inputs, 0.01, 0.5, read_back)
        for e, g in zip(expected, got, strict=True):
            torch.testing.assert_close(g, e)
