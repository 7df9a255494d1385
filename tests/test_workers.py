"""Every script's worker loop (Algorithm 1) in process: it learns, prints no warnings and
keeps no autograd history."""

import warnings

import pytest
import torch
from conftest import SCRIPTS, load_script, shared_for, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


@pytest.mark.parametrize("name", SCRIPTS)
def test_worker_learns_in_process_without_warnings_or_autograd_history(name, one_thread):
    module = load_script(name)
    # t_max 5 < Catch's 15-step episodes: rollouts bootstrap from V(s_last)
    args = tiny_args(module, total_timesteps=60, t_max=5)
    shared = shared_for(module, args)
    before = [p.detach().clone() for p in shared.params]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # normal runs print no warnings
        module.worker(0, shared, args)
    assert 60 <= shared.global_step() < 60 + args.t_max
    assert shared.stats[0, 3] >= 60 // 5  # updates
    # every parameter learns, except those that provably get no gradient:
    # - a3c_ss.py: the second convolution's bias (torso.2.bias) adds a constant to each map, which
    #   the spatial softmax over the map's positions ignores;
    # - a3c_ww.py: for the same reason, the biases of its "where" maps, the second convolution's
    #   channels from what_maps on (convs.2.bias[what_maps:]); its "what" biases must learn.
    # (Such a gradient is zero up to rounding, so these may change a little: they are not checked.)
    model = shared.model
    no_gradient = {"a3c_ss": {"torso.2.bias"}}.get(name, set())
    after = dict(model.named_parameters())
    for key, old in zip(after, before, strict=True):
        new = after[key].detach()
        if name == "a3c_ww" and key == "convs.2.bias":
            what = slice(0, model.what_maps)
            assert not torch.equal(old[what], new[what]), f"{key}[:{model.what_maps}] did not learn"
        elif key not in no_gradient:
            assert not torch.equal(old, new), f"{key} did not learn"
    # logging the losses must not chain each rollout's graph onto the stats (a memory leak)
    assert shared.stats.grad_fn is None and not shared.stats.requires_grad
