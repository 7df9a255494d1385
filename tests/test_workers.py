"""Every agent script's worker loop (Algorithm 1) in process, at K = 1 and K = 4 envs per worker
and in each --precision: it takes the steps and updates it should, every parameter learns (but
those listed in NO_GRADIENT, with the reason), the weights and optimizer statistics stay finite
float32, it prints no warnings and keeps no autograd history."""

import warnings

import pytest
import torch
from conftest import ALL_SCRIPTS, SCRIPTS, load_script, shared_for, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


def no_gradient(name: str, model: torch.nn.Module, k: int) -> dict[str, torch.Tensor]:
    """The parameter entries that provably get no gradient, as a mask per parameter (True: may
    stay unchanged). One list for every script, K and precision:
    - a3c_ss: the second convolution's bias (torso.2.bias) adds a constant to each map, which the
      spatial softmax over the map's positions ignores;
    - a3c_ww: for the same reason, the biases of its "where" maps, the second convolution's
      channels from what_maps on (convs.2.bias[what_maps:]); its "what" biases must learn;
    - the growth scripts: the slot mask (prototype_active), used detached and written only by the
      growth step, and the free slots' prototypes, which take no part in the policy;
    - a3c_lws_online at K = 1: the centroid predictor's encoder gets its gradient through the
      heads, whose weights start at 0 (so that the predicted centroids start at the static ones),
      so over the K = 1 case's small updates its steps stay below float32's resolution of its
      weights; it learns in the K = 4 case.
    (Such a gradient is zero up to rounding, so these may change a little: they are not checked.)
    """
    params = dict(model.named_parameters())
    exempt = {}
    if name == "a3c_ss":
        exempt["torso.2.bias"] = torch.ones_like(params["torso.2.bias"], dtype=torch.bool)
    if name == "a3c_ww":
        mask = torch.zeros_like(params["convs.2.bias"], dtype=torch.bool)
        mask[model.what_maps :] = True
        exempt["convs.2.bias"] = mask
    if name.endswith("_growth"):
        exempt["prototype_active"] = torch.ones_like(params["prototype_active"], dtype=torch.bool)
        free = ~model.active_slots().flatten()
        exempt["prototypes"] = free[:, None].expand_as(params["prototypes"])
    if name == "a3c_lws_online" and k == 1:
        for key, param in params.items():
            if key.startswith("centroid_predictor.encoder."):
                exempt[key] = torch.ones_like(param, dtype=torch.bool)
    return exempt


# (K, t_max, T_max): K = 1 with t_max 5 < Catch's 15-step episodes, so rollouts bootstrap from
# V(s_last), for 10 episodes (a value head whose values start at 0 learns only from a return
# that is not 0: a catch); K = 4 with t_max 20, so the 4 episodes end together after 15 steps
# and each update holds 4 x 15 states
SETTINGS = {1: (5, 150), 4: (20, 120)}
# each thesis script in fp32 and in what --precision auto picks on a CPU with native bf16
# (bf16-learn at K = 1, bf16 at K > 1); chapter 8's scripts in fp32
PRECISIONS = {1: ("fp32", "bf16-learn"), 4: ("fp32", "bf16")}
CASES = [
    (name, k, precision)
    for name in ALL_SCRIPTS
    for k in SETTINGS
    for precision in (PRECISIONS[k] if name in SCRIPTS else ("fp32",))
]


@pytest.mark.parametrize(("name", "k", "precision"), CASES)
def test_every_parameter_learns(name, k, precision, one_thread):
    module = load_script(name)
    t_max, steps = SETTINGS[k]
    args = tiny_args(
        module, total_timesteps=steps, t_max=t_max, envs_per_worker=k, precision=precision
    )
    torch.manual_seed(0)  # the network's initialisation; the worker seeds its own streams
    shared = shared_for(module, args)
    before = {key: p.detach().clone() for key, p in shared.model.named_parameters()}
    exempt = no_gradient(name, shared.model, k)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # normal runs print no warnings
        module.worker(0, shared, args)
    stats = dict(zip(shared.STATS, shared.stats[0].tolist(), strict=True))
    if k == 1:
        assert steps <= shared.global_step() < steps + t_max
        assert stats["updates"] >= steps // t_max
    else:
        assert shared.global_step() == steps
        assert (stats["updates"], stats["episodes"], stats["length_sum"]) == (2, 8, 8 * 15)
    for key, new in shared.model.named_parameters():
        new = new.detach()
        assert new.dtype == torch.float32 and torch.isfinite(new).all(), key
        learnt = new != before[key]
        if key in exempt:
            learnt = learnt | exempt[key]
        assert learnt.any(), f"{key} did not learn"
        must_learn = ~exempt[key] if key in exempt else None
        if must_learn is not None and must_learn.any():
            assert (new != before[key])[must_learn].any(), f"{key} (its learning part) is fixed"
    for statistics in shared.optimizer.state_dict().values():
        for statistic in statistics if isinstance(statistics, list) else [statistics]:
            assert statistic.dtype in (torch.float32, torch.float64), statistic.dtype
            assert torch.isfinite(statistic).all()
    # logging the losses must not chain each rollout's graph onto the stats (a memory leak)
    assert shared.stats.grad_fn is None and not shared.stats.requires_grad
    assert all(torch.isfinite(torch.tensor(v)) for v in stats.values())
