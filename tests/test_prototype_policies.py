"""Tests of agents/a3c_lpq.py and agents/a3c_glpq.py (thesis chapter 7, appendix C): the
distances, the LPQ and GLPQ heads and the temperature against hand-computed values, then both
scripts end to end on tiny budgets."""

import itertools
import math
from pathlib import Path

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from conftest import ALL_SCRIPTS, load_script, main_exit, shared_for
from hypothesis import given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]


def load(name: str):
    return load_script(name)


@pytest.fixture(scope="module")
def lpq():
    return load("a3c_lpq")


@pytest.fixture(scope="module")
def glpq():
    return load("a3c_glpq")


def both(lpq, glpq):
    return {"lpq": lpq, "glpq": glpq}


# ---------------------------------------------------------------------------------------------
# Distances (thesis 7.2.1)
# ---------------------------------------------------------------------------------------------
H = torch.tensor([[1.0, 2.0, 2.0]])  # |h| = 3, mean 5/3
W = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])  # the middle one is zero
# by hand: h - w = [0, 2, 2], [1, 2, 2], [0, 0, -1]
EXPECTED = {
    "squared-euclidean": [8.0, 9.0, 1.0],
    "euclidean": [math.sqrt(8), 3.0, 1.0],
    "manhattan": [4.0, 5.0, 1.0],
    # 1 - h.w / (|h| |w|); the zero prototype has no direction: distance 1
    "cosine": [1 - 1 / 3, 1.0, 1 - 11 / (3 * math.sqrt(14))],
    # centred: h [-2, 1, 1] / 3, w1 [2, -1, -1] / 3 (r = -1), w2 constant (no direction),
    # w3 [-1, 0, 1]: r = 1 / (sqrt(6) / 3 * sqrt(2)) = sqrt(3) / 2
    "pearson": [2.0, 1.0, 1 - math.sqrt(3) / 2],
    "inverse-squared-euclidean": [-1 / 9, -1 / 10, -1 / 2],
}


@pytest.mark.parametrize("distance", list(EXPECTED))
def test_distances_by_hand(lpq, glpq, distance):
    got = lpq.prototype_distances(H, W, distance)
    np.testing.assert_allclose(got.numpy(), [EXPECTED[distance]], rtol=1e-6, atol=1e-7)
    if distance != "inverse-squared-euclidean":  # GLPQ needs d >= 0: it offers the others
        torch.testing.assert_close(glpq.prototype_distances(H, W, distance), got)


@pytest.mark.parametrize(
    "name", [n for n in ALL_SCRIPTS if hasattr(load_script(n), "prototype_distances")]
)
@pytest.mark.parametrize("distance", ["bogus", "zz"])  # before and after every name's spelling
def test_an_unknown_distance_is_refused_by_every_copy(name, distance):
    with pytest.raises(ValueError, match=f"unknown distance '{distance}'"):
        load_script(name).prototype_distances(H, W, distance)


@pytest.mark.parametrize("distance", ["cosine", "pearson"])
def test_zero_and_constant_vectors_give_finite_distances_and_gradients(lpq, distance):
    features = torch.tensor([[0.0, 0.0, 0.0], [2.0, 2.0, 2.0]], requires_grad=True)
    prototypes = torch.tensor([[0.0, 0.0, 0.0], [1.0, -2.0, 0.5]], requires_grad=True)
    d = lpq.prototype_distances(features, prototypes, distance)
    expected = torch.ones(2, 2)  # zero vectors have no direction, nor constant ones for Pearson
    if distance == "cosine":  # [2, 2, 2] . [1, -2, 0.5] = -1; |.| = sqrt(12), sqrt(5.25)
        expected[1, 1] = 1 + 1 / (math.sqrt(12) * math.sqrt(5.25))
    np.testing.assert_allclose(d.detach().numpy(), expected.numpy(), rtol=1e-6)
    d.sum().backward()
    assert torch.isfinite(features.grad).all() and torch.isfinite(prototypes.grad).all()


