"""Activation replay: the learning forward takes back the layer outputs that acting computed.

Acting and learning run the same synced network theta' on the same states (Algorithm 1), so
every Conv2d and Linear output of the learning forward was already computed while acting, one
step at a time. `replay_activations(model, rollout_frames)`, called once before a worker's loop,
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
backward runs in bf16. It pays on the fast setting (K = 16 envs per worker: 1.17x the steps/s,
`benchmarks/a3c_throughput.py --replay on off`, results/throughput_package), and workers with
K = 1 go without it.
"""

from __future__ import annotations

import contextlib
from typing import Any

import torch
import torch.nn as nn


def replay_activations(model: nn.Module, rollout_frames: torch.Tensor) -> ActivationReplay | None:
    """Attach an ActivationReplay to model for forwards on rows of rollout_frames (t_max + 1, K,
    ...), where it pays: with K > 1 envs per worker. With K = 1 the acting pass's copies cost
    more than the update's forward saves (replay on against off, 3 rounds each: 17% faster at
    K = 16, 1-5% slower at K = 1; results/throughput_package), so the model is left as it is."""
    if rollout_frames.shape[1] == 1:
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
        self.layers: list[_ReplayedConv2d | _ReplayedLinear] = []
        for layer in model.modules():
            replayed = {nn.Conv2d: _ReplayedConv2d, nn.Linear: _ReplayedLinear}.get(type(layer))
            if replayed is _ReplayedConv2d and (
                not isinstance(layer.padding, tuple) or layer.padding_mode != "zeros"
            ):
                replayed = None  # "same"/"valid" or non-zero padding: computed as before
            if replayed is not None:
                layer.__class__ = replayed  # a subclass: only forward changes
                layer.replay, layer.recorded, layer.count, layer.cursor = self, None, 0, 0
                self.layers.append(layer)
        model.register_forward_pre_hook(self._before_forward)
        model.register_forward_hook(self._after_forward)

    def _before_forward(self, _model: nn.Module, inputs: tuple[Any, ...]) -> None:
        frames = inputs[0] if inputs else None
        if not torch.is_tensor(frames) or frames.untyped_storage().data_ptr() != self.storage:
            self.mode = None
        elif torch.is_grad_enabled():
            if self.first_offset is not None and frames.storage_offset() != self.first_offset:
                raise RuntimeError(
                    "ActivationReplay: the learning forward must start at the rollout's first "
                    "acting state"
                )
            self.mode = "replay"
            for layer in self.layers:
                layer.cursor = 0
        else:
            if self.first_offset is None:
                self.first_offset = frames.storage_offset()
            self.mode = "record"

    def _after_forward(self, _model: nn.Module, _inputs: Any, _output: Any) -> None:
        replayed, self.mode = self.mode == "replay", None
        if not replayed:
            return
        # the rollout is over: the next acting forward starts a new recording
        left = [(layer, layer.count - layer.cursor) for layer in self.layers]
        self.first_offset = None
        for layer in self.layers:
            layer.count = 0
        for layer, rows in left:
            if rows:
                raise RuntimeError(
                    f"ActivationReplay: {rows} recorded rows of {layer} were not replayed; the "
                    "learning forward must take the acting rows in order"
                )


class _Recording:
    """What ActivationReplay adds to a Conv2d or Linear: the outputs' rows (a Linear's leading
    dimensions flattened), kept in a buffer that doubles when full and lives across rollouts."""

    replay: ActivationReplay
    recorded: torch.Tensor | None
    count: int  # rows recorded in this rollout
    cursor: int  # rows taken back by the replay so far

    def compute(self, x: torch.Tensor) -> torch.Tensor:
        """The layer's own forward."""
        return super().forward(x)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mode = self.replay.mode
        if mode is None:
            return super().forward(x)
        if mode == "replay":
            return _Replay.apply(x, self.weight, self.bias, self)
        y = super().forward(x)
        rows = y if y.dim() == 2 or isinstance(self, nn.Conv2d) else y.reshape(-1, y.shape[-1])
        end = self.count + len(rows)
        if self.recorded is None or end > len(self.recorded):
            self.grow(rows, end)
        self.recorded[self.count : end] = rows  # a copy: y may get an in-place activation
        self.count = end
        return y

    def grow(self, rows: torch.Tensor, end: int) -> None:
        old = self.recorded
        capacity = max(end, 2 * len(old)) if old is not None else end
        self.recorded = torch.empty_like(rows[:1]).expand(capacity, *rows.shape[1:]).clone()
        if old is not None:
            self.recorded[: self.count] = old[: self.count]

    def take(self, rows: int) -> torch.Tensor | None:
        """The next `rows` recorded rows (fewer where the recording ends; None if none)."""
        if self.cursor >= self.count:
            return None
        taken = self.recorded[self.cursor : min(self.cursor + rows, self.count)]
        self.cursor += len(taken)
        return taken


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
