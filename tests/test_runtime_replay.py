"""a3c_runtime.replay: the learning forward over a rollout takes back the Conv2d and Linear
outputs that acting computed with the same synced network, instead of computing them again; its
gradients are those of recomputing. Which forwards record and replay is chosen by their input
(rows of the rollout buffer or not) and the grad mode, so the worker loops never mention it."""

import copy

import a3c_runtime as runtime
import pytest
import torch
import torch.nn as nn
from conftest import SCRIPTS, load_script, shared_for, tiny_args

# the relative error allowed in every gradient, replayed against recomputed in the same
# precision: fp32 differs by float rounding only, bf16 by the kernels' batch sizes. bf16-learn
# replays the fp32 activations of acting where recomputing makes bf16 ones, so it is held to
# fp32's recomputation, as near as bf16 gradients get (recomputing in bf16 strays 4-9%); a
# replay of the wrong rows is off by O(1)
TOLERANCE = {"fp32": 1e-4, "bf16": 2e-2, "bf16-learn": 0.1}
# a3c_ss: the spatial softmax ignores a constant per map, so those biases get no gradient
NO_GRADIENT = {"a3c_ss": {"torso.2.bias"}}


def test_a_linear_layer_replays_what_acting_recorded_and_backpropagates_by_hand():
    """y = W x + b: the replay returns the recorded y, not one computed with the layer's current
    weights, and its backward gives dL/dW = g^T x, dL/db = sum g, dL/dx = g W by hand."""
    layer = nn.Linear(2, 2)
    with torch.no_grad():
        layer.weight.copy_(torch.tensor([[1.0, 2.0], [3.0, 4.0]]))
        layer.bias.copy_(torch.tensor([0.5, -0.5]))
    inputs = torch.tensor([[1.0, -1.0], [2.0, 0.5]], requires_grad=True)  # the rollout's frames
    runtime.ActivationReplay(layer, inputs)
    with torch.inference_mode():
        for t in range(2):
            layer(inputs[t, None])  # acting: one state per step
    torch.testing.assert_close(layer.recorded, torch.tensor([[-0.5, -1.5], [3.5, 7.5]]))
    with torch.inference_mode():
        layer.recorded += 100.0  # a replay now differs from a recomputation
    y = layer(inputs)
    torch.testing.assert_close(y, torch.tensor([[99.5, 98.5], [103.5, 107.5]]))  # the recording
    g = torch.tensor([[1.0, 0.0], [0.0, 2.0]])
    grad_x, grad_w, grad_b = torch.autograd.grad(y, (inputs, layer.weight, layer.bias), g)
    torch.testing.assert_close(grad_w, torch.tensor([[1.0, -1.0], [4.0, 1.0]]))  # g^T x
    torch.testing.assert_close(grad_b, torch.tensor([1.0, 2.0]))
    torch.testing.assert_close(grad_x, torch.tensor([[1.0, 2.0], [6.0, 8.0]]))  # g W


def test_rows_acting_never_saw_are_computed_and_other_tensors_are_not_recorded():
    torch.manual_seed(0)
    layer = nn.Linear(3, 2)
    x = torch.randn(3, 3)
    runtime.ActivationReplay(layer, x)
    with torch.inference_mode():
        layer(x[:1])
        layer(torch.randn(5, 3))  # not rows of the rollout: e.g. V(s_last) of a truncation
        layer(x[1:2])
    assert layer.count == 2
    y = layer(x)  # row 2 (the bootstrap state) was not recorded
    torch.testing.assert_close(y, nn.functional.linear(x, layer.weight, layer.bias))


def test_rows_acting_never_saw_are_computed_in_actings_precision():
    """bf16-learn acts in fp32 and learns under bf16 autocast: the bootstrap row s_n, which
    acting never saw, is computed in fp32 like the rows it did see, not in bf16."""
    torch.manual_seed(0)
    layer = nn.Linear(64, 8)
    x = torch.randn(3, 64)
    runtime.ActivationReplay(layer, x)
    act, learn = runtime.autocast_contexts("bf16-learn")
    with torch.inference_mode(), act:
        layer(x[:1])
        layer(x[1:2])
    with learn:
        y = layer(x)
    assert y.dtype == torch.float32
    fp32 = nn.functional.linear(x, layer.weight, layer.bias)
    torch.testing.assert_close(y, fp32, rtol=1e-6, atol=1e-6)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        bf16 = layer.compute(x[2:])  # what the row would be under the learning autocast
    assert (bf16.float() - fp32[2:]).abs().max() > 1e-3  # so the check above can fail