@pytest.mark.parametrize("distance", ["squared-euclidean", "euclidean", "manhattan", "cosine"])
def test_distances_stay_float32_under_bf16_autocast(lpq, glpq, distance):
    """--precision bf16 / bf16-learn run the network under bf16 autocast; the distances must not
    follow: |h|^2 - 2 h.w + |w|^2 of features near a prototype cancels to noise in bf16 (a
    distance of 0.5 came out as 0 or 38 before the fix)."""
    torch.manual_seed(0)
    features = 3 * torch.randn(4, 256) + 5
    prototypes = features.repeat_interleave(3, 0) + 0.05 * torch.randn(12, 256)
    for module in (lpq, glpq):
        expected = module.prototype_distances(features, prototypes, distance)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            got = module.prototype_distances(features.bfloat16(), prototypes, distance)
        assert got.dtype == torch.float32
        # the features' own bf16 rounding (8 bits) is all that differs
        torch.testing.assert_close(got, expected, rtol=0.02, atol=0.5)


def test_euclidean_gradient_is_finite_at_zero_distance(lpq):
    h = torch.tensor([[1.0, 2.0]], requires_grad=True)
    d = lpq.prototype_distances(h, h.detach().clone(), "euclidean")
    assert d.item() == pytest.approx(1e-6)  # sqrt of the floor SQRT_EPS
    d.sum().backward()
    assert torch.isfinite(h.grad).all()


# ---------------------------------------------------------------------------------------------
# The heads: pi is a distribution; LPQ generalises softmax; Theorem 1
# ---------------------------------------------------------------------------------------------
def configurations(module, name):
    """Every distance, competition size (1, 3, all of 4) and temperature; the three prototype
    initialisations take turns."""
    distances = list(EXPECTED) if name == "lpq" else list(EXPECTED)[:-1]
    temperatures = [None] if name == "lpq" else ["fixed", "cold", "hot", "searing", "trainable"]
    grid = itertools.product(distances, [1, 3, None], temperatures)
    for i, (distance, k, temperature) in enumerate(grid):
        extra = {} if temperature is None else {"temperature": temperature, "tau": 2.0}
        init = ["uniform", "uniform-clipped", "uniform-positive"][i % 3]
        yield module.Args(prototypes_per_action=4, distance=distance, competition_size=k,
                          prototype_init=init, **extra)  # fmt: skip


@pytest.mark.parametrize("name", ["lpq", "glpq"])
def test_the_prototype_initialisations(lpq, glpq, name):
    """U(-b, b); U(0, b), the thesis code's option; U(-b, b) with its negatives set to 0."""
    module = both(lpq, glpq)[name]
    b = 0.25
    drawn = {}
    for init in ("uniform", "uniform-positive", "uniform-clipped"):
        torch.manual_seed(0)
        args = module.Args(prototype_init=init, prototype_init_bound=b)
        drawn[init] = module.ActorCritic(3, args).prototypes.detach()
    uniform, positive, clipped = drawn.values()
    assert -b <= uniform.min() < -0.99 * b and 0.99 * b < uniform.max() <= b
    assert 0 < positive.min() < 0.01 * b and 0.99 * b < positive.max() <= b
    assert positive.mean().item() == pytest.approx(b / 2, rel=0.02)
    # the same draws: clipping keeps uniform's non-negative entries and zeroes the others
    torch.testing.assert_close(clipped, uniform.clamp(min=0.0))
    assert (clipped == 0).float().mean().item() == pytest.approx(0.5, abs=0.02)


@pytest.mark.parametrize("name", ["lpq", "glpq"])
def test_pi_is_a_distribution_with_finite_gradients_for_every_configuration(lpq, glpq, name):
    module = both(lpq, glpq)[name]
    torch.manual_seed(0)
    # ReLU features, one of them all zero and one constant (no direction for cosine, Pearson)
    hidden = torch.rand(5, 256) * 10
    hidden[0], hidden[1] = 0.0, 3.0
    hidden.requires_grad_()
    count = 0
    for args in configurations(module, name):
        model = module.ActorCritic(4, args)
        for progress in (0.0, 0.5, 1.0):
            if name == "glpq":
                model.set_progress(progress)
            log_probs = model.log_policy(hidden)
            assert log_probs.shape == (5, 4)
            probs = log_probs.exp()
            assert (probs >= 0).all() and torch.isfinite(log_probs).all(), args
            torch.testing.assert_close(probs.sum(-1), torch.ones(5))
        entropy = -(probs * log_probs).sum()
        head = [
            p for name, p in model.named_parameters() if not name.startswith(("torso", "value"))
        ]
        grads = torch.autograd.grad(log_probs[:, 1].sum() + entropy, [hidden, *head])
        assert all(torch.isfinite(g).all() for g in grads), args
        count += 1
    assert count == (18 if name == "lpq" else 75)


