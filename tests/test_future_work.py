"""Tests of the thesis's future work (chapter 8), each idea a script of its own in
agents/future_work/: the prototype value head (learning vector regression), prototypes from the
data and dynamic prototypes on LPQ and GLPQ, and online local weight sharing (centroids predicted
per sample) on LWS; against hand-computed values, a thesis script's refusal of their checkpoints,
then end to end."""

import math

import numpy as np
import pytest
import torch
from a3c_runtime import UsageError
from conftest import evaluation_steps, load_script, main_exit, read_checkpoint

TINY = ["--num-workers", "2", "--eval-episodes", "2", "--log-interval", "1"]


def scripts(idea: str) -> pytest.fixture:
    @pytest.fixture(scope="module", params=[f"a3c_lpq_{idea}", f"a3c_glpq_{idea}"])
    def fixture(request):
        return load_script(request.param)

    return fixture


value_script = scripts("value_head")
data_script = scripts("data_init")
growth_script = scripts("growth")


def network(script, **flags):
    import a3c_runtime

    import catch_env  # noqa: F401  (registers Catch-v0)

    args = a3c_runtime.resolve_defaults(script.Args(**flags))
    return script.ActorCritic(3, args), args


# ---------------------------------------------------------------------------------------------
# The prototype value head: V = sum_j softmax_j(-beta d_j) v_j
# ---------------------------------------------------------------------------------------------
def test_prototype_regression_by_hand(value_script):
    script = value_script
    distances = torch.tensor([[0.0, 1.0], [2.0, 2.0]])
    values = torch.tensor([1.0, 3.0])
    # row 1: weights e^0 : e^-1 = 0.7311 : 0.2689; row 2: equal weights
    expected = [(1 + 3 * math.exp(-1)) / (1 + math.exp(-1)), 2.0]
    torch.testing.assert_close(script.prototype_regression(distances, 1.0, values),
                               torch.tensor(expected))  # fmt: skip
    # beta = 0.5 halves the distances: weights e^0 : e^-0.5
    half = (1 + 3 * math.exp(-0.5)) / (1 + math.exp(-0.5))
    assert script.prototype_regression(distances, 0.5, values)[0].item() == pytest.approx(half)


def test_the_value_head_on_the_network_by_hand(value_script):
    """Two value prototypes in the 256-d feature space, h on the first: V by hand."""
    model, _ = network(value_script, value_prototypes=2)
    h = torch.zeros(1, 256)
    with torch.no_grad():
        model.value_prototypes.zero_()
        model.value_prototypes[1, 0] = 1.0  # |h - u_2|^2 = 1
        model.prototype_values.copy_(torch.tensor([-1.0, 2.0]))
        model.log_value_beta.fill_(math.log(2.0))  # weights e^0 : e^-2
    expected = (-1 + 2 * math.exp(-2)) / (1 + math.exp(-2))
    assert model.state_value(h).item() == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("scale", [1.0, 1e3, 1e5])  # Catch's unscaled features reach 1e3-1e5
def test_the_value_head_has_finite_gradients_and_only_the_value_loss_trains_it(value_script, scale):
    model, _ = network(value_script)
    hidden = (torch.rand(5, 256) * scale).requires_grad_()
    log_probs = model.log_policy(hidden)
    values = model.state_value(hidden)
    assert torch.isfinite(values).all()
    value_params = [model.value_prototypes, model.prototype_values, model.log_value_beta]
    value_grads = torch.autograd.grad(values.square().sum(), [*value_params, model.prototypes],
                                      allow_unused=True)  # fmt: skip
    assert all(torch.isfinite(g).all() for g in value_grads[:-1])
    assert value_grads[-1] is None  # the policy prototypes: no gradient from the value loss
    policy_grads = torch.autograd.grad(log_probs[:, 0].sum(), value_params, allow_unused=True)
    assert all(g is None for g in policy_grads)  # and the value head none from the policy