def test_a_linear_layer_over_more_dimensions_replays_its_rows():
    """A Linear applied to (T, B, ..., features), as the LSTM's heads are to (T, B, cells):
    acting records the rows of each step, and the replay takes them back in that order."""
    torch.manual_seed(0)
    layer = nn.Linear(3, 2)
    x = torch.randn(3, 2, 4, 3)  # T = 3 steps of B = 2, 4 positions each
    runtime.ActivationReplay(layer, x)
    with torch.inference_mode():
        for t in range(2):
            layer(x[t, None])  # acting: (1, B, 4, features)
    assert layer.count == 2 * 2 * 4
    y = layer(x)  # step 2 was not recorded
    torch.testing.assert_close(y, nn.functional.linear(x, layer.weight, layer.bias))


def test_a_replay_that_leaves_recorded_rows_is_an_error():
    layer = nn.Linear(3, 2)
    frames = torch.randn(7, 3)
    replay = runtime.ActivationReplay(layer, frames)
    with torch.inference_mode():
        layer(frames[:4])
    with pytest.raises(RuntimeError, match="1 recorded rows .* were not replayed"):
        layer(frames[:3])
    assert replay.mode is None and layer.count == 0  # the next rollout starts afresh


def test_the_layers_stay_what_they_were():
    """Same parameters, names and state_dict; on any tensor but the rollout's a plain forward."""
    module = load_script("a3c_ff")
    torch.manual_seed(0)
    model = module.ActorCritic(3, tiny_args(module))
    plain = copy.deepcopy(model)
    frames = torch.zeros(3, 4, 84, 84, dtype=torch.uint8)
    replay = runtime.ActivationReplay(model, frames)
    assert len(replay.layers) == 5  # 2 convs, the FC layer, the two heads
    assert all(isinstance(layer, (nn.Conv2d, nn.Linear)) for layer in replay.layers)
    assert list(model.state_dict()) == list(plain.state_dict())
    obs = torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8)
    torch.testing.assert_close(model(obs), plain(obs))
    with torch.inference_mode():
        model(obs)
    assert all(layer.count == 0 for layer in replay.layers)  # nothing recorded


@pytest.mark.parametrize("precision", ["fp32", "bf16", "bf16-learn"])
@pytest.mark.parametrize("name", SCRIPTS)
def test_replayed_gradients_are_those_of_recomputing(name, precision, one_thread):
    """A worker's rollout of T = 3 steps of K = 2 envs, acted one step at a time, then the
    learning pass over the T + 1 states (the last one a bootstrap state acting never saw): the
    replaying network's values and gradients match the same network's recomputation (see
    TOLERANCE)."""
    module = load_script(name)
    args = tiny_args(module, precision=precision)
    torch.manual_seed(1)
    plain = module.AGENT.build_network(3, args)
    model = copy.deepcopy(plain)
    act, learn = runtime.autocast_contexts(precision)
    obs = torch.randint(0, 256, (4, 2, 4, 84, 84), dtype=torch.uint8)
    runtime.ActivationReplay(model, obs)
    lstm = name == "a3c_lstm"
    state = model.initial_state(2) if lstm else None
    with torch.inference_mode(), act:
        for t in range(3):
            if lstm:
                state = model(obs[t, None], state)[2]
            else:
                model(obs[t])

    def loss_and_grads(network, learn=learn):
        with learn:
            if lstm:
                log_probs, values, _ = network(obs, network.initial_state(2))
                log_probs, values = log_probs.flatten(0, 1), values.flatten(0, 1)
            else:
                log_probs, values = network(obs.flatten(0, 1))
        log_probs, values = log_probs.float(), values.float()
        returns = torch.linspace(-1, 1, 6)
        loss = module.a3c_loss(log_probs[:6], torch.tensor([0, 1, 2, 2, 1, 0]), values[:6],
                               returns, args.ent_coef, args.vf_coef)[0]  # fmt: skip
        params = [p for p in network.parameters() if p.requires_grad]
        return values, torch.autograd.grad(loss, params, allow_unused=True)

    reference = runtime.autocast_contexts("fp32" if precision == "bf16-learn" else precision)[1]
    plain_values, plain_grads = loss_and_grads(plain, reference)
    values, grads = loss_and_grads(model)
    tolerance = TOLERANCE[precision]
    torch.testing.assert_close(values, plain_values, rtol=tolerance, atol=tolerance)
    names = [n for n, p in plain.named_parameters() if p.requires_grad]
    for key, grad, plain_grad in zip(names, grads, plain_grads, strict=True):
        if plain_grad is None or key in NO_GRADIENT.get(name, ()):
            assert grad is None or grad.abs().max() < 1e-4, key
            continue
        assert grad.dtype == torch.float32, key
        error = (grad - plain_grad).norm() / plain_grad.norm().clamp_min(1e-12)
        assert error < tolerance, f"{key}: relative error {error:.2e}"