@pytest.mark.parametrize("name", ["lpq", "glpq"])
def test_network_forward_contract(lpq, glpq, name):
    module = both(lpq, glpq)[name]
    model = module.ActorCritic(6, module.Args())
    obs = torch.randint(0, 256, (3, 4, 84, 84), dtype=torch.uint8)
    log_probs, values = model(obs)
    assert log_probs.shape == (3, 6) and values.shape == (3,)
    x = obs.to(torch.float32, memory_format=torch.channels_last)  # as forward does
    torch.testing.assert_close(log_probs, model.log_policy(model.torso(x)))
    assert model.prototypes.shape == (6 * 16, 256)
    assert model.prototypes.abs().max() <= 1 / 16  # U(-1/16, 1/16)


@settings(max_examples=100, deadline=None)
@given(
    d=st.lists(st.floats(0.0, 1e6), min_size=12, max_size=12),
    k=st.integers(1, 4),
    tau=st.floats(0.01, 50.0),
)
def test_heads_on_extreme_distances(lpq, glpq, d, k, tau):
    distances = torch.tensor(d, dtype=torch.float64).view(1, 3, 4)
    for log_probs in (lpq.lpq_log_policy(distances, k), glpq.glpq_log_policy(distances, tau, k)):
        assert torch.isfinite(log_probs).all()
        assert log_probs.exp().sum().item() == pytest.approx(1.0, abs=1e-9)


def test_lpq_with_one_prototype_per_action_and_dot_distance_is_softmax(lpq):
    # thesis 7.2.2: P = 1 and d(h, w) = -(w.h + b) give the softmax head of eq. 7.4
    torch.manual_seed(0)
    h, weight, bias = torch.randn(5, 256), torch.randn(6, 256), torch.randn(6)
    distances = -(h @ weight.T + bias)
    log_probs = lpq.lpq_log_policy(distances.view(5, 6, 1), k=1)
    torch.testing.assert_close(log_probs, F.log_softmax(h @ weight.T + bias, dim=-1))


def test_lpq_by_hand(lpq):
    # eq. 7.9 with A = 2, P = 2: pi(0) = (e^-1 + e^-2) / (e^-1 + e^-2 + e^-3 + e^-0.5)
    distances = torch.tensor([[[1.0, 2.0], [3.0, 0.5]]])
    e = np.exp(-np.array([1.0, 2.0, 3.0, 0.5]))
    expected = np.array([e[0] + e[1], e[2] + e[3]]) / e.sum()
    np.testing.assert_allclose(lpq.lpq_log_policy(distances, 2).exp().numpy(), [expected])
    # k = 1 (eq. 7.11): only the nearest of each action competes, e^-1 against e^-0.5
    near = np.array([e[0], e[3]]) / (e[0] + e[3])
    np.testing.assert_allclose(lpq.lpq_log_policy(distances, 1).exp().numpy(), [near])


def test_glpq_by_hand(glpq):
    # eq. 7.7: action 0 (d 1, 2) sees d_- = 0.5, action 1 (d 3, 0.5) sees d_- = 1
    distances = torch.tensor([[[1.0, 2.0], [3.0, 0.5]]])
    mu = np.array([(0.5 - 1) / 1.5, (0.5 - 2) / 2.5, (1 - 3) / 4, (1 - 0.5) / 1.5])
    np.testing.assert_allclose(glpq.relative_distances(distances).numpy().ravel(), mu, rtol=1e-6)
    e = np.exp(2.0 * mu)  # eq. 7.10 with tau = 2
    expected = np.array([e[0] + e[1], e[2] + e[3]]) / e.sum()
    policy = glpq.glpq_log_policy(distances, 2.0, 2).exp().numpy()  # float32: rtol 1e-6
    np.testing.assert_allclose(policy, [expected], rtol=1e-6)
    near = np.array([e[0], e[3]]) / (e[0] + e[3])  # k = 1
    policy = glpq.glpq_log_policy(distances, 2.0, 1).exp().numpy()
    np.testing.assert_allclose(policy, [near], rtol=1e-6)


def theorem_1_bound(tau: float, num_actions: int) -> float:
    return math.exp(2 * tau) / (math.exp(2 * tau) + num_actions - 1)


@settings(max_examples=150, deadline=None)
@given(
    d=st.lists(st.floats(0.0, 1e4), min_size=12, max_size=12),
    k=st.integers(1, 3),
    tau=st.floats(0.01, 20.0),
)
def test_theorem_1_glpq_never_exceeds_its_bound(glpq, d, k, tau):
    distances = torch.tensor(d, dtype=torch.float64).view(1, 4, 3)
    pi = glpq.glpq_log_policy(distances, tau, k).exp()
    assert pi.max().item() <= theorem_1_bound(tau, 4) * (1 + 1e-9)


