"""The network variants of thesis chapter 6: agents/a3c_lws.py (local weight sharing, 6.1),
a3c_ss.py (spatial softmax, 6.2), a3c_ww.py (what and where, 6.2.1) and a3c_lstm.py (A3C LSTM).
Layer maths against hand-computed values, parameter counts against the thesis's figures, and
end-to-end runs of each script on tiny budgets (Catch-v0 and BreakoutNoFrameskip-v4)."""

import math
import re
from pathlib import Path

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro
from conftest import load_script, main_exit, read_checkpoint, shared_for

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("a3c_lws", "a3c_ss", "a3c_ww", "a3c_lstm")


def load(name: str):
    return load_script(name)


@pytest.fixture(scope="module")
def lws():
    return load("a3c_lws")


@pytest.fixture(scope="module")
def ss():
    return load("a3c_ss")


@pytest.fixture(scope="module")
def ww():
    return load("a3c_ww")


@pytest.fixture(scope="module")
def lstm():
    return load("a3c_lstm")


def lws_layer(
    lws,
    kcps: int,
    centroids: str = "feature",
    trainable: bool = True,
    size: int = 84,
    out_channels: int = 32,
    kernel: int = 8,
    stride: int = 4,
    **flags,
):
    args = lws.Args(lws_kcps=kcps, lws_centroids=centroids, lws_trainable=trainable, **flags)
    generator = torch.Generator().manual_seed(0)
    return lws.LWSConv2d(4, out_channels, kernel, stride, size, args, generator)


def set_lws(layer, centroids, sigma) -> None:
    with torch.no_grad():
        layer.centroids.copy_(torch.as_tensor(centroids, dtype=torch.float32))
        layer.sigma.copy_(torch.as_tensor(sigma, dtype=torch.float32))


# ---------------------------------------------------------------------------------------------
# Local weight sharing (thesis 6.1, eqs. 6.1 and 6.2)


def test_lws_with_one_pair_is_a_plain_convolution(lws):
    torch.manual_seed(0)
    layer = lws_layer(lws, kcps=1)
    set_lws(layer, torch.rand(1, 32, 2) * 3 - 1, [[2.0, 0.5], [-0.3, 1.5]])  # any centroid, Sigma
    x = torch.rand(2, 4, 84, 84) * 255
    expected = F.conv2d(x, layer.conv.weight, layer.conv.bias, stride=4)
    torch.testing.assert_close(layer(x), expected, rtol=1e-5, atol=1e-4)
    assert layer(x).shape == (2, 32, 20, 20)


def test_lws_similarity_weights_match_hand_computation(lws):
    # group-wise, S = 2, a 3x3 output grid: coordinates 0, 0.5, 1 on both axes
    layer = lws_layer(lws, kcps=2, centroids="group", size=9, out_channels=1, kernel=3, stride=3)
    set_lws(layer, [[[0.0, 0.0]], [[1.0, 1.0]]], [[2.0, 1.0], [0.0, 1.0]])
    weights = layer.similarity_weights()  # (H, W, S, maps)
    assert weights.shape == (3, 3, 2, 1)

    def similarity(x, mu):  # eq. 6.2 with Sigma = [[2, 1], [0, 1]]: 2 a^2 + a b + b^2
        a, b = x[0] - mu[0], x[1] - mu[1]
        return math.exp(-(2 * a * a + a * b + b * b))

    for i, j in [(0, 1), (1, 1), (2, 0), (1, 2)]:
        x = (i / 2, j / 2)
        s0, s1 = similarity(x, (0, 0)), similarity(x, (1, 1))
        assert weights[i, j, 0, 0].item() == pytest.approx(s0 / (s0 + s1), rel=1e-5)
        assert weights[i, j, 1, 0].item() == pytest.approx(s1 / (s0 + s1), rel=1e-5)
    # cell (0, 1), x = (0, 0.5): d0 = 0.25, d1 = 2 + 0.5 + 0.25 = 2.75 -> 1 / (1 + e^-2.5)
    assert weights[0, 1, 0, 0].item() == pytest.approx(1 / (1 + math.exp(-2.5)), rel=1e-6)


@pytest.mark.parametrize("centroids", ["feature", "group"])
def test_lws_similarity_weights_sum_to_one_at_every_cell(lws, centroids):
    torch.manual_seed(1)
    layer = lws_layer(lws, kcps=3, centroids=centroids)
    maps = 32 if centroids == "feature" else 1
    set_lws(layer, torch.rand(3, maps, 2) * 4 - 2, [[3.0, -1.0], [0.5, 0.2]])  # indefinite Sigma
    weights = layer.similarity_weights()
    assert weights.shape == (20, 20, 3, maps)
    assert torch.isfinite(weights).all() and (weights >= 0).all()
    torch.testing.assert_close(weights.sum(2), torch.ones(20, 20, maps))
    assert weights.std() > 0.05  # not a uniform blend: the centroids matter