def test_the_value_head_replaces_the_linear_critic(value_script):
    model, _ = network(value_script)
    assert not hasattr(model, "value") and model.value_prototypes.shape == (16, 256)
    obs = torch.randint(0, 256, (3, 4, 84, 84), dtype=torch.uint8)
    _, values = model(obs)
    hidden = model.torso(obs.float().contiguous(memory_format=torch.channels_last))
    torch.testing.assert_close(values, model.state_value(hidden))


def test_bad_value_prototypes_is_a_usage_error(value_script):
    with pytest.raises(UsageError, match="--value-prototypes must be >= 1"):
        network(value_script, value_prototypes=0)


def test_a_value_prototype_learns_the_value_of_its_states(value_script):
    """Gradient descent on 0.5 (G - V)^2 moves each v_j toward the returns of the states it
    covers: two separated clusters of features with returns 1 and -1."""
    model, _ = network(value_script, value_prototypes=2)
    with torch.no_grad():
        model.value_prototypes.zero_()
        model.value_prototypes[1, :] = 1.0
    hidden = torch.cat([torch.zeros(8, 256), torch.ones(8, 256)])
    returns = torch.cat([torch.ones(8), -torch.ones(8)])
    optimizer = torch.optim.SGD([model.prototype_values], lr=0.05)
    for _ in range(200):
        optimizer.zero_grad()
        (0.5 * (returns - model.state_value(hidden)).square().sum()).backward()
        optimizer.step()
    torch.testing.assert_close(model.prototype_values.detach(), torch.tensor([1.0, -1.0]),
                               atol=1e-3, rtol=0)  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Prototypes from the data (a3c_*_data_init.py)
# ---------------------------------------------------------------------------------------------
def test_place_prototypes_puts_each_prototype_on_a_distinct_feature(data_script):
    model, _ = network(data_script)
    hidden = torch.arange(100 * 256, dtype=torch.float32).view(100, 256) / 1000
    model.place_prototypes(hidden, np.random.default_rng(0))
    rows = [int(torch.where((hidden == p).all(1))[0][0]) for p in model.prototypes.detach()]
    assert len(set(rows)) == len(rows) == 48  # distinct rows: 100 features for 48 prototypes


def test_data_initialisation_on_catch_places_prototypes_at_the_features_scale(data_script):
    """On Catch's unscaled frames the features are far from U(-1/16, 1/16) prototypes: the
    uniform init puts every prototype at about |h|^2 from h, the data init at 0 from some h."""
    script = data_script
    torch.manual_seed(3)  # as train's seed_everything before it builds the network
    model, args = network(script, seed=3)
    uniform = model.prototypes.detach().clone()
    script.AGENT.initialize(model, args)  # what train does for a new run
    frames = script.random_play_frames("Catch-v0", np.random.default_rng(3), 3)
    assert frames.shape == (script.DATA_INIT_STEPS * script.DATA_INIT_ENVS, 4, 84, 84)
    # every step's states, not 32 copies of the last (the vector env reuses its buffer)
    distinct = np.unique(frames.reshape(len(frames), -1), axis=0)
    assert len(distinct) > 4 * script.DATA_INIT_ENVS
    with torch.no_grad():
        hidden = model.features(torch.from_numpy(frames))
        nearest_uniform = script.prototype_distances(hidden, uniform, "squared-euclidean")
        placed = script.prototype_distances(hidden, model.prototypes, "squared-euclidean")
    # every prototype sits on a feature of the random play's states, each on its own
    assert placed.amin(0).max().item() == pytest.approx(0.0, abs=1e-2)
    assert len(torch.unique(model.prototypes.detach(), dim=0)) == len(model.prototypes)
    assert nearest_uniform.amin(0).min().item() > 100
    torch.manual_seed(3)
    again, _ = network(script, seed=3)
    script.initialize_network(again, args)
    torch.testing.assert_close(again.prototypes, model.prototypes)  # seeded


def test_the_thesis_initialisation_is_one_flag_away(data_script):
    model, args = network(data_script, prototype_init="uniform")
    before = model.prototypes.detach().clone()
    data_script.initialize_network(model, args)
    torch.testing.assert_close(model.prototypes.detach(), before)