@pytest.mark.parametrize("distance", ["squared-euclidean", "euclidean", "manhattan", "cosine"])
@pytest.mark.parametrize(("tau", "k"), [(1.0, 3), (3.02, 3), (0.5, 2)])
def test_theorem_1_bound_is_reached_when_an_actions_prototypes_equal_h(glpq, distance, tau, k):
    torch.manual_seed(0)
    h = torch.rand(1, 8) + 0.1
    prototypes = torch.rand(4 * 3, 8)
    prototypes[3:6] = h  # every prototype of action 1
    distances = glpq.prototype_distances(h, prototypes, distance).view(1, 4, 3)
    pi = glpq.glpq_log_policy(distances, tau, k).exp()
    assert pi[0, 1].item() == pytest.approx(theorem_1_bound(tau, 4), rel=1e-5)


# ---------------------------------------------------------------------------------------------
# Prototype gradients (appendix C): attraction for a positive advantage, repulsion otherwise
# ---------------------------------------------------------------------------------------------
def policy_gradient_case(module, head: str, advantage: float):
    """A3C's policy loss -log pi(a) * advantage for one state, A = 3, P = 2, squared Euclidean;
    returns h, the prototypes, their loss gradients, the distances and pi's pieces."""
    torch.manual_seed(3)
    h = torch.rand(1, 5, dtype=torch.float64)
    prototypes = torch.rand(6, 5, dtype=torch.float64, requires_grad=True)
    distances = module.prototype_distances(h, prototypes, "squared-euclidean").view(1, 3, 2)
    if head == "lpq":
        log_probs = module.lpq_log_policy(distances, 2)
    else:
        log_probs = module.glpq_log_policy(distances, 2.0, 2)
    action = 0
    loss = -log_probs[0, action] * advantage
    (grad,) = torch.autograd.grad(loss, prototypes)
    return h[0], prototypes.detach(), grad, distances.detach()[0], action