def test_lws_far_apart_centroids_give_each_region_its_own_kernel(lws):
    torch.manual_seed(2)
    layer = lws_layer(lws, kcps=2, centroids="group")
    # columns j < 0.5 are nearer the first centroid, j > 0.5 the second, by a margin of at
    # least 2 * 1000.5 * 0.5/19 = 52 in the exponent: far apart, so each side takes one kernel
    set_lws(layer, [[[0.5, -500.0]], [[0.5, 501.0]]], torch.eye(2))
    x = torch.rand(1, 4, 84, 84) * 255
    y = layer(x)
    per_kernel = F.conv2d(x, layer.conv.weight, layer.conv.bias, stride=4).view(1, 2, 32, 20, 20)
    torch.testing.assert_close(y[..., :10], per_kernel[:, 0, ..., :10], rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(y[..., 10:], per_kernel[:, 1, ..., 10:], rtol=1e-5, atol=1e-4)
    assert not torch.allclose(per_kernel[:, 0], per_kernel[:, 1])


def test_lws_acting_reuses_weights_only_while_centroids_and_sigma_are_unchanged(lws):
    torch.manual_seed(9)
    layer = lws_layer(lws, kcps=3)
    x = torch.rand(1, 4, 84, 84) * 255
    with torch.inference_mode():
        before = layer(x)
        torch.testing.assert_close(layer(x), before)
    with torch.no_grad():  # as the worker's sync does: in place
        layer.centroids.copy_(torch.rand(3, 32, 2))
        layer.sigma.copy_(torch.tensor([[2.0, 0.3], [0.1, 0.5]]))
    expected = layer(x)  # with autograd on: computed afresh
    with torch.inference_mode():
        after = layer(x)
    torch.testing.assert_close(after, expected)
    assert not torch.allclose(after, before)


def test_lws_feature_wise_centroids_are_per_map(lws):
    layer = lws_layer(lws, kcps=2, centroids="feature", out_channels=2)
    # map 0 is near pair 0 everywhere, map 1 near pair 1 everywhere
    set_lws(layer, [[[0.5, 0.5], [0.5, 500.0]], [[0.5, 500.0], [0.5, 0.5]]], torch.eye(2))
    x = torch.rand(1, 4, 84, 84) * 255
    per_kernel = F.conv2d(x, layer.conv.weight, layer.conv.bias, stride=4).view(1, 2, 2, 20, 20)
    y = layer(x)
    torch.testing.assert_close(y[:, 0], per_kernel[:, 0, 0], rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(y[:, 1], per_kernel[:, 1, 1], rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("trainable", [True, False])
def test_lws_gradients_reach_centroids_and_sigma_only_when_trainable(lws, trainable):
    torch.manual_seed(3)
    net = lws.ActorCritic(3, lws.Args(lws_trainable=trainable))
    layers = [m for m in net.modules() if isinstance(m, lws.LWSConv2d)]
    assert len(layers) == 2  # both convolutions of A3C FF are LWS layers
    log_probs, values = net(torch.randint(0, 256, (4, 4, 84, 84), dtype=torch.uint8))
    (log_probs[:, 0].sum() + values.sum()).backward()
    names = {name for name, _ in net.named_parameters()}
    for k, layer in enumerate(layers):
        for tensor_name in ("centroids", "sigma"):
            tensor = getattr(layer, tensor_name)
            is_parameter = f"torso.{2 * k}.{tensor_name}" in names
            assert is_parameter == trainable
            if trainable:
                assert tensor.grad is not None and tensor.grad.abs().sum() > 0
            else:
                assert tensor.grad is None and not tensor.requires_grad


def test_lws_fixed_centroids_are_the_same_in_every_process(lws):
    """Fixed centroids are buffers, not synced like parameters: every process must draw the
    same ones from --seed, whatever its global RNG state."""
    args = lws.Args(lws_trainable=False)
    torch.manual_seed(10)
    first = lws.ActorCritic(3, args).state_dict()
    torch.manual_seed(11)
    second = lws.ActorCritic(3, args).state_dict()
    for key in ("torso.0.centroids", "torso.2.centroids"):
        torch.testing.assert_close(first[key], second[key], rtol=0, atol=0)
        assert first[key].min() >= 0 and first[key].max() <= 1  # U[0, 1]
    other_seed = lws.ActorCritic(3, lws.Args(lws_trainable=False, seed=2)).state_dict()
    assert not torch.equal(first["torso.0.centroids"], other_seed["torso.0.centroids"])
    torch.testing.assert_close(first["torso.0.sigma"], torch.eye(2))


def count_parameters(model: nn.Module, weights_only: bool = False) -> int:
    """All parameters, or as the thesis counts them: the weights, without the value head."""
    named = model.named_parameters()
    if weights_only:
        named = [(n, p) for n, p in named if n.endswith("weight") and not n.startswith("value")]
    return sum(p.numel() for _, p in named)


@pytest.mark.parametrize("num_actions", [3, 18])
def test_lws_parameter_counts_against_the_thesis(lws, num_actions):
    ff = load("a3c_ff")
    a = num_actions
    lws_net = lws.ActorCritic(a, lws.Args(lws_trainable=False))
    ff_net = ff.ActorCritic(a, ff.Args())
    # thesis 6.1.2: 1,449,984 + 256|A| for LWS, counting the weights only (no biases, no
    # value head, no centroids): 3 * (8*8*4*32 + 4*4*32*64) + 5184 * 256 + 256|A|
    assert count_parameters(lws_net, weights_only=True) == 1_449_984 + 256 * a
    # with the biases (3 * (32 + 64) kernel biases, FC 256, policy |A|) and the value head (257)
    assert count_parameters(lws_net) == 1_449_984 + 256 * a + 288 + 256 + a + 257
    # A3C FF weights only: 1,368,064 + 256|A|; the thesis says 1,336,320 + 256|A|, short by
    # 4*4*64*31: as if conv 2's input depth (32) was left out of its 4*4*32*64 kernels
    assert count_parameters(ff_net, weights_only=True) == 1_368_064 + 256 * a
    assert 1_368_064 - 1_336_320 == 4 * 4 * 64 * 31
    # the centroids (feature-wise 3 * (32 + 64) * 2, group-wise 3 * 2 * 2) and Sigma (2 * 4)
    trainable_fw = lws.ActorCritic(a, lws.Args(lws_centroids="feature"))
    trainable_gw = lws.ActorCritic(a, lws.Args(lws_centroids="group"))
    assert count_parameters(trainable_fw) - count_parameters(lws_net) == 576 + 8
    assert count_parameters(trainable_gw) - count_parameters(lws_net) == 12 + 8


def test_lws_network_shapes(lws):
    net = lws.ActorCritic(4, lws.Args())
    x = torch.randint(0, 256, (5, 4, 84, 84), dtype=torch.uint8)
    hidden = net.torso[1](net.torso[0](x.float()))
    assert hidden.shape == (5, 32, 20, 20)
    assert net.torso[2](hidden).shape == (5, 64, 9, 9)
    log_probs, values = net(x)
    assert log_probs.shape == (5, 4) and values.shape == (5,)
    torch.testing.assert_close(log_probs.exp().sum(1), torch.ones(5))


def test_lws_bad_kcps_is_a_usage_error(lws):
    with pytest.raises(lws.UsageError, match="--lws-kcps must be >= 1"):
        lws.ActorCritic(3, lws.Args(lws_kcps=0))


# The as-run options (thesis-notes.md "As run", sisws.py): --lws-similarity matrix,
# --lws-padding same, --lws-second-layer-maps, --lws-kernel-init, --lws-centroid-init


def test_lws_matrix_similarity_matches_numpy(lws):
    # group-wise, S = 2, a 3x3 output grid (coordinates 0, 0.5, 1), a 2x2 A_s per centroid
    layer = lws_layer(
        lws, kcps=2, centroids="group", size=9, out_channels=1, kernel=3, stride=3,
        lws_similarity="matrix",
    )  # fmt: skip
    assert layer.matrix.shape == (2, 1, 2, 2) and not hasattr(layer, "sigma")
    mu = np.array([[0.2, 0.9], [0.7, 0.1]])
    a = np.array([[[1.5, -0.4], [0.3, 0.8]], [[0.6, 1.2], [-0.9, 2.0]]])
    with torch.no_grad():
        layer.centroids.copy_(torch.tensor(mu[:, None], dtype=torch.float32))
        layer.matrix.copy_(torch.tensor(a[:, None], dtype=torch.float32))
    weights = layer.similarity_weights().detach().numpy()  # (H, W, S, maps)
    for i in range(3):
        for j in range(3):
            x = np.array([i / 2, j / 2])
            sim = np.array([np.exp(-np.sum((a[s] @ (x - mu[s])) ** 2)) for s in range(2)])
            np.testing.assert_allclose(weights[i, j, :, 0], sim / sim.sum(), rtol=1e-5)


def test_lws_matrix_weights_sum_to_one_and_equal_sigma_at_the_identity(lws):
    torch.manual_seed(12)
    matrix = lws_layer(lws, kcps=3, lws_similarity="matrix")
    sigma = lws_layer(lws, kcps=3)
    assert matrix.matrix.shape == (3, 32, 2, 2)  # per pair and map: shaped like the centroids
    torch.testing.assert_close(matrix.matrix, torch.eye(2).expand(3, 32, 2, 2))
    centroids = torch.rand(3, 32, 2) * 2 - 0.5
    set_lws(sigma, centroids, torch.eye(2))
    with torch.no_grad():
        matrix.centroids.copy_(centroids)
    torch.testing.assert_close(matrix.similarity_weights(), sigma.similarity_weights())
    with torch.no_grad():
        matrix.matrix.copy_(torch.randn(3, 32, 2, 2) * 2)
    weights = matrix.similarity_weights()
    assert torch.isfinite(weights).all() and (weights >= 0).all()
    torch.testing.assert_close(weights.sum(2), torch.ones(20, 20, 32))


def test_lws_matrix_acting_cache_follows_the_matrices(lws):
    torch.manual_seed(13)
    layer = lws_layer(lws, kcps=3, lws_similarity="matrix")
    x = torch.rand(1, 4, 84, 84) * 255
    with torch.inference_mode():
        before = layer(x)
    with torch.no_grad():  # the worker's sync: in place, the centroids unchanged
        layer.matrix.copy_(torch.randn(3, 32, 2, 2) * 3)
    expected = layer(x)
    with torch.inference_mode():
        after = layer(x)
    torch.testing.assert_close(after, expected)
    assert not torch.allclose(after, before)


@pytest.mark.parametrize("trainable", [True, False])
def test_lws_matrix_is_trained_only_when_trainable(lws, trainable):
    torch.manual_seed(14)
    args = lws.Args(lws_similarity="matrix", lws_trainable=trainable, lws_centroids="group")
    net = lws.ActorCritic(3, args)
    names = {name for name, _ in net.named_parameters()}
    assert ("torso.0.matrix" in names) == trainable and "torso.0.sigma" not in names
    assert net.state_dict()["torso.2.matrix"].shape == (3, 1, 2, 2)
    log_probs, values = net(torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8))
    (log_probs[:, 0].sum() + values.sum()).backward()
    if trainable:
        assert net.torso[0].matrix.grad.abs().sum() > 0


def test_lws_same_padding_is_tensorflow_s(lws):
    """TF 'same': ceil(in / stride) outputs, padding split with the odd pixel at the bottom and
    right. 7x7, kernel 4, stride 2: 4x4 outputs, 3 pixels of padding: 1 before, 2 after."""
    layer = lws_layer(
        lws, kcps=1, centroids="group", size=7, out_channels=1, kernel=4, stride=2,
        lws_padding="same",
    )  # fmt: skip
    assert layer.size == 4 and layer.padding == (1, 2, 1, 2)
    torch.manual_seed(15)
    x = torch.randn(1, 4, 7, 7)
    w = layer.conv.weight.detach().numpy()[0]  # (4, 4, 4)
    b = layer.conv.bias.item()
    padded = np.zeros((4, 10, 10))
    padded[:, 1:8, 1:8] = x[0].numpy()
    expected = np.array(
        [[(padded[:, 2 * i : 2 * i + 4, 2 * j : 2 * j + 4] * w).sum() + b for j in range(4)]
         for i in range(4)]
    )  # fmt: skip
    np.testing.assert_allclose(layer(x)[0, 0].detach().numpy(), expected, rtol=1e-4, atol=1e-4)
    # Conv2d's symmetric padding (1 on every side) gives another, smaller output
    assert F.conv2d(x, layer.conv.weight, stride=2, padding=1).shape[-1] == 3


@pytest.mark.parametrize(("padding", "sizes"), [("valid", (20, 9)), ("same", (21, 11))])
@pytest.mark.parametrize("maps", [64, 32])
def test_lws_padding_and_second_layer_maps_shape_the_network(lws, padding, sizes, maps):
    net = lws.ActorCritic(3, lws.Args(lws_padding=padding, lws_second_layer_maps=maps))
    first, second = net.torso[0], net.torso[2]
    assert (first.size, second.size) == sizes
    if padding == "same":  # 84: 4 pixels of padding, 2 + 2; 21: 3 pixels, 1 + 2
        assert first.padding == (2, 2, 2, 2) and second.padding == (1, 2, 1, 2)
    x = torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8)
    hidden = net.torso[:2](x.float())
    assert hidden.shape == (2, 32, sizes[0], sizes[0])
    assert net.torso[2](hidden).shape == (2, maps, sizes[1], sizes[1])
    assert net.torso[5].in_features == maps * sizes[1] ** 2  # as run: 11 * 11 * 32 = 3,872
    log_probs, values = net(x)
    assert torch.isfinite(log_probs).all() and torch.isfinite(values).all()
    torch.testing.assert_close(log_probs.exp().sum(1), torch.ones(2))


def test_lws_uniform_sqrt3_kernel_init(lws):
    torch.manual_seed(16)
    net = lws.ActorCritic(3, lws.Args(lws_kernel_init="uniform-sqrt3"))
    for layer, fan_in in ((net.torso[0].conv, 4 * 8 * 8), (net.torso[2].conv, 32 * 4 * 4)):
        bound = math.sqrt(3 / fan_in)
        weights = layer.weight.abs()
        assert weights.max() <= bound and weights.max() > 0.95 * bound
        assert weights.mean().item() == pytest.approx(bound / 2, rel=0.05)  # uniform
        assert not layer.bias.any()
    fc = net.torso[5]  # keeps --weight-init torch: U(+-1/sqrt(fan_in)), biases too
    assert fc.weight.abs().max() <= 1 / math.sqrt(5184) and fc.bias.any()
    default = lws.ActorCritic(3, lws.Args())
    assert default.torso[0].conv.weight.abs().max() <= 1 / math.sqrt(256)
    assert default.torso[0].conv.bias.any()


@pytest.mark.parametrize("centroids", ["feature", "group"])
def test_lws_grid_centroids(lws, centroids):
    args = lws.Args(lws_kcps=4, lws_centroid_init="grid", lws_centroids=centroids)
    net = lws.ActorCritic(3, args)
    third = 1 / 3  # as the thesis code: k / (n + 1) for n = 2
    grid = torch.tensor([[third, third], [third, 2 * third], [2 * third, third], [2 * third] * 2])
    for layer, maps in ((net.torso[0], 32), (net.torso[2], 64)):
        maps = maps if centroids == "feature" else 1
        torch.testing.assert_close(layer.centroids.detach(), grid[:, None].expand(4, maps, 2))
    one = lws.ActorCritic(3, lws.Args(lws_kcps=1, lws_centroid_init="grid", lws_trainable=False))
    torch.testing.assert_close(one.torso[0].centroids, torch.full((1, 32, 2), 0.5))


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        ({"lws_centroid_init": "grid"}, "--lws-centroid-init grid needs a square --lws-kcps"),
        ({"lws_centroid_init": "grid", "lws_kcps": 8}, "1, 4, 9, ... (got 8)"),
        ({"lws_second_layer_maps": 0}, "--lws-second-layer-maps must be >= 1 (got 0)"),
    ],
)
def test_lws_bad_shapes_are_usage_errors(lws, flags, message):
    with pytest.raises(lws.UsageError, match=re.escape(message)):
        lws.ActorCritic(3, lws.Args(**flags))