# ---------------------------------------------------------------------------------------------
# Dynamic prototypes (a3c_*_growth.py): masked slots, grow_and_prune, maintain_prototypes
# ---------------------------------------------------------------------------------------------
def growth_case(idle_slot_wins: bool):
    """4 states, 2 actions, 3 slots each; action 0 has slots 0 and 1 active, action 1 slot 0.
    States 0-2 took action 0, state 3 action 1."""
    active = torch.tensor([[True, True, False], [True, False, False]])
    distances = torch.full((4, 2, 3), 50.0)
    distances[0, 0] = torch.tensor([1.0, 5.0, 0.0])  # free slots' distances must not count
    distances[1, 0] = torch.tensor([6.0, 2.0, 0.0] if idle_slot_wins else [2.0, 6.0, 0.0])
    distances[2, 0] = torch.tensor([9.0, 20.0, 0.0])
    distances[3, 1] = torch.tensor([3.0, 0.0, 0.0])
    return distances, torch.tensor([0, 0, 0, 1]), active


def test_grow_and_prune_by_hand(growth_script):
    script = growth_script
    # nearest to the taken action's active prototypes: 1, 2, 9, 3 -> mean 3.75, so ratio 2
    # grows where a state is more than 7.5 away: state 2 for action 0 (9); action 1's only
    # state is 3 away. Slot 1 of action 0 is no state's nearest: pruned,
    # and the new prototype takes its slot.
    pruned, grown = script.grow_and_prune(*growth_case(False), ratio=2.0)
    assert (pruned, grown) == ({0: 1}, {0: (1, 2)})
    # slot 1 now wins state 1: nothing to prune; the new prototype goes to the free slot 2
    pruned, grown = script.grow_and_prune(*growth_case(True), ratio=2.0)
    assert (pruned, grown) == ({}, {0: (2, 2)})
    # ratio 2.5 (9.375 > 9): no growth; an action's last prototype is never pruned
    pruned, grown = script.grow_and_prune(*growth_case(False), ratio=2.5)
    assert (pruned, grown) == ({0: 1}, {})


def growth_network(script, **flags):
    flags = {"prototypes_per_action": 2, "max_prototypes_per_action": 3, **flags}
    return network(script, **flags)


def test_free_slots_change_nothing_and_get_no_gradient(growth_script):
    """The policy with a free slot (placed right on h, where it would dominate) is the policy of
    the active prototypes alone; gradients are finite and the mask's is exactly 0."""
    # k = 2 in both: GLPQ's hot tau counts k |A| competitors (with growth k defaults to the slots)
    model, _ = growth_network(growth_script, competition_size=2)
    assert model.prototypes.shape == (9, 256) and model.active_slots().sum().item() == 6
    hidden = torch.rand(5, 256) * 30
    with torch.no_grad():
        model.prototypes.view(3, 3, 256)[:, 2] = hidden[0]  # the free slots, on h
    log_probs = model.log_policy(hidden)
    thesis = load_script(growth_script.__name__.removesuffix("_growth"))
    active_only, _ = network(thesis, prototypes_per_action=2, competition_size=2)
    with torch.no_grad():
        active_only.prototypes.copy_(model.prototypes.view(3, 3, 256)[:, :2].reshape(6, 256))
    torch.testing.assert_close(log_probs, active_only.log_policy(hidden))
    grads = torch.autograd.grad(log_probs[:, 1].sum(), [model.prototypes, model.prototype_active])
    assert torch.isfinite(grads[0]).all()
    assert grads[0].view(3, 3, 256)[:, 2].abs().max() == 0  # free slots: no gradient
    assert grads[1].abs().max() == 0