@pytest.mark.parametrize("head", ["lpq", "glpq"])
@pytest.mark.parametrize("advantage", [1.5, -0.7])
def test_prototype_gradient_attracts_or_repels_by_the_advantages_sign(lpq, glpq, head, advantage):
    h, prototypes, grad, _, action = policy_gradient_case(both(lpq, glpq)[head], head, advantage)
    step = -grad  # the direction gradient descent moves each prototype
    for i, w in enumerate(prototypes):
        towards_h = h - w
        cosine = torch.dot(step[i], towards_h) / (step[i].norm() * towards_h.norm())
        # (C.5, C.11) the taken action's prototypes, (C.15, C.18) the others'
        expected = np.sign(advantage) * (1.0 if i // 2 == action else -1.0)
        assert cosine.item() == pytest.approx(expected, abs=1e-9), (i, cosine)


def test_glpq_prototype_gradients_match_appendix_c(glpq):
    h, prototypes, grad, distances, action = policy_gradient_case(glpq, "glpq", 1.0)
    tau = 2.0
    mu = glpq.relative_distances(distances[None])[0]
    e = torch.exp(tau * mu)  # (A, P)
    # the setup: action 0's far prototype is not the nearest, action 1's far one neither
    near = distances.argmin(-1)
    far_own, far_other = 1 - near[0].item(), 1 - near[1].item()
    d_minus = [min(distances[b].min() for b in range(3) if b != a) for a in range(3)]
    # (C.5): d log pi / d w_k = tau 4 d_- / (d_k + d_-)^2 (h - w_k) (P(k | a) - P(k))
    k = far_own
    d_k = distances[0, k]
    c5 = tau * 4 * d_minus[0] / (d_k + d_minus[0]) ** 2 * (h - prototypes[k])
    c5 = c5 * (e[0, k] / e[0].sum() - e[0, k] / e.sum())
    torch.testing.assert_close(-grad[k], c5)  # the loss is -log pi, advantage 1
    # (C.15): d log pi / d w_l = -tau 4 d_- / (d_l + d_-)^2 (h - w_l) P(l), d_- of l's action
    row = 2 + far_other
    d_l = distances[1, far_other]
    c15 = -tau * 4 * d_minus[1] / (d_l + d_minus[1]) ** 2 * (h - prototypes[row])
    c15 = c15 * e[1, far_other] / e.sum()
    torch.testing.assert_close(-grad[row], c15)


def test_lpq_prototype_gradients_are_rslvq(lpq):
    # with mu = -d: d log pi / d w_k = 2 (h - w_k) (P(k | a) - P(k)) for a's prototypes and
    # -2 (h - w_l) P(l) for the others (Seo and Obermayer 2003; thesis 7.1.2)
    h, prototypes, grad, distances, action = policy_gradient_case(lpq, "lpq", 1.0)
    e = torch.exp(-distances).flatten()
    own = torch.zeros(6, dtype=torch.bool)
    own[2 * action : 2 * action + 2] = True
    p_all = e / e.sum()
    p_own = torch.where(own, e / e[own].sum(), 0.0)
    expected = 2 * (h - prototypes) * (p_own - p_all)[:, None]
    torch.testing.assert_close(-grad, expected)


# ---------------------------------------------------------------------------------------------
# Temperature (thesis 7.2.4)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("temperature", "start", "end"),
    # the notes: cold on Catch tau 1.45 -> 2.64, hot 3.02 -> 4.22; searing by hand:
    # 0.5 ln(0.95 * 47 / 0.05) = 3.397, 0.5 ln(0.999 * 47 / 0.001) = 5.378
    [("cold", 1.45, 2.64), ("hot", 3.02, 4.22), ("searing", 3.397, 5.378)],
)
def test_temperature_schedules_on_catch(glpq, temperature, start, end):
    model = glpq.ActorCritic(3, glpq.Args(temperature=temperature))  # 3 actions, 16 each
    assert model.tau() == pytest.approx(start, abs=0.005)
    model.set_progress(1.0)
    assert model.tau() == pytest.approx(end, abs=0.005)
    assert model.policy_loss_scale() == pytest.approx(1 / end, abs=1e-3)
    model.set_progress(2.0)  # the final evaluation sees T >= T_max: p stays at pN
    assert model.tau() == pytest.approx(end, abs=0.005)
    # half way p is the mean of p0 and pN
    model.set_progress(0.5)
    p = {"cold": 0.945, "hot": 0.945, "searing": 0.9745}[temperature]
    n = 3 if temperature == "cold" else 48
    assert model.tau() == pytest.approx(0.5 * math.log(p * (n - 1) / (1 - p)), rel=1e-9)


def test_cold_temperature_makes_p_the_largest_policy_value(glpq):
    # Corollary 1: with tau of eq. 7.17 the bound of Theorem 1 is p
    for p, num_actions in [(0.9, 3), (0.99, 3), (0.5, 18)]:
        assert theorem_1_bound(glpq.scheduled_tau(p, num_actions), num_actions) == pytest.approx(p)


def test_competition_size_sets_the_hot_temperature(glpq):
    model = glpq.ActorCritic(3, glpq.Args(temperature="hot", competition_size=4, p_start=0.8))
    assert model.tau() == pytest.approx(0.5 * math.log(0.8 * 11 / 0.2))  # n = k |A| = 12


def test_fixed_and_trainable_temperature_and_the_loss_correction(glpq):
    fixed = glpq.ActorCritic(3, glpq.Args(temperature="fixed", tau=1.0))
    assert fixed.tau() == 1.0 and fixed.policy_loss_scale() == 1.0
    assert "log_tau" not in dict(fixed.named_parameters())
    off = glpq.ActorCritic(3, glpq.Args(tau_loss_correction=False))
    assert off.tau() > 3 and off.policy_loss_scale() == 1.0
    trainable = glpq.ActorCritic(3, glpq.Args(temperature="trainable", tau=2.0))
    assert trainable.tau().item() == pytest.approx(2.0)
    assert trainable.policy_loss_scale() == pytest.approx(0.5)
    log_probs, _ = trainable(torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8))
    (grad,) = torch.autograd.grad(log_probs[:, 0].sum(), [trainable.log_tau])
    assert torch.isfinite(grad) and grad.item() != 0.0


@pytest.mark.parametrize(
    ("name", "flags"),
    [
        ("lpq", {"competition_size": 17}),
        ("lpq", {"competition_size": 0}),
        ("lpq", {"prototypes_per_action": 0}),
        ("lpq", {"prototype_init_bound": 0.0}),
        ("glpq", {"temperature": "fixed", "tau": 0.0}),
        ("glpq", {"temperature": "cold", "p_start": 0.3}),  # tau <= 0 for p <= 1/|A|
        ("glpq", {"temperature": "hot", "p_end": 1.0}),
    ],
)
def test_bad_head_flags_are_usage_errors(lpq, glpq, name, flags):
    module = both(lpq, glpq)[name]
    with pytest.raises(runtime.UsageError):
        module.ActorCritic(3, module.Args(**flags))