def test_lws_network_args_hold_the_shaping_flags(lws):
    for key in ("lws_similarity", "lws_padding", "lws_second_layer_maps", "lws_centroid_init"):
        assert key in lws.NETWORK_ARGS


# ---------------------------------------------------------------------------------------------
# Spatial softmax (thesis 6.2, eqs. 6.3 and 6.4)


def spatial_softmax(
    module,
    maps: int,
    size: int,
    temperature: float = 0.6,
    mode: str = "per-map",
    trainable: bool = True,
):
    args = module.Args(
        ss_temperature=mode, ss_trainable_temperature=trainable, ss_initial_temperature=temperature
    )
    return module.SpatialSoftmax(maps, size, args)


def test_spatial_softmax_matches_hand_computation(ss):
    # one 2x2 map, tau = 1: psi = [1, 3, 1, 1] / 6 over (0,0), (0,1), (1,0), (1,1);
    # x (column) = -0.5, 0.5; y (row) = -0.5, 0.5
    layer = spatial_softmax(ss, maps=2, size=2, temperature=1.0)
    features = torch.tensor([[[[0.0, math.log(3)], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]]])
    out = layer(features)
    assert out.shape == (1, 4)  # x_1, y_1, x_2, y_2
    x1 = (-0.5 * 1 + 0.5 * 3 - 0.5 * 1 + 0.5 * 1) / 6
    y1 = (-0.5 * 1 - 0.5 * 3 + 0.5 * 1 + 0.5 * 1) / 6
    np.testing.assert_allclose(out[0].detach().numpy(), [x1, y1, 0.0, 0.0], atol=1e-6)
    # tau = 2 halves the logits: weights [1, sqrt 3, 1, 1] / (3 + sqrt 3)
    layer = spatial_softmax(ss, maps=2, size=2, temperature=2.0)
    r3 = math.sqrt(3)
    expected_x = (-0.5 + 0.5 * r3 - 0.5 + 0.5) / (3 + r3)
    expected_y = (-0.5 - 0.5 * r3 + 0.5 + 0.5) / (3 + r3)
    np.testing.assert_allclose(
        layer(features)[0, :2].detach().numpy(), [expected_x, expected_y], atol=1e-6
    )