@pytest.mark.parametrize("name", SCRIPTS)
def test_the_workers_learning_pass_computes_no_recorded_layer_again(name, one_thread):
    """In each script's worker with K = 2 envs, the learning forwards compute Conv2d outputs only
    for states that acting did not see: with Catch's 15-step episodes and t_max 20 every rollout
    ends with its episodes, so none at all, while acting computes one row per env and step."""
    module = load_script(name)
    args = tiny_args(module, total_timesteps=90, t_max=20, precision="fp32", envs_per_worker=2)
    shared = shared_for(module, args)
    rows = {True: 0, False: 0}  # by inference mode: acting, learning
    forward = nn.Conv2d.forward

    def counting_forward(self, x):
        rows[torch.is_inference_mode_enabled()] += x.shape[0]
        return forward(self, x)

    nn.Conv2d.forward = counting_forward
    try:
        module.worker(0, shared, args)
    finally:
        nn.Conv2d.forward = forward
    convs = sum(isinstance(m, nn.Conv2d) for m in shared.model.modules())
    assert shared.global_step() == 90 and shared.stats[0, 3] == 3  # 3 updates of 2 x 15 states
    assert rows == {True: 90 * convs, False: 0}


@pytest.mark.parametrize(
    ("flags", "replays"),
    [
        ({"envs_per_worker": 2, "precision": "bf16"}, True),
        ({"envs_per_worker": 2, "precision": "fp32"}, True),
        ({"envs_per_worker": 1, "precision": "fp32"}, False),
        ({"envs_per_worker": 2, "precision": "bf16-learn"}, False),
        ({"envs_per_worker": 2, "precision": "bf16", "env": "BreakoutNoFrameskip-v4"}, False),
    ],
)
def test_the_replay_runs_only_where_it_measured_faster(flags, replays):
    """Catch with K > 1 in bf16 or fp32 (the gains in replay_activations' docstring); K = 1,
    bf16-learn and Atari gained under 5% (results/replay_measurement): there the model stays
    plain."""
    module = load_script("a3c_ff")
    args = tiny_args(module, **flags)
    model = module.ActorCritic(4 if "env" in flags else 3, args)
    frames = torch.zeros(21, args.envs_per_worker, 4, 84, 84)
    replay = runtime.replay_activations(model, frames, args)
    assert (replay is not None) == replays
    plain = all(type(m) in (nn.Conv2d, nn.Linear) for m in model.modules() if hasattr(m, "weight"))
    assert plain != replays
    assert not replays or len(replay.layers) == 5


def test_a_learning_forward_that_does_not_start_at_the_first_acting_state_is_an_error():
    layer = nn.Linear(3, 2)
    frames = torch.randn(5, 3)
    runtime.ActivationReplay(layer, frames)
    with torch.inference_mode():
        layer(frames[0:1])
        layer(frames[1:2])
    with pytest.raises(RuntimeError, match="must start at the rollout's first acting state"):
        layer(frames[1:4])  # shifted by one: it would replay the wrong rows


class TiedLayers(nn.Module):
    """One layer called twice in a forward (weight tying): its rows would interleave."""

    def __init__(self):
        super().__init__()
        self.fc = nn.Linear(3, 3)

    def forward(self, x):
        return self.fc(torch.tanh(self.fc(x)))