# ---------------------------------------------------------------------------------------------
# End to end, tiny budgets (the flags of tests/test_runtime_a3c.py)
# ---------------------------------------------------------------------------------------------
def saved_checkpoint(name: str, folder: Path, *flags: str) -> Path:
    """A checkpoint of the script's network built with these flags, as a run at step 0 writes it."""
    import tyro

    module = load(name)
    args = runtime.resolve_defaults(tyro.cli(module.Args, args=["--num-workers", "1", *flags]))
    path = folder / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 0.0, module.AGENT.script)
    return path


@pytest.mark.parametrize("name", ["a3c_lpq", "a3c_glpq"])
def test_the_heads_flags_are_part_of_the_experiment(tmp_path, monkeypatch, capsys, name):
    """--evaluate plays the checkpoint (GLPQ's temperature from the checkpoint's step, a diff
    from FF); a different head cannot resume it."""
    checkpoint = saved_checkpoint(name, tmp_path)
    argv = ["--evaluate", str(checkpoint), "--eval-episodes", "2"]
    code, err = main_exit(load(name), argv, monkeypatch, capsys, keep_out=True)
    assert code == 0, err
    assert "over 2 episodes" in capsys.readouterr().out
    argv = ["--resume", str(checkpoint), "--distance", "manhattan"]
    code, err = main_exit(load(name), argv, monkeypatch, capsys)
    assert code == 2
    assert "--distance manhattan differs from the run's squared-euclidean" in err


AS_RUN = ["--mu-form", "code", "--temperature", "trainable", "--tau-parametrization", "plain"]


@pytest.mark.parametrize("scope", ["policy", "policy-and-entropy"])
def test_glpq_as_run_learns_and_resumes_only_as_run(
    tmp_path, monkeypatch, capsys, scope, one_thread
):
    """The as-run form (thesis-notes.md "As run") in the GLPQ worker loop: it learns, tau
    included; the form is part of the experiment: the text form cannot resume it."""
    import tyro

    glpq = load("a3c_glpq")
    flags = [*AS_RUN, "--tau-loss-scope", scope]
    args = runtime.resolve_defaults(
        tyro.cli(glpq.Args, args=[*flags, "--num-workers", "1", "--total-timesteps", "100",
                                  "--t-max", "5"])
    )  # fmt: skip
    torch.manual_seed(0)
    shared = shared_for(glpq, args)
    tau = shared.model.plain_tau.item()
    glpq.worker(0, shared, args)
    assert shared.global_step() >= 100 and shared.model.plain_tau.item() != tau
    checkpoint = saved_checkpoint("a3c_glpq", tmp_path, *flags)
    argv = ["--resume", str(checkpoint), "--mu-form", "text"]
    code, err = main_exit(glpq, argv, monkeypatch, capsys)
    assert code == 2 and "--mu-form text differs from the run's code" in err


def test_glpq_rejects_the_negative_distance(glpq, capsys):
    tyro = pytest.importorskip("tyro")
    with pytest.raises(SystemExit) as exit_info:
        tyro.cli(glpq.Args, args=["--distance", "inverse-squared-euclidean"])
    assert exit_info.value.code == 2
    tyro.cli(glpq.Args, args=["--distance", "manhattan"])  # while the others parse


@pytest.mark.parametrize("tau", [0.5, 4.22, 39.0, 41.0, 200.0])
def test_glpq_policy_and_gradients_equal_the_logsumexp_form(glpq, tau):
    # below EXP_SAFE_TAU the head sums exp(tau (mu - 1)) instead of calling logsumexp(tau mu)
    generator = torch.Generator().manual_seed(0)
    distances = torch.rand(4, 3, 5, generator=generator, dtype=torch.float64) * 10
    distances.requires_grad_()
    log_pi = glpq.glpq_log_policy(distances, tau, 5)
    mu = glpq.relative_distances(distances)
    reference = F.log_softmax(torch.logsumexp(tau * mu, dim=-1), dim=-1)
    torch.testing.assert_close(log_pi, reference)
    weights = torch.rand(4, 3, generator=generator, dtype=torch.float64)
    (grad,) = torch.autograd.grad((log_pi * weights).sum(), distances)
    (reference_grad,) = torch.autograd.grad((reference * weights).sum(), distances)
    torch.testing.assert_close(grad, reference_grad)
    assert torch.isfinite(log_pi).all()