def test_spatial_softmax_of_a_one_hot_map_is_that_cells_coordinates(ss):
    layer = spatial_softmax(ss, maps=3, size=13)
    features = torch.zeros(1, 3, 13, 13)
    cells = [(3, 10), (0, 0), (12, 6)]  # (row i, column j) per map
    for k, (i, j) in enumerate(cells):
        features[0, k, i, j] = 100.0
    out = layer(features).view(3, 2).detach()
    for k, (i, j) in enumerate(cells):  # coordinates -0.5 + index / 12
        np.testing.assert_allclose(out[k].numpy(), [-0.5 + j / 12, -0.5 + i / 12], atol=1e-6)
    np.testing.assert_allclose(out[0].numpy(), [1 / 3, -0.25], atol=1e-6)


def test_spatial_softmax_at_high_temperature_returns_the_centre(ss):
    torch.manual_seed(4)
    features = torch.randn(2, 5, 13, 13) * 3
    cold = spatial_softmax(ss, maps=5, size=13, temperature=0.6)(features)
    hot = spatial_softmax(ss, maps=5, size=13, temperature=1e6)(features)
    np.testing.assert_allclose(hot.detach().numpy(), np.zeros((2, 10)), atol=1e-5)
    assert cold.abs().max() > 0.05


@pytest.mark.parametrize(("mode", "shape"), [("per-map", (5, 1)), ("global", (1, 1))])
@pytest.mark.parametrize("trainable", [True, False])
def test_spatial_softmax_temperature_gradient_only_when_trainable(ss, mode, shape, trainable):
    layer = spatial_softmax(ss, maps=5, size=13, mode=mode, trainable=trainable)
    assert layer.temperature.shape == shape
    assert torch.all(layer.temperature == 0.6)
    assert (list(layer.parameters()) == [layer.temperature]) == trainable
    features = torch.randn(2, 5, 13, 13, requires_grad=True)
    (layer(features) * torch.randn(2, 10)).sum().backward()
    assert features.grad.abs().sum() > 0
    if trainable:
        assert layer.temperature.grad.abs().min() > 0  # every tau gets a gradient
    else:
        assert layer.temperature.grad is None


