"""Activation replay: the learning forward takes back the layer outputs that acting computed.

Acting and learning run the same synced network theta' on the same states (Algorithm 1), so
every Conv2d and Linear output of the learning forward was already computed while acting, one
step at a time. `replay_activations(model, rollout_frames, args)`, called once before a worker's
loop where it pays,
keeps them and hands them back, so the loop itself stays Algorithm 1 as written:

- a forward of `model` without gradients (acting, in inference mode) on rows of `rollout_frames`
  (the worker's rollout buffer) records each layer's output;
- the forward with gradients on rows of it (the update) takes the recorded outputs back, in
  acting order, instead of computing them again; only rows acting never saw (the bootstrap
  state s_n) are computed, in acting's precision. It checks that every recorded row was taken;
- a forward on any other tensor (V(s_last) of a truncated episode, tests, the evaluator's own
  network) is the layer's own.

The backward is each layer's own (aten.convolution_backward; two matmuls for Linear), so the
gradients are those of recomputing the forward, up to float rounding. Everything else in a
network (activations, LSTM cells, softmaxes, prototypes) is recomputed from the replayed
outputs. A network's learning forward must call each layer on the rollout's rows in acting order
(step-major, a Conv2d's inputs batched, a Linear's rows its leading dimensions), once per
forward. Under --precision bf16-learn the replayed outputs are acting's fp32 ones and the
backward runs in bf16. Anything it cannot replay exactly (a layer called twice in one forward, a
Conv2d or Linear subclass, non-zero or string padding, a learning forward over other rows than
acting's, in another order, or after the weights changed, or a layer fed other inputs than
acting fed it: each recorded row keeps its input's sum as a fingerprint) raises a RuntimeError
naming it, at the latest at the first update. It runs only where it passes the project's rule
for speed tricks (docs/speed.md, "Speed tricks: the 5% rule"): replay_activations decides.
"""

from __future__ import annotations

import contextlib
from typing import Any

import torch
import torch.nn as nn


def replay_activations(
    model: nn.Module, rollout_frames: torch.Tensor, args: Any
) -> ActivationReplay | None:
    """Attach an ActivationReplay to model for forwards on rows of rollout_frames (t_max + 1, K,
    ...), where it passes the 5% rule (docs/speed.md): with K > 1 envs per worker on Catch, in
    bf16 or fp32. Measured on and off in one run, alternating rounds of 15 s, A3C FF
    (results/replay_measurement): with its input fingerprint, on the 2-core Zen 4 EPYC with
    native bf16, K = 16 bf16 1.08x and fp32 1.17x; on a 2-core AVX2 EPYC without bf16, alone,
    K = 16 fp32 1.22x. Under 5% elsewhere, so the model is left as it is there: K = 16
    bf16-learn 1.04x, K = 1 0.94-1.04x (acting's copies cost about what the update's forward
    saves), Breakout K = 16 1.04x (the emulator's share of a step is large)."""
    from catch_env.wrappers import is_atari

    if args.envs_per_worker == 1 or args.precision == "bf16-learn" or is_atari(args.env):
        return None
    return ActivationReplay(model, rollout_frames)


