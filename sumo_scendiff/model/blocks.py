"""Shared convolutional building blocks (latent-diffusion / EDM style).

Used by the scenario autoencoder (paper section 3.1, appendix C) and by the latent
diffusion model. API is stable:

* ``ResnetBlock(in_ch, out_ch, emb_ch=0, dropout=0.0)``; ``forward(x, emb=None)``.
  If ``emb_ch > 0``, ``emb`` (B, emb_ch) is projected to a per-channel bias added
  after the first convolution.
* ``Downsample(ch)``: stride-2 3x3 convolution (H -> H/2).
* ``Upsample(ch)``: nearest-neighbour x2 followed by a 3x3 convolution.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def group_norm(ch: int, max_groups: int = 32) -> nn.GroupNorm:
    """GroupNorm with the largest group count <= ``max_groups`` that divides ``ch``."""
    g = min(max_groups, ch)
    while ch % g:
        g -= 1
    return nn.GroupNorm(g, ch, eps=1e-6)


class ResnetBlock(nn.Module):
    """Pre-activation residual block: (GN, SiLU, conv3x3) x 2 with optional embedding bias.

    Args:
        in_ch: input channels.
        out_ch: output channels (a 1x1 skip projection is used if it differs from ``in_ch``).
        emb_ch: width of the conditioning embedding (0 = no embedding).
        dropout: dropout probability before the second convolution.
    """

    def __init__(self, in_ch: int, out_ch: int, emb_ch: int = 0, dropout: float = 0.0):
        super().__init__()
        self.in_ch, self.out_ch, self.emb_ch = in_ch, out_ch, emb_ch
        self.norm1 = group_norm(in_ch)
        self.conv1 = nn.Conv2d(in_ch, out_ch, 3, padding=1)
        self.emb_proj = nn.Linear(emb_ch, out_ch) if emb_ch > 0 else None
        self.norm2 = group_norm(out_ch)
        self.dropout = nn.Dropout(dropout)
        self.conv2 = nn.Conv2d(out_ch, out_ch, 3, padding=1)
        self.skip = nn.Conv2d(in_ch, out_ch, 1) if in_ch != out_ch else nn.Identity()

    def forward(self, x: torch.Tensor, emb: torch.Tensor | None = None) -> torch.Tensor:
        """x: (B, in_ch, H, W); emb: (B, emb_ch) or None -> (B, out_ch, H, W)."""
        h = self.conv1(F.silu(self.norm1(x)))
        if self.emb_proj is not None and emb is not None:
            h = h + self.emb_proj(F.silu(emb))[:, :, None, None]
        h = self.conv2(self.dropout(F.silu(self.norm2(h))))
        return self.skip(x) + h


class Downsample(nn.Module):
    """Stride-2 3x3 convolution, (B, ch, H, W) -> (B, ch, H/2, W/2)."""

    def __init__(self, ch: int):
        super().__init__()
        self.conv = nn.Conv2d(ch, ch, 3, stride=2, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


class Upsample(nn.Module):
    """Nearest-neighbour x2 upsampling followed by a 3x3 convolution."""

    def __init__(self, ch: int):
        super().__init__()
        self.conv = nn.Conv2d(ch, ch, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(F.interpolate(x, scale_factor=2.0, mode="nearest"))


def unused(module: nn.Module) -> torch.Tensor | float:
    """0, depending on every weight of ``module`` while gradients are on: for a module a batch leaves
    out (its gradients are then zero, as they would be through it), since DistributedDataParallel
    waits for a gradient of every weight on every process (a process whose share of a batch had no
    agent token stopped a run)."""
    if not torch.is_grad_enabled():
        return 0.0
    return sum(p.sum() for p in module.parameters()) * 0.0