def test_spatial_softmax_per_map_temperatures_apply_to_their_map(ss):
    layer = spatial_softmax(ss, maps=2, size=2, temperature=1.0)
    with torch.no_grad():
        layer.temperature.copy_(torch.tensor([[1.0], [2.0]]))
    features = torch.tensor([[[[0.0, math.log(3)], [0.0, 0.0]]] * 2])
    out = layer(features)[0].detach()
    r3 = math.sqrt(3)
    assert out[0].item() == pytest.approx(1 / 6, abs=1e-6)  # tau 1, as by hand above
    assert out[2].item() == pytest.approx((0.5 * r3 - 0.5) / (3 + r3), abs=1e-6)  # tau 2


# --conv-layout: (kernel, stride) of each convolution and the grid sizes after them
LAYOUTS = {"ff": (((8, 8), (4, 4)), ((4, 4), (2, 2)), 20, 9),
           "final": (((5, 5), (3, 3)), ((3, 3), (2, 2)), 27, 13)}  # fmt: skip


@pytest.mark.parametrize("layout", ["ff", "final"])
def test_ss_network_layouts(ss, layout):
    (kernel1, stride1), (kernel2, stride2), size1, size2 = LAYOUTS[layout]
    net = ss.ActorCritic(3, ss.Args(conv_layout=layout))
    convs = [m for m in net.modules() if isinstance(m, nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size, c.stride) for c in convs] == [
        (32, kernel1, stride1),
        (64, kernel2, stride2),
    ]
    x = torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8)
    assert net.torso[:2](x.float()).shape == (2, 32, size1, size1)
    maps = net.torso[:3](x.float())
    assert maps.shape == (2, 64, size2, size2)
    assert net.torso[3].coordinates.shape == (size2 * size2, 2)  # the grid follows the maps
    assert net.torso[3](maps).shape == (2, 128) and net.torso[4].in_features == 128
    assert (maps < 0).any(), "the second convolution is linear: no ReLU before the softmax"
    log_probs, values = net(x)
    assert log_probs.shape == (2, 3) and values.shape == (2,)
    assert torch.isfinite(log_probs).all() and torch.isfinite(values).all()
    torch.testing.assert_close(log_probs.exp().sum(1), torch.ones(2))
    # conv 1 and 2 (weights + biases), 64 temperatures, FC 128*256 + 256, heads 257 * 4
    conv_params = {"ff": 8224 + 32832, "final": 3232 + 18496}[layout]
    assert count_parameters(net) == conv_params + 64 + 33024 + 257 * 4


