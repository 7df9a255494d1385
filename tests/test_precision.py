"""--precision auto|fp32|bf16|bf16-learn: bf16 runs the workers' forward passes under CPU autocast
(bf16-learn: only the learning pass) while the weights, optimizer statistics, returns and the
loss stay float32."""

import pytest
import torch
from conftest import SCRIPTS, load_script, shared_for, tiny_args


@pytest.mark.parametrize("name", ["a3c_ff", "a3c_lstm"])
def test_bf16_forward_outputs_cast_back_give_a_float32_loss(name):
    """The worker's learning forward: bf16 inside autocast, float32 after its cast."""
    module = load_script(name)
    args = tiny_args(module, precision="bf16")
    model = module.AGENT.build_network(3, args)
    obs = torch.randint(0, 256, (6, 4, 84, 84), dtype=torch.uint8)
    inputs = (obs[:, None], model.initial_state(1)) if name == "a3c_lstm" else (obs,)
    precision = torch.autocast("cpu", dtype=torch.bfloat16, enabled=True)
    with precision:
        log_probs, values = model(*inputs)[:2]
    assert values.dtype == torch.bfloat16  # the forward did run in bf16
    log_probs, values = log_probs.float(), values.float()
    if name == "a3c_lstm":
        log_probs, values = log_probs[:, 0], values[:, 0]
    returns = torch.zeros(5)
    loss = module.a3c_loss(log_probs[:5], torch.zeros(5, dtype=torch.int64), values[:5], returns,
                           args.ent_coef, args.vf_coef)[0]  # fmt: skip
    assert loss.dtype == torch.float32
    grads = torch.autograd.grad(loss, list(model.parameters()))
    assert all(g.dtype == torch.float32 and torch.isfinite(g).all() for g in grads)


@pytest.mark.parametrize(
    ("precision", "acting", "learning"),
    [("fp32", False, False), ("bf16", True, True), ("bf16-learn", False, True)],
)
@pytest.mark.parametrize("name", SCRIPTS)
def test_each_forward_pass_runs_in_its_precision(
    name,
    precision,
    acting,
    learning,
    one_thread,
    monkeypatch,
):
    """The worker's acting passes (inference mode) and learning passes (with autograd) are
    under bf16 autocast exactly as --precision says."""
    module = load_script(name)
    args = tiny_args(module, total_timesteps=40, t_max=5, precision=precision)
    shared = shared_for(module, args)
    calls = []
    forward = module.ActorCritic.forward

    def recording_forward(self, *inputs, **kwargs):
        calls.append((torch.is_inference_mode_enabled(), torch.is_autocast_enabled("cpu")))
        return forward(self, *inputs, **kwargs)

    monkeypatch.setattr(module.ActorCritic, "forward", recording_forward)
    module.worker(0, shared, args)
    acting_calls = {autocast for inference, autocast in calls if inference}
    learning_calls = {autocast for inference, autocast in calls if not inference}
    assert acting_calls == {acting} and learning_calls == {learning}, calls
