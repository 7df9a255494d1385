"""The scripts' convolutions as matmuls, for the batched backend (a3c_runtime.batched).

Under torch.func.vmap an nn.Conv2d whose weight is stacked over N runs becomes one grouped
convolution, which cuDNN runs as a kernel per run (per group). Every convolution the scripts use
by default has kernel = 2 x stride and no padding (8/4, 4/2), and such a convolution is a 2x2
convolution over the input cut into stride x stride blocks (space-to-depth): each output cell
sees exactly its block and the 3 blocks right, below and diagonal of it. Gathered, that is one
matmul of (B*Ho*Wo, 4*s*s*C) by (4*s*s*C, O), which vmap turns into one bmm for all N runs.
(Measured speed is for a GPU to tell; this module only keeps the function the same.)
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def qualifies(conv: nn.Module) -> bool:
    """Whether conv is a Conv2d that SpaceToDepthConv2d computes as a matmul: square kernel =
    2 x stride, no padding, dilation 1, one group (padding_mode is moot without padding)."""
    return (
        isinstance(conv, nn.Conv2d)
        and conv.stride[0] == conv.stride[1]
        and tuple(conv.kernel_size) == (2 * conv.stride[0],) * 2
        and conv.padding in ((0, 0), "valid")
        and tuple(conv.dilation) == (1, 1)
        and conv.groups == 1
    )


class SpaceToDepthConv2d(nn.Conv2d):
    """nn.Conv2d (same parameters, same state_dict) computed by space-to-depth and one matmul
    when it qualifies (see qualifies); otherwise nn.Conv2d's own forward. The output is
    (..., O, Ho, Wo) with channels_last strides: a view of the matmul's NHWC result."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not qualifies(self):  # the module's geometry, not data: fine under vmap
            return super().forward(x)
        s, (height, width) = self.stride[0], x.shape[-2:]
        rows, cols = height // s, width // s  # blocks; output Ho = rows - 1, Wo = cols - 1
        # NHWC (a view for channels_last input), cropped to whole blocks as the conv ignores the
        # remainder, then (..., rows, cols, s*s*C) in (row in block, column in block, C) order
        x = x.movedim(-3, -1)[..., : rows * s, : cols * s, :]
        blocks = x.unflatten(-2, (cols, s)).unflatten(-4, (rows, s)).transpose(-4, -3)
        blocks = blocks.flatten(-3)
        # each output cell's 2x2 neighbouring blocks, in (block row, block column) order
        patches = torch.cat(
            (blocks[..., :-1, :-1, :], blocks[..., :-1, 1:, :],
             blocks[..., 1:, :-1, :], blocks[..., 1:, 1:, :]),
            dim=-1,
        )  # fmt: skip
        # weight (O, C, 2s, 2s) -> (O, block row, block column, row, column, C), as patches
        weight = self.weight.unflatten(-1, (2, s)).unflatten(-3, (2, s))  # (O, C, 2, s, 2, s)
        weight = weight.permute(0, 2, 4, 3, 5, 1).flatten(1)
        return F.linear(patches, weight, self.bias).movedim(-1, -3)


def matmul_convs(model: nn.Module) -> nn.Module:
    """model, in place, with every plain nn.Conv2d that qualifies made a SpaceToDepthConv2d;
    other convolutions are left as they are. Changing the instance's class is safe: the subclass
    adds no attributes, parameters or buffers, so state_dict, parameters() and functional_call
    see the same module; only forward differs. Subclasses of nn.Conv2d are not touched (their
    own forward would be lost)."""
    for module in model.modules():
        if type(module) is nn.Conv2d and qualifies(module):
            module.__class__ = SpaceToDepthConv2d
    return model