def test_ss_and_ww_default_to_the_text_s_ff_convolutions(ss, ww):
    assert ss.Args().conv_layout == ww.Args().conv_layout == "ff"
    for module in (ss, ww):
        assert "conv_layout" in module.NETWORK_ARGS  # a checkpoint's network depends on it


@pytest.mark.parametrize("layout", ["ff", "final"])
def test_ss_one_hot_corner_maps_to_the_grid_corners(ss, layout):
    """The coordinates span [-0.5, 0.5] over the second convolution's grid, whatever its size."""
    size = LAYOUTS[layout][3]
    net = ss.ActorCritic(3, ss.Args(conv_layout=layout))
    features = torch.zeros(1, 64, size, size)
    features[0, 0, 0, size - 1] = features[0, 1, size - 1, 0] = 100.0  # top right, bottom left
    out = net.torso[3](features).view(64, 2).detach()
    np.testing.assert_allclose(out[0].numpy(), [0.5, -0.5], atol=1e-5)
    np.testing.assert_allclose(out[1].numpy(), [-0.5, 0.5], atol=1e-5)


def test_ss_bad_temperature_is_a_usage_error(ss):
    with pytest.raises(ss.UsageError, match="--ss-initial-temperature must be > 0"):
        ss.ActorCritic(3, ss.Args(ss_initial_temperature=0.0))


# ---------------------------------------------------------------------------------------------
# What and where (thesis 6.2.1)


@pytest.mark.parametrize("layout", ["ff", "final"])
@pytest.mark.parametrize("where_maps", [32, 0, 64, 10])
def test_ww_routes_maps_to_relu_and_spatial_softmax(ww, where_maps, layout):
    torch.manual_seed(5)
    size = LAYOUTS[layout][3]
    net = ww.ActorCritic(3, ww.Args(ww_where_maps=where_maps, conv_layout=layout))
    assert net.fc[0].in_features == (64 - where_maps) * size * size + 2 * where_maps
    x = torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8)
    captured = {}
    net.fc.register_forward_hook(lambda _m, inputs, _o: captured.update(fc_input=inputs[0]))
    net(x)
    maps = net.convs(x.float())
    what, where = maps[:, : 64 - where_maps], maps[:, 64 - where_maps :]
    expected = torch.cat([F.relu(what).flatten(1), net.where(where)], dim=1)
    torch.testing.assert_close(captured["fc_input"], expected, rtol=1e-4, atol=1e-4)
    if where_maps == 32:  # the default: 32 * size^2 "what" values, then 64 "where" coordinates
        coordinates = captured["fc_input"][:, 32 * size * size :]
        assert coordinates.shape == (2, 64) and coordinates.abs().max() <= 0.5


@pytest.mark.parametrize("layout", ["ff", "final"])
def test_ww_network_layouts(ww, layout):
    (kernel1, stride1), (kernel2, stride2), size1, size2 = LAYOUTS[layout]
    net = ww.ActorCritic(3, ww.Args(conv_layout=layout))
    convs = [(c.out_channels, c.kernel_size, c.stride) for c in net.convs if hasattr(c, "stride")]
    assert convs == [(32, kernel1, stride1), (64, kernel2, stride2)]
    x = torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8)
    assert net.convs[:2](x.float()).shape == (2, 32, size1, size1)
    assert net.convs(x.float()).shape == (2, 64, size2, size2)
    assert net.where.coordinates.shape == (size2 * size2, 2)
    # 32 * 9 * 9 + 64 = 2,656 (ff) or 32 * 13 * 13 + 64 = 5,472 (final)
    assert net.fc[0].in_features == {"ff": 2656, "final": 5472}[layout] == 32 * size2**2 + 64
    log_probs, values = net(x)
    assert log_probs.shape == (2, 3) and values.shape == (2,)
    assert torch.isfinite(log_probs).all() and torch.isfinite(values).all()
    torch.testing.assert_close(log_probs.exp().sum(1), torch.ones(2))


