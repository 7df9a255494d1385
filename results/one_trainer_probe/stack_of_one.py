"""Probe for issue 101's one trainer: can a Hogwild worker's network be "a stack of one" (its
parameters stacked (1, ...) and called through torch.func.functional_call with the views p[0],
as a batch's stacked parameters are) and compute the same bits as fast as the plain module?
A3C FF: one learning pass over 6 frames (forward, the script's a3c_loss, autograd.grad) and one
acting step, timed in turns (plain, stack of one, plain, ...); `fc_own` is functional_call with
the module's own parameters, to tell functional_call's cost from the views'.

    python results/one_trainer_probe/stack_of_one.py
"""

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT / "agents"), str(ROOT)]

import torch  # noqa: E402
from a3c_runtime.flags import resolve_defaults  # noqa: E402
from a3c_tools import load_script, parsed_flags  # noqa: E402
from torch.func import functional_call  # noqa: E402

torch.set_num_threads(1)
ff = load_script(ROOT / "agents" / "a3c_ff.py")
args = resolve_defaults(parsed_flags(ff.Args, ["--num-workers", "1"]))
torch.manual_seed(0)
net = ff.ActorCritic(3, args).to(memory_format=torch.channels_last)
names = [name for name, _ in net.named_parameters()]
params = list(net.parameters())
own = dict(net.named_parameters())
stacked = [p.detach().clone().unsqueeze(0).requires_grad_() for p in params]  # (1, ...)
obs = torch.randint(0, 256, (6, 4, 84, 84), dtype=torch.uint8)
actions, returns = torch.randint(0, 3, (5,)), torch.randn(5)


def views() -> dict:
    return {name: p[0] for name, p in zip(names, stacked, strict=True)}


def grads(outputs: tuple, wrt: list) -> tuple:
    log_probs, values = outputs
    loss = ff.a3c_loss(log_probs[:5], actions, values[:5], returns, 0.01, 0.5, "code")[0]
    return torch.autograd.grad(loss, wrt)


def plain() -> tuple:
    return grads(net(obs), params)


def fc_own() -> tuple:
    return grads(functional_call(net, own, (obs,)), params)


def one() -> tuple:
    return grads(functional_call(net, views(), (obs,)), stacked)


def act_plain() -> None:
    with torch.inference_mode():
        net(obs[:1])


def act_one() -> None:
    with torch.inference_mode():
        functional_call(net, views(), (obs[:1],))


def timed(functions: tuple, calls: int, unit: str, scale: float) -> None:
    for function in functions:
        for _ in range(calls // 10):
            function()
        start = time.perf_counter()
        for _ in range(calls):
            function()
        seconds = (time.perf_counter() - start) / calls
        print(f"{function.__name__:10s} {seconds * scale:8.3f} {unit}")


same_grads = all(torch.equal(a, b[0]) for a, b in zip(plain(), one(), strict=True))
with torch.inference_mode():
    acted, acted_one = net(obs[:1]), functional_call(net, views(), (obs[:1],))
same_acts = all(torch.equal(a, b) for a, b in zip(acted, acted_one, strict=True))
print(f"torch {torch.__version__}: bit-identical gradients {same_grads}, acting {same_acts}")
timed((plain, fc_own, one) * 2, 300, "ms per learning pass", 1e3)
timed((act_plain, act_one) * 2, 2000, "us per acting step", 1e6)