@pytest.mark.parametrize("mu_form", ["text", "code"])
@pytest.mark.parametrize("parametrization", ["log", "plain"])
def test_free_slots_give_a_trainable_tau_a_finite_gradient(mu_form, parametrization):
    """GLPQ's free slots are masked after the product with tau: masking the scores before it
    would make tau's gradient 0 * -inf = NaN (the default k counts every slot)."""
    glpq = load_script("a3c_glpq_growth")
    model, _ = network(glpq, temperature="trainable", mu_form=mu_form,
                       tau_parametrization=parametrization)  # fmt: skip
    hidden = torch.rand(6, 256) * 30
    log_probs = model.log_policy(hidden)
    tau = model.log_tau if parametrization == "log" else model.plain_tau
    (grad,) = torch.autograd.grad(log_probs[:, 0].sum(), [tau])
    assert torch.isfinite(log_probs).all() and torch.isfinite(grad) and grad != 0


def test_bad_growth_flags_are_usage_errors(growth_script):
    with pytest.raises(UsageError, match="--max-prototypes-per-action"):
        growth_network(growth_script, prototypes_per_action=4)  # 3 slots < 4
    with pytest.raises(UsageError, match="--growth-interval"):
        growth_network(growth_script, growth_interval=0)


def test_maintain_prototypes_grows_on_the_policys_states(growth_script):
    """On Catch, with a tiny ratio every action that the policy took gains a prototype on one of
    its states' features, in a free or pruned slot, with its optimizer statistics restarted;
    every action keeps at least one prototype, and nothing happens before the interval."""
    import types

    from a3c_runtime.hogwild import RMSprop

    script = growth_script
    torch.manual_seed(0)
    model, args = growth_network(script, growth_ratio=1e-6, growth_interval=100, seed=2)
    params = list(model.parameters())
    optimizer = RMSprop(params, 0.99, 0.1, initial=0.0)
    shared = types.SimpleNamespace(model=model, params=params, optimizer=optimizer)
    index = next(i for i, p in enumerate(params) if p is model.prototypes)
    shared.optimizer.square_avg[index].fill_(5.0)
    before = model.prototypes.detach().clone()
    script.maintain_prototypes(shared, args, 0)
    script.maintain_prototypes(shared, args, 99)
    torch.testing.assert_close(model.prototypes.detach(), before)  # not yet
    script.maintain_prototypes(shared, args, 100)
    active = model.active_slots()
    assert (active.sum(1) >= 1).all() and (active.sum(1) <= 3).all()
    changed = (model.prototypes.detach() != before).any(1).nonzero().flatten().tolist()
    assert changed  # some action grew
    for row in changed:
        assert active.flatten()[row]
        assert shared.optimizer.square_avg[index][row].abs().max() == 0  # restarted
    unchanged = [row for row in range(9) if row not in changed]
    assert (shared.optimizer.square_avg[index][unchanged] == 5.0).all()


def test_restart_statistics_resets_the_rows_of_either_optimizer(growth_script):
    from a3c_runtime.hogwild import RMSprop, SharedAdam

    params = [torch.zeros(4, 2)]
    rmsprop, adam = (
        RMSprop(params, 0.99, 0.1, initial=1.0),
        SharedAdam(params, 0.9, 0.99, 0.1),
    )
    for statistic in (rmsprop.square_avg[0], adam.exp_avg[0], adam.exp_avg_sq[0]):
        statistic.fill_(7.0)
    growth_script.restart_statistics(rmsprop, 0, [1, 3])
    growth_script.restart_statistics(adam, 0, [2])
    assert rmsprop.square_avg[0][:, 0].tolist() == [7.0, 1.0, 7.0, 1.0]  # back to its initial 1
    assert adam.exp_avg[0][:, 0].tolist() == adam.exp_avg_sq[0][:, 0].tolist() == [7, 7, 0, 7]


