"""a3c_runtime.stacked_convs: a convolution with kernel = 2 x stride as space-to-depth and one
matmul computes nn.Conv2d's function (by hand, for random shapes, its gradients, under vmap and
grad as the batched backend calls it, and in every script's network); other convolutions are
left alone."""

import copy

import pytest
import torch
import torch.nn as nn
from a3c_runtime.stacked_convs import SpaceToDepthConv2d, matmul_convs, qualifies
from conftest import SCRIPTS, load_script, tiny_args
from hypothesis import given, settings
from hypothesis import strategies as st
from torch.func import functional_call, grad, stack_module_state, vmap

pytestmark = pytest.mark.usefixtures("one_thread")  # (conftest's: a worker's one thread)


def converted(conv: nn.Conv2d) -> nn.Conv2d:
    return matmul_convs(copy.deepcopy(conv))


def test_a_4x4_stride_2_conv_on_a_6x6_input_by_hand():
    """Input x[i, j] = 6i + j, kernel w[u, v] = u - v (4x4), bias 1: output (2, 2) at (r, c) is
    1 + sum_uv (u - v) * (6(2r + u) + 2c + v). Over the 4x4 window sum(u - v) = 0, so the cell's
    offset drops out: 1 + sum_uv (u - v)(6u + v) = 1 + 6 * sum(u^2 - uv) + sum(uv - v^2), with
    sum_uv u^2 = 4 * 14 = 56, sum_uv uv = 6 * 6 = 36: 1 + 6 * 20 - 20 = 101 at every cell. A
    second map, kernel all ones and bias 0, sums each window: 16 * 6(2r + 1.5) + 16 * (2c + 1.5)
    = 192r + 32c + 168."""
    conv = nn.Conv2d(1, 2, 4, stride=2)
    with torch.no_grad():
        u, v = torch.meshgrid(torch.arange(4.0), torch.arange(4.0), indexing="ij")
        conv.weight.copy_(torch.stack([u - v, torch.ones(4, 4)])[:, None])
        conv.bias.copy_(torch.tensor([1.0, 0.0]))
    x = torch.arange(36.0).reshape(1, 1, 6, 6)
    expected = torch.tensor([[[101.0, 101.0], [101.0, 101.0]], [[168.0, 200.0], [360.0, 392.0]]])
    out = converted(conv)(x)
    assert out.shape == (1, 2, 2, 2)
    torch.testing.assert_close(out[0], expected, rtol=0, atol=0)
    torch.testing.assert_close(conv(x)[0], expected, rtol=0, atol=0)  # (the hand sums)


@settings(max_examples=40, deadline=None)
@given(
    channels=st.integers(1, 5),
    maps=st.integers(1, 5),
    stride=st.sampled_from([1, 2, 3, 4]),
    extra_height=st.integers(0, 9),
    extra_width=st.integers(0, 9),
    batch=st.integers(1, 3),
    channels_last=st.booleans(),
    bias=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_output_and_gradients_are_conv2ds(
    channels, maps, stride, extra_height, extra_width, batch, channels_last, bias, seed
):
    """Random shapes (H, W >= 2 x stride, not always multiples of it), either memory layout:
    the output and the gradients with respect to input, weight and bias are nn.Conv2d's."""
    torch.manual_seed(seed)
    conv = nn.Conv2d(channels, maps, 2 * stride, stride=stride, bias=bias)
    fast = converted(conv)
    assert isinstance(fast, SpaceToDepthConv2d)
    shape = (batch, channels, 2 * stride + extra_height, 2 * stride + extra_width)
    x = torch.randn(shape)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    outs, grads = [], []
    for module in (conv, fast):
        x_leaf = x.detach().clone().requires_grad_(True)
        out = module(x_leaf)
        out_grad = torch.linspace(-1, 1, out.numel()).reshape(out.shape)
        params = [x_leaf, *module.parameters()]
        outs.append(out)
        grads.append(torch.autograd.grad(out, params, out_grad))
    assert outs[1].shape == outs[0].shape
    torch.testing.assert_close(outs[1], outs[0], atol=1e-5, rtol=1e-5)
    for got, want in zip(grads[1], grads[0], strict=True):
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)