class ActivationReplay:
    """See the module docstring. Turns the model's Conv2d and Linear layers into recording ones,
    in place (same parameters, names and state_dict), and adds a forward pre-hook and hook on
    the model that choose each forward's mode from its input and the grad mode."""

    def __init__(self, model: nn.Module, rollout_frames: torch.Tensor) -> None:
        self.storage = rollout_frames.untyped_storage().data_ptr()
        self.mode: str | None = None  # "record", "replay" or None (plain layers)
        self.first_offset: int | None = None  # where this rollout's first acting state lies
        self.next_offset: int | None = None  # where the next acting state must lie
        self.acting_strides: tuple[int, ...] | None = None  # the layout of acting's frames
        self.weight_versions: list[int] = []  # the replayed layers' weights while acting
        self.problem: str | None = None  # an acting forward the replay cannot match
        self.layers: list[_ReplayedConv2d | _ReplayedLinear] = []
        for name, layer in model.named_modules():
            name = name or type(model).__name__
            if isinstance(layer, (nn.Conv2d, nn.Linear)):
                check_supported(name, layer)
                layer.__class__ = {nn.Conv2d: _ReplayedConv2d, nn.Linear: _ReplayedLinear}[
                    type(layer)
                ]  # a subclass: only forward changes
                layer.replay, layer.recorded, layer.count, layer.cursor = self, None, 0, 0
                layer.input_sums = None
                layer.replay_name, layer.calls = name, 0
                self.layers.append(layer)
        model.register_forward_pre_hook(self._before_forward)
        model.register_forward_hook(self._after_forward)

    def _before_forward(self, _model: nn.Module, inputs: tuple[Any, ...]) -> None:
        frames = inputs[0] if inputs else None
        if not torch.is_tensor(frames) or frames.untyped_storage().data_ptr() != self.storage:
            self.mode = None
            return
        for layer in self.layers:
            layer.calls = 0
        if torch.is_grad_enabled():
            self.mode = "replay"
            if self.first_offset is not None:
                self.check_learning_frames(frames)
            for layer in self.layers:
                layer.cursor = 0
        else:
            self.mode = "record"
            if self.first_offset is None:  # a new rollout's first acting step
                self.first_offset, self.acting_strides = frames.storage_offset(), frames.stride()
                self.weight_versions = [layer.weight._version for layer in self.layers]
            elif frames.storage_offset() != self.next_offset or frames.stride() != (
                self.acting_strides
            ):
                self.problem = "acting did not step through the rollout's rows in order"
            self.next_offset = frames.storage_offset() + frames.shape[0] * frames.stride(0)

    def check_learning_frames(self, frames: torch.Tensor) -> None:
        """The learning forward must be over the states acting saw, in acting's order, with the
        weights acting used; anything else would replay outputs of other inputs or weights."""
        problem = self.problem
        if problem is None and frames.storage_offset() != self.first_offset:
            problem = "the learning forward must start at the rollout's first acting state"
        elif problem is None and frames.stride() != self.acting_strides:
            problem = "the learning forward's rows are not acting's rows in acting's order"
        elif problem is None:
            changed = [layer.replay_name for layer, version in
                       zip(self.layers, self.weight_versions, strict=True)
                       if layer.weight._version != version]  # fmt: skip
            if changed:
                problem = f"layer {changed[0]!r}'s weights changed between acting and learning"
        if problem is not None:
            self.reset()
            raise RuntimeError(f"ActivationReplay: {problem}")

    def reset(self) -> None:
        """Forget this rollout's recording: the next acting forward starts a new one."""
        self.mode, self.first_offset, self.next_offset, self.problem = None, None, None, None
        for layer in self.layers:
            layer.count = 0

    def _after_forward(self, _model: nn.Module, _inputs: Any, _output: Any) -> None:
        replayed = self.mode == "replay"
        self.mode = None
        if not replayed:
            return
        # the rollout is over: the next acting forward starts a new recording
        left = [(layer, layer.count - layer.cursor) for layer in self.layers]
        self.reset()
        for layer, rows in left:
            if rows:
                raise RuntimeError(
                    f"ActivationReplay: {rows} recorded rows of layer {layer.replay_name!r} were "
                    "not replayed; the learning forward must take the acting rows in order"
                )


def check_supported(name: str, layer: nn.Module) -> None:
    """Raise for a Conv2d or Linear the replay cannot stand in for: a subclass (its own forward
    would be bypassed) or a convolution whose padding is not zeros given as numbers."""
    kind = "Conv2d" if isinstance(layer, nn.Conv2d) else "Linear"
    if type(layer) not in (nn.Conv2d, nn.Linear):
        reason = f"{type(layer).__name__} is a subclass of {kind}"
    elif kind == "Conv2d" and not isinstance(layer.padding, tuple):
        reason = f"its padding is {layer.padding!r}"
    elif kind == "Conv2d" and layer.padding_mode != "zeros":
        reason = f"its padding mode is {layer.padding_mode!r}"
    else:
        return
    raise RuntimeError(
        f"ActivationReplay: cannot replay layer {name!r}: {reason} (it replays exact nn.Conv2d "
        "with numeric zero padding and nn.Linear); build the worker without replay_activations"
    )