def test_growth_rounds_survive_a_resume(growth_script):
    """The last growth step is in the network's state (so in the checkpoint): a run resumed
    from a checkpoint taken past a boundary whose step has not run yet runs it at once, and one
    resumed after a step does not repeat it."""
    import types

    from a3c_runtime.hogwild import RMSprop

    def shared_for(model):
        params = list(model.parameters())
        optimizer = RMSprop(params, 0.99, 0.1, initial=0.0)
        return types.SimpleNamespace(model=model, params=params, optimizer=optimizer)

    script = growth_script
    torch.manual_seed(0)
    model, args = growth_network(script, growth_ratio=1e-6, growth_interval=100, seed=2)
    script.maintain_prototypes(shared_for(model), args, 0)
    saved = {k: v.clone() for k, v in model.state_dict().items()}  # checkpoint at step 120
    resumed, _ = growth_network(script, growth_ratio=1e-6, growth_interval=100, seed=2)
    resumed.load_state_dict(saved)
    script.maintain_prototypes(shared_for(resumed), args, 120)  # the step of round 1 runs now
    assert int(resumed.growth_round) == 1
    assert not torch.equal(resumed.prototypes.detach(), saved["prototypes"])
    again, _ = growth_network(script, growth_ratio=1e-6, growth_interval=100, seed=2)
    again.load_state_dict(resumed.state_dict())
    before = again.prototypes.detach().clone()
    script.maintain_prototypes(shared_for(again), args, 150)  # round 1 is done: nothing
    torch.testing.assert_close(again.prototypes.detach(), before)


# ---------------------------------------------------------------------------------------------
# Online local weight sharing (a3c_lws_online.py)
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def lws():
    return load_script("a3c_lws")


@pytest.fixture(scope="module")
def online_lws():
    return load_script("a3c_lws_online")


def test_per_sample_similarity_by_hand(lws, online_lws):
    """Two samples with their own centroids: each sample's weights are the static formula's
    (a3c_lws.py's) for its centroids. Group-wise, S = 2, a 3x3 grid (0, 0.5, 1), Sigma = I."""
    args = online_lws.Args(lws_kcps=2, lws_centroids="group")
    layer = online_lws.LWSConv2d(4, 1, 3, 3, 9, args, torch.Generator().manual_seed(0))
    static = lws.LWSConv2d(4, 1, 3, 3, 9, lws.Args(lws_kcps=2, lws_centroids="group"),
                           torch.Generator().manual_seed(0))  # fmt: skip
    centroids = torch.tensor([[[[0.0, 0.0]], [[1.0, 1.0]]], [[[0.5, 0.5]], [[0.0, 1.0]]]])
    weights = layer.compute_similarity_weights(centroids)  # (B, H, W, S, maps)
    assert weights.shape == (2, 3, 3, 2, 1)
    # sample 0 at cell (0, 1), x = (0, 0.5): d = 0.25 and 1 + 0.25 -> 1 / (1 + e^-1)
    assert weights[0, 0, 1, 0, 0].item() == pytest.approx(1 / (1 + math.exp(-1)), rel=1e-6)
    # sample 1 at cell (2, 0), x = (1, 0): d = 0.5 and 1 + 1 = 2 -> 1 / (1 + e^-1.5)
    assert weights[1, 2, 0, 0, 0].item() == pytest.approx(1 / (1 + math.exp(-1.5)), rel=1e-6)
    for b in range(2):
        with torch.no_grad():
            static.centroids.copy_(centroids[b])
        torch.testing.assert_close(weights[b], static.compute_similarity_weights())


def online_and_static(lws, online_lws, **flags):
    import a3c_runtime

    import catch_env  # noqa: F401

    nets = []
    for script in (lws, online_lws):
        torch.manual_seed(0)
        args = a3c_runtime.resolve_defaults(script.Args(**flags))
        nets.append(script.ActorCritic(3, args))
    return nets


def test_online_centroids_start_at_the_static_ones(lws, online_lws):
    """At initialisation every sample's predicted centroids are the static initial ones (grid:
    1/3 and 2/3), so the online network computes what the static one does."""
    static, online = online_and_static(lws, online_lws, lws_kcps=4, lws_centroid_init="grid")
    online.load_state_dict(static.state_dict(), strict=False)  # the same kernels and heads
    obs = torch.randint(0, 256, (3, 4, 84, 84), dtype=torch.uint8)
    for first, second in zip(static(obs), online(obs), strict=True):
        torch.testing.assert_close(first, second, rtol=1e-4, atol=1e-5)
    predicted = online.centroid_predictor(obs.float() / 255)
    for layer, centroids in zip(online.lws_layers, predicted, strict=True):
        assert centroids.shape == (3, *layer.centroids.shape)
        torch.testing.assert_close(centroids, layer.centroids.expand_as(centroids))