def test_ww_bad_split_is_a_usage_error(ww):
    with pytest.raises(ww.UsageError, match="--ww-where-maps must be in"):
        ww.ActorCritic(3, ww.Args(ww_where_maps=65))


# ---------------------------------------------------------------------------------------------
# A3C LSTM


def test_lstm_sequence_replay_equals_stepwise_acting(lstm):
    torch.manual_seed(6)
    net = lstm.ActorCritic(3, lstm.Args())
    obs = torch.randint(0, 256, (7, 1, 4, 84, 84), dtype=torch.uint8)
    start = (torch.randn(1, 256), torch.randn(1, 256))
    replay_log_probs, replay_values, replay_end = net(obs, start)
    assert replay_log_probs.shape == (7, 1, 3) and replay_values.shape == (7, 1)
    state = start
    with torch.inference_mode():
        for t in range(7):
            log_probs, values, state = net(obs[t : t + 1], state)
            torch.testing.assert_close(log_probs[0], replay_log_probs[t], rtol=1e-4, atol=1e-5)
            torch.testing.assert_close(values[0], replay_values[t], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(state[0], replay_end[0], rtol=1e-4, atol=1e-5)


def test_lstm_state_matters_and_starts_at_zero(lstm):
    torch.manual_seed(7)
    net = lstm.ActorCritic(3, lstm.Args())
    h, c = net.initial_state(2)
    assert h.shape == c.shape == (2, 256) and not h.any() and not c.any()
    obs = torch.randint(0, 256, (1, 1, 4, 84, 84), dtype=torch.uint8).expand(1, 2, 4, 84, 84)
    log_probs, _, _ = net(obs, (torch.zeros(2, 256), torch.randn(2, 256) * 3))
    assert not torch.allclose(log_probs[0, 0], log_probs[0, 1])


def test_lstm_gradients_stop_at_the_rollout_start_state(lstm):
    """The worker's truncation: a state from inference-mode acting, cloned, starts the replay;
    the loss reaches every parameter, and nothing flows into the start state."""
    torch.manual_seed(8)
    net = lstm.ActorCritic(3, lstm.Args())
    obs = torch.randint(0, 256, (5, 1, 4, 84, 84), dtype=torch.uint8)
    with torch.inference_mode():
        _, _, carried = net(obs[:2], net.initial_state(1))
    rollout_state = tuple(s.clone() for s in carried)
    assert not any(s.requires_grad for s in rollout_state)
    log_probs, values, _ = net(obs[2:], rollout_state)
    params = list(net.parameters())
    grads = torch.autograd.grad(log_probs[:, 0, 0].sum() + values.sum(), params)
    assert all(g.abs().sum() > 0 for g in grads)
    assert {n.split(".")[0] for n, _ in net.named_parameters()} >= {"lstm", "torso"}


class CountingModel(nn.Module):
    """A stand-in LSTM net: the state counts each episode's steps, and the forward checks that
    every row of the batch sees its own episode's count (the observation holds it)."""

    def __init__(self):
        super().__init__()
        self.rows_seen = []

    def initial_state(self, batch):
        return torch.zeros(batch, 1), torch.zeros(batch, 1)

    def forward(self, obs, state):
        steps = obs[0, :, 0, 0, 0].float()
        assert torch.equal(state[0][:, 0], steps), (state[0][:, 0], steps)
        self.rows_seen.append(obs.shape[1])
        log_probs = torch.full((1, obs.shape[1], 2), math.log(0.5))
        return log_probs, torch.zeros(1, obs.shape[1]), (state[0] + 1, state[1])


class FixedLengthEnv:
    def __init__(self, length):
        self.length, self.t = length, 0

    def reset(self, seed=None):
        self.t = 0
        return np.zeros((4, 84, 84), dtype=np.uint8), {}

    def step(self, action):
        self.t += 1
        done = self.t == self.length
        obs = np.full((4, 84, 84), self.t, dtype=np.uint8)
        return obs, 0.0, done, False, {"episode": {"r": float(self.length), "l": self.length}}


def test_lstm_evaluation_carries_a_state_per_episode():
    import a3c_runtime

    model = CountingModel()
    scores = a3c_runtime.play_episodes(model, [FixedLengthEnv(n) for n in (2, 5, 3)])
    np.testing.assert_array_equal(scores, [2, 5, 3])
    assert model.rows_seen == [3, 3, 2, 1, 1]  # the finished episodes' rows leave the batch


# ---------------------------------------------------------------------------------------------
# End to end: each script on tiny budgets, with the flags of tests/test_runtime_a3c.py


def saved_checkpoint(name: str, folder: Path, *flags: str) -> Path:
    """A checkpoint of the script's network built with these flags, as a run at step 0 writes it
    (no training: what is tested is what the checkpoint holds and how the script reads it)."""
    module = load_script(name)
    args = runtime.resolve_defaults(tyro.cli(module.Args, args=["--num-workers", "1", *flags]))
    path = folder / "checkpoint.pt"
    shared = shared_for(module, args)
    runtime.save_checkpoint(path, shared, args, 0.0, module.AGENT.script)
    return path


@pytest.mark.parametrize("name", ["a3c_lws", "a3c_lstm"])
def test_evaluate_plays_a_checkpoint_with_lws_buffers_and_lstm_states(
    tmp_path, monkeypatch, capsys, name
):
    """--evaluate is the runtime's; LWS's fixed-centroid buffers and LSTM's recurrent states are
    the variants' own, so the checkpoint's network must play whole episodes."""
    flags = ["--no-lws-trainable"] if name == "a3c_lws" else []
    checkpoint = saved_checkpoint(name, tmp_path, *flags)
    argv = ["--evaluate", str(checkpoint), "--eval-episodes", "3"]
    code, err = main_exit(load_script(name), argv, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0, err
    assert len(re.findall(r"^episode \d: score [01]$", out, re.M)) == 3


def test_lws_fixed_group_wise_centroids_resume_only_with_their_seed(tmp_path, monkeypatch, capsys):
    """Fixed centroids come from --seed: resuming with another seed would silently change them."""
    flags = ["--no-lws-trainable", "--lws-centroids", "group"]
    checkpoint = saved_checkpoint("a3c_lws", tmp_path, *flags)
    saved = read_checkpoint(checkpoint)
    assert saved["model"]["torso.0.centroids"].shape == (3, 1, 2)  # buffers, saved
    argv = [*flags, "--seed", "2", "--resume", str(checkpoint), "--total-timesteps", "1000"]
    code, err = main_exit(load_script("a3c_lws"), argv, monkeypatch, capsys)
    assert code == 2 and "--seed 2 differs from the run's 1" in err


# The thesis's figures as run (thesis-notes.md "As run"): the non-default flags
AS_RUN = {
    "a3c_ss": ["--conv-layout", "final", "--ss-temperature", "global",
               "--no-ss-trainable-temperature", "--optimizer", "adam", "--adam-beta2", "0.999"],
    "a3c_ww": ["--conv-layout", "final", "--ss-temperature", "global"],
    "a3c_lws": ["--lws-similarity", "matrix", "--lws-padding", "same",
                "--lws-second-layer-maps", "32", "--lws-kernel-init", "uniform-sqrt3",
                "--lws-kcps", "4", "--lws-centroid-init", "grid", "--lws-centroids", "group",
                "--no-lws-trainable"],
}  # fmt: skip


@pytest.mark.parametrize("name", AS_RUN)
def test_as_run_flags_evaluate_and_resume_only_with_the_same_network(
    tmp_path, monkeypatch, capsys, name
):
    module = load_script(name)
    checkpoint = saved_checkpoint(name, tmp_path, *AS_RUN[name])
    argv = ["--evaluate", str(checkpoint), "--eval-episodes", "1"]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 0, err  # the checkpoint's flags rebuild its network
    # a resumed run keeps its network's flags: left out, they come from the checkpoint; one
    # given with another value is refused
    flag, value, default = ("--conv-layout", "final", "ff") if name != "a3c_lws" else (
        "--lws-padding", "same", "valid")  # fmt: skip
    loaded = runtime.load_checkpoint(str(checkpoint), module.AGENT)
    args = module.Args(resume=str(checkpoint))
    resumed = runtime.resume.resumed_args(module.AGENT, loaded, args, set())
    assert getattr(resumed, flag[2:].replace("-", "_")) == value
    code, err = main_exit(module, ["--resume", str(checkpoint), flag, default], monkeypatch, capsys)
    assert code == 2
    assert f"{flag} {default} differs from the run's {value}" in err


@pytest.mark.parametrize(
    ("name", "flags", "message"),
    [
        ("a3c_ss", ["--conv-layout", "nine"], "'ff', 'final'"),
        ("a3c_ww", ["--conv-layout", "nine"], "'ff', 'final'"),
        ("a3c_ss", ["--adam-beta2", "1"], "error: --adam-beta2 must be in [0, 1) (got 1.0)"),
        ("a3c_lws", ["--lws-similarity", "cosine"], "'sigma', 'matrix'"),
        ("a3c_lws", ["--lws-padding", "full"], "'valid', 'same'"),
        ("a3c_lws", ["--lws-kernel-init", "he"], "'default', 'uniform-sqrt3'"),
        ("a3c_lws", ["--lws-centroid-init", "ring"], "'uniform', 'grid'"),
        ("a3c_lws", ["--lws-second-layer-maps", "0"], "error: --lws-second-layer-maps must"),
        ("a3c_lws", ["--lws-centroid-init", "grid"], "error: --lws-centroid-init grid needs"),
    ],
)
def test_bad_as_run_flags_exit_2_naming_the_valid_values(
    tmp_path, monkeypatch, capsys, name, flags, message
):
    monkeypatch.chdir(tmp_path)
    code, err = main_exit(
        load_script(name), [*flags, "--total-timesteps", "100"], monkeypatch, capsys
    )
    assert code == 2 and list(tmp_path.iterdir()) == []
    if message.startswith("error: "):  # ours: one line
        assert err.strip().splitlines() == [err.strip()], err
        assert err.startswith(message), err
    else:  # tyro's box around a Literal's choices; unwrap it
        assert message in re.sub(r"[\s│|]+", " ", err), err