class _Recording:
    """What ActivationReplay adds to a Conv2d or Linear: the outputs' rows (a Linear's leading
    dimensions flattened), kept in a buffer that doubles when full and lives across rollouts."""

    replay: ActivationReplay
    replay_name: str  # the layer's name in the model, for error messages
    recorded: torch.Tensor | None
    input_sums: torch.Tensor | None  # each recorded row's input, summed: its fingerprint
    count: int  # rows recorded in this rollout
    cursor: int  # rows taken back by the replay so far
    calls: int  # calls in the current forward (more than one is an error)

    def compute(self, x: torch.Tensor) -> torch.Tensor:
        """The layer's own forward."""
        return super().forward(x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mode = self.replay.mode
        if mode is None:
            return super().forward(x)
        self.calls += 1
        if self.calls > 1:  # its rows would interleave: the replay would hand back the wrong ones
            self.replay.reset()
            raise RuntimeError(
                f"ActivationReplay: layer {self.replay_name!r} is called more than once in one "
                "forward; build the worker without replay_activations"
            )
        if mode == "replay":
            return _Replay.apply(x, self.weight, self.bias, self)
        y = super().forward(x)
        rows = y if y.dim() == 2 or isinstance(self, nn.Conv2d) else y.reshape(-1, y.shape[-1])
        end = self.count + len(rows)
        if self.recorded is None or end > len(self.recorded):
            self.grow(rows, end)
        self.recorded[self.count : end] = rows  # a copy: y may get an in-place activation
        self.input_sums[self.count : end] = row_sums(self, x)
        self.count = end
        return y

    def grow(self, rows: torch.Tensor, end: int) -> None:
        old, old_sums = self.recorded, self.input_sums
        capacity = max(end, 2 * len(old)) if old is not None else end
        self.recorded = torch.empty_like(rows[:1]).expand(capacity, *rows.shape[1:]).clone()
        self.input_sums = torch.empty(capacity, dtype=torch.float32)
        if old is not None:
            self.recorded[: self.count] = old[: self.count]
            self.input_sums[: self.count] = old_sums[: self.count]

    def take(self, rows: int) -> tuple[torch.Tensor, torch.Tensor] | None:
        """The next `rows` recorded rows and their inputs' sums (fewer where the recording
        ends; None if none)."""
        if self.cursor >= self.count:
            return None
        end = min(self.cursor + rows, self.count)
        taken = self.recorded[self.cursor : end], self.input_sums[self.cursor : end]
        self.cursor = end
        return taken


def row_sums(layer: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """A fingerprint of each input row of a Conv2d (a sample) or a Linear (a feature vector):
    the float32 sum of a fixed subset of it (every 4th pixel of every 4th image row, every 4th
    feature), which tells the replay whether the learning pass feeds the layer acting's inputs.
    A subset, summed where it lies: the whole input would cost a tenth of what the replay saves."""
    if isinstance(layer, nn.Conv2d):
        return x[:, :, ::4, ::4].sum(dim=(1, 2, 3), dtype=torch.float32)
    return x[..., ::4].sum(dim=-1, dtype=torch.float32).reshape(-1)


def check_inputs(
    layer: nn.Module, x: torch.Tensor, recorded: torch.Tensor, mixed: bool = False
) -> None:
    """A learning forward whose inputs to a replayed layer differ from acting's (a recurrent
    state or any computation between the layers that differs) would get acting's outputs for
    other inputs: refused. In one precision the sums are of the same numbers in the same order
    and agree up to float rounding; mixed (bf16-learn: acting in fp32, what lies between the
    replayed layers recomputed in bf16) they differ by bf16's rounding, about 1%."""
    current = row_sums(layer, x)[: len(recorded)]
    tolerance = 5e-2 if mixed else 1e-4
    scale = float(recorded.abs().max().clamp_min(1.0))
    if not torch.allclose(current, recorded, rtol=tolerance, atol=tolerance * scale):
        layer.replay.reset()
        raise RuntimeError(
            f"ActivationReplay: layer {layer.replay_name!r} gets other inputs in the learning "
            "forward than while acting; build the worker without replay_activations"
        )


class _ReplayedConv2d(_Recording, nn.Conv2d):
    pass


class _ReplayedLinear(_Recording, nn.Linear):
    pass


class _Replay(torch.autograd.Function):
    """y = layer(x) from the recorded rows (computing only the rest); backward as the layer's."""

    @staticmethod
    def forward(ctx, x, weight, bias, layer):  # noqa: ANN001, ANN205 (autograd's signature)
        conv = isinstance(layer, nn.Conv2d)
        rows = x.shape[0] if conv else x.numel() // x.shape[-1]
        taken = layer.take(rows)
        if taken is not None:
            taken, sums = taken
            mixed = taken.dtype == torch.float32 and torch.is_autocast_enabled("cpu")
            check_inputs(layer, x.detach(), sums, mixed)
        done = 0 if taken is None else len(taken)
        if done < rows:  # rows acting never saw (s_n): computed here, in acting's precision
            rest_x = x[done:] if conv else x.reshape(rows, -1)[done:]
            acting_fp32 = layer.recorded is not None and layer.recorded.dtype == torch.float32
            # bf16-learn acts in fp32: computing s_n in fp32 too keeps every forward value
            # acting's, and autocast does not convert a whole weight matrix for one row
            no_autocast = torch.autocast("cpu", enabled=False)
            with no_autocast if acting_fp32 else contextlib.nullcontext():
                rest = layer.compute(rest_x.float() if acting_fp32 else rest_x)
            y = rest if taken is None else torch.cat([taken, rest.to(taken.dtype)])
        else:
            y = taken.clone()  # a fresh tensor: the caller may modify it in place
        ctx.save_for_backward(x, weight)
        ctx.layer, ctx.has_bias = layer, bias is not None
        # the backward's precision: the learning pass's (bf16 under autocast), as autocast's is
        autocast = torch.is_autocast_enabled("cpu")
        ctx.dtype = torch.get_autocast_dtype("cpu") if autocast else y.dtype
        if conv or x.dim() == 2:
            return y
        return y.view(*x.shape[:-1], y.shape[-1]).clone()  # autograd forbids returning a view

    @staticmethod
    def backward(ctx, grad):  # noqa: ANN001, ANN205
        x, weight = ctx.saved_tensors
        layer = ctx.layer
        need_x, need_w, need_b = ctx.needs_input_grad[:3]
        need_b = need_b and ctx.has_bias
        dtype = ctx.dtype
        grad, xc, wc = grad.to(dtype), x.to(dtype), weight.to(dtype)
        if isinstance(layer, nn.Conv2d):
            grad_x, grad_w, grad_b = torch.ops.aten.convolution_backward(
                grad, xc, wc, [wc.shape[0]] if ctx.has_bias else None,
                list(layer.stride), list(layer.padding), list(layer.dilation), False, [0, 0],
                layer.groups, [need_x, need_w, need_b],
            )  # fmt: skip
        else:
            grad2, x2 = grad.reshape(-1, grad.shape[-1]), xc.reshape(-1, xc.shape[-1])
            grad_x = (grad2 @ wc).view(x.shape) if need_x else None
            grad_w = grad2.t() @ x2 if need_w else None
            grad_b = grad2.sum(0) if need_b else None
        return (
            None if grad_x is None else grad_x.to(x.dtype),
            None if grad_w is None else grad_w.to(weight.dtype),
            None if grad_b is None else grad_b.to(weight.dtype),
            None,
        )