def test_a_layer_called_twice_in_one_forward_is_refused_by_name():
    net, frames = TiedLayers(), torch.randn(5, 3)
    runtime.ActivationReplay(net, frames)
    with (
        pytest.raises(RuntimeError, match="layer 'fc' is called more than once"),
        torch.inference_mode(),
    ):
        net(frames[:1])


class PaddedConv(nn.Module):
    def __init__(self, **conv):
        super().__init__()
        self.conv = nn.Conv2d(1, 1, 3, **conv)

    def forward(self, x):
        return self.conv(x)


class ScaledLinear(nn.Linear):
    def forward(self, x):
        return 2 * super().forward(x)


@pytest.mark.parametrize(
    ("model", "reason"),
    [
        (PaddedConv(padding="same"), "layer 'conv': its padding is 'same'"),
        (PaddedConv(padding=1, padding_mode="reflect"), "layer 'conv': its padding mode"),
        (
            nn.Sequential(nn.Linear(3, 3), ScaledLinear(3, 3)),
            "layer '1': ScaledLinear is a subclass",
        ),
    ],
)
def test_a_layer_it_cannot_replay_is_refused_by_name(model, reason):
    with pytest.raises(RuntimeError, match=f"cannot replay {reason}"):
        runtime.ActivationReplay(model, torch.zeros(3, 1, 5, 5))


def acted(layer: nn.Module, frames: torch.Tensor, steps: int) -> None:
    with torch.inference_mode():
        for t in range(steps):
            layer(frames[t : t + 1])


@pytest.mark.parametrize(
    ("learn", "message"),
    [
        (lambda frames: frames[1:], "must start at the rollout's first acting state"),
        (lambda frames: frames[::2], "not acting's rows in acting's order"),
    ],
)
def test_a_learning_pass_over_other_states_is_refused(learn, message):
    layer, frames = nn.Linear(3, 2), torch.randn(6, 3)
    runtime.ActivationReplay(layer, frames)
    acted(layer, frames, 3)
    with pytest.raises(RuntimeError, match=message):
        layer(learn(frames))
    acted(layer, frames, 2)  # the next rollout starts afresh
    torch.testing.assert_close(
        layer(frames[:3]), nn.functional.linear(frames[:3], layer.weight, layer.bias)
    )


def test_acting_out_of_order_is_refused_at_the_update():
    layer, frames = nn.Linear(3, 2), torch.randn(6, 3)
    runtime.ActivationReplay(layer, frames)
    with torch.inference_mode():
        layer(frames[0:1])
        layer(frames[2:3])  # a row skipped: the recording's rows are not the buffer's
    with pytest.raises(RuntimeError, match="acting did not step through the rollout's rows"):
        layer(frames[:3])


def test_weights_changed_between_acting_and_learning_are_refused():
    layer, frames = nn.Linear(3, 2), torch.randn(6, 3)
    runtime.ActivationReplay(layer, frames)
    acted(layer, frames, 2)
    with torch.no_grad():
        layer.weight.add_(1.0)  # e.g. theta' synced again before the update
    with pytest.raises(RuntimeError, match="layer 'Linear''s weights changed"):
        layer(frames[:3])


class StatefulBetween(nn.Module):
    """fc2 sees fc1's output plus a state, as an LSTM's heads see its cell's: the learning pass
    must bring the state acting had."""

    def __init__(self):
        super().__init__()
        self.fc1, self.fc2, self.state = nn.Linear(3, 3), nn.Linear(3, 2), 0.0

    def forward(self, x):
        return self.fc2(torch.tanh(self.fc1(x)) + self.state)


def test_a_layer_fed_other_inputs_in_the_learning_pass_is_refused_by_name():
    """A recurrent state started wrong in the learning pass: fc2's replayed outputs would be
    acting's for other inputs (a wrong value, with no error from the rows or the order)."""
    torch.manual_seed(0)
    net, frames = StatefulBetween(), torch.randn(4, 3)
    runtime.ActivationReplay(net, frames)
    acted(net, frames, 3)
    torch.testing.assert_close(net(frames[:4]), net.fc2(torch.tanh(net.fc1(frames[:4]))))
    acted(net, frames, 3)
    net.state = 0.5  # the learning pass's state is not acting's
    with pytest.raises(RuntimeError, match="layer 'fc2' gets other inputs in the learning forward"):
        net(frames[:4])