def test_under_vmap_and_grad_each_run_is_its_own_conv2d():
    """3 runs' parameters stacked and called under vmap (functional_call), as the batched backend
    calls a network; and vmap(grad(loss)): each run's output and gradients are its own
    nn.Conv2d's."""
    torch.manual_seed(0)
    convs = [nn.Conv2d(3, 4, 4, stride=2) for _ in range(3)]
    fast = converted(convs[0])
    params, _ = stack_module_state(convs)
    x = torch.randn(3, 2, 11, 10, 3).movedim(-1, -3)  # each run's frames channels_last

    def out(weights, frames):
        return functional_call(fast, weights, (frames,))

    def loss(weights, frames):
        return (out(weights, frames) ** 2).sum()

    outs = vmap(out)(params, x)
    grads = vmap(grad(loss))(params, x)
    for i, conv in enumerate(convs):
        torch.testing.assert_close(outs[i], conv(x[i]), atol=1e-5, rtol=1e-5)
        conv.zero_grad()
        (conv(x[i]) ** 2).sum().backward()
        for name, parameter in conv.named_parameters():
            torch.testing.assert_close(grads[name][i], parameter.grad, atol=1e-4, rtol=1e-5)


# every script's default convolutions, and two layouts of other convolutions: LWS's TF "same"
# padding (F.pad before the conv: its inner conv still qualifies) and SS's final network's
# 5x5/3 and 3x3/2 (kernel != 2 x stride: left as they are)
NETWORKS = [(name, {}, 2) for name in SCRIPTS] + [
    ("a3c_lws", {"lws_padding": "same"}, 2),
    ("a3c_ss", {"conv_layout": "final"}, 0),
]


@pytest.mark.parametrize(("name", "flags", "convs"), NETWORKS)
def test_each_scripts_network_is_the_same_with_matmul_convs(name, flags, convs):
    """The network as the runtime builds it and a deep copy with matmul_convs: every default
    convolution converted (counted), the same log-probs and values (LSTM: and state) on random
    frames; and the same state_dict keys."""
    module = load_script(name)
    torch.manual_seed(1)
    network = module.AGENT.build_network(3, tiny_args(module, **flags))
    fast = matmul_convs(copy.deepcopy(network))
    all_convs = [m for m in fast.modules() if isinstance(m, nn.Conv2d)]
    assert sum(isinstance(m, SpaceToDepthConv2d) for m in all_convs) == convs
    assert len(all_convs) == 2  # the rest left as nn.Conv2d
    assert list(fast.state_dict()) == list(network.state_dict())
    frames = torch.randint(0, 256, (5, 4, 84, 84), dtype=torch.uint8)
    with torch.no_grad():
        if hasattr(network, "initial_state"):  # LSTM: (T = 5, B = 1) from a nonzero state
            state = tuple(torch.randn_like(s) for s in network.initial_state(1))
            want, got = network(frames[:, None], state), fast(frames[:, None], state)
            assert len(want) == len(got) == 3
            want, got = (*want[:2], *want[2]), (*got[:2], *got[2])
        else:
            want, got = network(frames), fast(frames)
    for g, w in zip(got, want, strict=True):
        torch.testing.assert_close(g, w, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize(
    "conv",
    [
        nn.Conv2d(2, 3, 3, stride=1),
        nn.Conv2d(2, 3, 4, stride=2, padding=1),
        nn.Conv2d(2, 3, 4, stride=2, dilation=2),
        nn.Conv2d(2, 4, 4, stride=2, groups=2),
        nn.Conv2d(2, 3, (4, 2), stride=(2, 1)),
    ],
    ids=["3x3/1", "padding-1", "dilation-2", "groups-2", "non-square"],
)
def test_a_non_qualifying_conv_is_left_alone(conv):
    assert not qualifies(conv)
    assert type(converted(conv)) is nn.Conv2d
    model = matmul_convs(nn.Sequential(conv, nn.Conv2d(conv.out_channels, 1, 2, stride=1)))
    assert type(model[0]) is nn.Conv2d and type(model[1]) is SpaceToDepthConv2d


def test_a_conv2d_subclass_is_left_alone():
    """A subclass's own forward would be lost by changing its class."""

    class Doubled(nn.Conv2d):
        def forward(self, x):
            return 2 * super().forward(x)

    conv = Doubled(1, 1, 4, stride=2)
    assert qualifies(conv) and type(matmul_convs(conv)) is Doubled