@pytest.mark.parametrize("scale", [1.0, 1e3])
def test_lpq_policy_and_gradients_equal_the_logsumexp_form(lpq, scale):
    generator = torch.Generator().manual_seed(1)
    distances = torch.rand(4, 3, 5, generator=generator, dtype=torch.float64) * scale
    distances.requires_grad_()
    log_pi = lpq.lpq_log_policy(distances, 5)
    reference = F.log_softmax(torch.logsumexp(-distances, dim=-1), dim=-1)
    torch.testing.assert_close(log_pi, reference)
    weights = torch.rand(4, 3, generator=generator, dtype=torch.float64)
    (grad,) = torch.autograd.grad((log_pi * weights).sum(), distances)
    (reference_grad,) = torch.autograd.grad((reference * weights).sum(), distances)
    torch.testing.assert_close(grad, reference_grad)


# ---------------------------------------------------------------------------------------------
# GLPQ as run (--mu-form code): the thesis's code computed tau * (d_- / (d_i + d_-) - d_i)
# ---------------------------------------------------------------------------------------------
def as_run_policy_by_hand(d: np.ndarray, tau: float, k: int) -> np.ndarray:
    """A direct NumPy computation for distances d (A, P): each prototype's logit is
    tau * (d_- / (d_i + d_-) - d_i), d_- the nearest prototype of another action; the k nearest
    prototypes of each action compete; softmax over them all, summed per action."""
    num_actions = d.shape[0]
    logits, owners = [], []
    for a in range(num_actions):
        d_minus = min(d[b].min() for b in range(num_actions) if b != a)
        for i in np.argsort(d[a])[:k]:
            logits.append(tau * (d_minus / (d[a, i] + d_minus) - d[a, i]))
            owners.append(a)
    logits = np.array(logits, dtype=np.float64)
    e = np.exp(logits - logits.max())
    return np.array([e[np.array(owners) == a].sum() for a in range(num_actions)]) / e.sum()


@pytest.mark.parametrize(("tau", "k"), [(2.0, 2), (2.0, 1), (0.7, 2)])
def test_glpq_as_run_form_by_hand(glpq, tau, k):
    d = np.array([[1.0, 2.0], [3.0, 0.5]])
    # by hand for action 0's first prototype: d_- = 0.5, logit tau * (0.5 / 1.5 - 1)
    scores = glpq.as_run_scores(torch.tensor(d)[None]).numpy().ravel()
    np.testing.assert_allclose(scores, [0.5 / 1.5 - 1, 0.5 / 2.5 - 2, 1 / 4 - 3, 1 / 1.5 - 0.5])
    policy = glpq.glpq_log_policy(torch.tensor(d)[None], tau, k, "code").exp().numpy()
    np.testing.assert_allclose(policy, [as_run_policy_by_hand(d, tau, k)], rtol=1e-12)


def test_glpq_as_run_form_is_half_mu_minus_d(glpq):
    # thesis-notes: tau * (mu_i / 2 - d_i) up to a constant, so the same policy
    generator = torch.Generator().manual_seed(2)
    d = torch.rand(5, 3, 4, generator=generator, dtype=torch.float64) * 50
    mu = glpq.relative_distances(d)
    reference = F.log_softmax(torch.logsumexp(1.3 * (mu / 2 - d), dim=-1), dim=-1)
    torch.testing.assert_close(glpq.glpq_log_policy(d, 1.3, 4, "code"), reference)


@settings(max_examples=150, deadline=None)
@given(
    d=st.lists(st.floats(0.0, 1e4), min_size=12, max_size=12),
    k=st.integers(1, 4),
    tau=st.floats(0.01, 5.0),
    dtype=st.sampled_from([torch.float32, torch.float64]),
)
def test_glpq_as_run_form_is_finite_far_from_the_prototypes(glpq, d, k, tau, dtype):
    # the old exp(tau (mu - 1)) shortcut underflows here: logits reach -5e4
    distances = torch.tensor(d, dtype=dtype).view(1, 3, 4).requires_grad_()
    tau_tensor = torch.tensor(tau, dtype=dtype, requires_grad=True)
    log_pi = glpq.glpq_log_policy(distances, tau_tensor, k, "code")
    assert torch.isfinite(log_pi).all()
    assert log_pi.exp().sum().item() == pytest.approx(1.0, abs=1e-5)
    grads = torch.autograd.grad(log_pi[0, 0] - log_pi[0, 2], [distances, tau_tensor])
    assert all(torch.isfinite(g).all() for g in grads)