def test_online_centroids_depend_on_the_input_and_learn(lws, online_lws):
    _, online = online_and_static(lws, online_lws)
    assert not any(isinstance(layer.centroids, torch.nn.Parameter) for layer in online.lws_layers)
    obs = torch.randint(0, 256, (4, 4, 84, 84), dtype=torch.uint8)
    log_probs, values = online(obs)
    params = dict(online.centroid_predictor.named_parameters())
    grads = torch.autograd.grad(values.sum() + log_probs[:, 0].sum(), list(params.values()))
    assert all(torch.isfinite(g).all() for g in grads)
    assert grads[list(params).index("heads.0.weight")].abs().sum() > 0  # the heads learn first
    with torch.no_grad():
        for head in online.centroid_predictor.heads:
            head.weight.normal_(0.0, 0.1)
    first, _ = online.centroid_predictor(obs.float() / 255)
    assert (first[0] - first[1]).abs().max() > 1e-3  # each sample its own centroids
    assert ((first > 0) & (first < 1)).all()  # frames in [0, 1]: the sigmoids not saturated


# ---------------------------------------------------------------------------------------------
# Checkpoints of the thesis scripts' old flags, and end to end
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("thesis", "flag", "value", "owner"),
    [
        ("a3c_lpq", "prototype_growth", True, "a3c_lpq_growth"),
        ("a3c_glpq", "value_head", "prototypes", "a3c_glpq_value_head"),
        ("a3c_glpq", "prototype_init", "data", "a3c_glpq_data_init"),
        ("a3c_lws", "lws_centroid_source", "online", "a3c_lws_online"),
    ],
)
def test_a_checkpoint_of_an_old_flag_belongs_to_its_script(
    tmp_path, monkeypatch, capsys, thesis, flag, value, owner
):
    """A checkpoint the thesis script wrote when the idea was its flag (the older format, a
    torch zip): converted, it is the idea's script's, which plays it; the thesis script refuses
    it with one line naming that script."""
    from dataclasses import asdict

    import a3c_runtime
    from a3c_tools import convert_checkpoint
    from conftest import run_main, shared_for, tiny_args
    from test_safe_loading import old_checkpoint

    module = load_script(owner)
    args = tiny_args(module)
    path = tmp_path / "checkpoint.pt"
    a3c_runtime.save_checkpoint(path, shared_for(module, args), args, 0.0, f"{thesis}.py")
    checkpoint = read_checkpoint(path)
    checkpoint["args"] = {**asdict(args), flag: value}  # as the old script stored its flags
    old_checkpoint(path, checkpoint)
    result = run_main(convert_checkpoint.main, [str(path)])
    assert result.returncode == 0, result.stderr
    assert read_checkpoint(path)["script"] == f"future_work/{owner}.py"
    code, err = main_exit(load_script(thesis), ["--evaluate", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1
    assert f"use python agents/future_work/{owner}.py" in err
    loaded = a3c_runtime.load_checkpoint(str(path), module.AGENT)
    a3c_runtime.load_network(module.AGENT.build_network(3, args), loaded, str(path))


@pytest.mark.slow
def test_data_init_end_to_end(tmp_path, monkeypatch, capsys):
    """The runtime's initialize hook, in a whole run (the worker loop is FF's)."""
    name = "a3c_lpq_data_init"
    budget = ["--total-timesteps", "2000", "--eval-interval", "1000", "--run-dir", str(tmp_path)]
    code, err = main_exit(load_script(name), [*TINY, *budget], monkeypatch, capsys)
    assert code == 0, err
    assert evaluation_steps(tmp_path)[-1] >= 2000