@pytest.mark.parametrize("tau", [1.0, 1.445, 3.02, 5.0])
def test_theorem_1_holds_for_the_text_and_not_for_the_as_run_form(glpq, tau):
    # h on a prototype of action 1, every other prototype at Catch's initial distance (~625):
    # Theorem 1 caps eq. 7.7's pi at e^2tau / (e^2tau + |A| - 1); the as-run logits, unbounded,
    # put nearly all mass on action 1
    distances = torch.full((1, 4, 3), 625.0, dtype=torch.float64)
    distances[0, 1, 0] = 0.0
    bound = theorem_1_bound(tau, 4)
    assert glpq.glpq_log_policy(distances, tau, 3, "text").exp()[0, 1].item() <= bound
    assert glpq.glpq_log_policy(distances, tau, 3, "code").exp()[0, 1].item() > bound
    assert glpq.glpq_log_policy(distances, tau, 3, "code").exp()[0, 1].item() > 1 - 1e-9


def test_as_run_form_gives_far_larger_gradients_at_catch_scale(glpq):
    # thesis-notes: at d ~ 625 eq. 7.7 is nearly flat; the as-run gradient is ~1000x larger
    generator = torch.Generator().manual_seed(3)
    distances = 600 + 50 * torch.rand(1, 3, 16, generator=generator, dtype=torch.float64)
    sizes = {}
    for form in ("text", "code"):
        d = distances.clone().requires_grad_()
        log_pi = glpq.glpq_log_policy(d, 1.445, 16, form)
        (grad,) = torch.autograd.grad(log_pi[0, 0], d)
        sizes[form] = grad.abs().sum().item()
        if form == "text":
            assert (log_pi.exp() - 1 / 3).abs().max() < 0.005  # pi within 0.005 of uniform
    assert sizes["code"] > 100 * sizes["text"]


def test_trainable_tau_as_run_and_the_loss_scope_flags(glpq):
    # by default a trainable tau starts at the cold tau for p0 = 0.9: 0.5 ln(0.9 * 2 / 0.1)
    as_run = glpq.Args(temperature="trainable", tau_parametrization="plain", mu_form="code")
    model = glpq.ActorCritic(3, as_run)
    assert isinstance(model.plain_tau, torch.nn.Parameter) and "log_tau" not in dict(
        model.named_parameters()
    )
    assert model.tau().item() == pytest.approx(0.5 * math.log(18), rel=1e-6)  # 1.445
    log_probs, _ = model(torch.randint(0, 256, (2, 4, 84, 84), dtype=torch.uint8))
    (grad,) = torch.autograd.grad(log_probs[:, 0].sum(), [model.plain_tau])
    assert torch.isfinite(grad) and grad.item() != 0.0
    log_form = glpq.ActorCritic(3, glpq.Args(temperature="trainable"))
    assert log_form.log_tau.exp().item() == pytest.approx(0.5 * math.log(18), rel=1e-6)
    assert glpq.ActorCritic(3, glpq.Args(temperature="fixed")).tau() == 1.0
    for flags in ({"temperature": "trainable", "p_start": 0.2}, {"tau": -1.0}):
        with pytest.raises(runtime.UsageError):
            glpq.ActorCritic(3, glpq.Args(**{"temperature": "fixed", **flags}))


def test_tau_loss_scope(glpq):
    # loss = L_pi - beta H + lambda_V L_V with L_pi = 2, H = 3, beta = 0.01, L_V term 0.5
    policy_loss, entropy = torch.tensor(2.0), torch.tensor(3.0)
    loss = policy_loss - 0.01 * entropy + 0.5
    scale = 1 / 4.0  # tau = 4
    text = glpq.tau_corrected_loss(loss, policy_loss, entropy, scale, glpq.Args(ent_coef=0.01))
    assert text.item() == pytest.approx(2.0 / 4 - 0.03 + 0.5)
    as_run = glpq.Args(ent_coef=0.01, tau_loss_scope="policy-and-entropy")
    whole = glpq.tau_corrected_loss(loss, policy_loss, entropy, scale, as_run)
    assert whole.item() == pytest.approx((2.0 - 0.03) / 4 + 0.5)
