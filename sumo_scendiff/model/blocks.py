"""Shared convolutional building blocks (latent-diffusion / EDM style).

Used by the scenario autoencoder (paper section 3.1, appendix C) and by the latent
diffusion model. API is stable:

* ``ResnetBlock(in_ch, out_ch, emb_ch=0, dropout=0.0)``; ``forward(x, emb=None)``.
  If ``emb_ch > 0``, ``emb`` (B, emb_ch) is projected to a per-channel bias added
  after the first convolution.
* ``Downsample(ch)``: stride-2 3x3 convolution (H -> H/2).
* ``Upsample(ch)``: nearest-neighbour x2 followed by a 3x3 convolution.
* ``widen_input(state, key, weight)``: a conv weight of a state dict grown to more input channels.
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


def widen_input(state: dict, key: str, weight: torch.Tensor) -> dict:
    """``state`` with the conv weight ``state[key]`` (out, in_old, k, k) fitted to ``weight``'s shape
    (out, in_new >= in_old, k, k): the new trailing input channels get zero weights, so a module
    warm-started from the old state computes what it did until training teaches it the new input."""
    old = state.get(key)
    if old is None or old.shape[1] >= weight.shape[1]:
        return state
    w = torch.zeros_like(weight)
    w[:, : old.shape[1]] = old
    return {**state, key: w}


def widen_output(state: dict, key: str, param: torch.Tensor) -> dict:
    """``state`` with the conv weight or bias ``state[key]`` (out_old, ...) fitted to ``param``'s shape
    (out_new >= out_old, ...): the new trailing output channels start at zero, the old ones keep
    their values (a head warm-started with more outputs computes the old outputs unchanged)."""
    old = state.get(key)
    if old is None or old.shape[0] >= param.shape[0]:
        return state
    w = torch.zeros_like(param)
    w[: old.shape[0]] = old
    return {**state, key: w}


def grow_segments(old: torch.Tensor, like: torch.Tensor, dim: int, old_sizes: tuple[int, ...],
                  new_sizes: tuple[int, ...]) -> torch.Tensor:
    """``like`` (a tensor of the grown layout: its values fill what is new) with ``old``'s values put
    back: along ``dim``, ``old`` is made of consecutive segments of ``old_sizes`` and ``like`` of
    ``new_sizes`` (each at least as long); segment ``i`` of ``old`` goes to the start of segment ``i``.
    E.g. an encoder's ``conv_out`` of ``[mu; logvar]`` grown from 4 + 4 to 8 + 8 latent channels."""
    if len(old_sizes) != len(new_sizes) or any(n < o for o, n in zip(old_sizes, new_sizes)):
        raise ValueError(f"cannot grow segments {old_sizes} to {new_sizes}")
    out = like.detach().clone()
    for src, dst, n in zip(torch.tensor((0,) + old_sizes).cumsum(0).tolist(),
                           torch.tensor((0,) + new_sizes).cumsum(0).tolist(), old_sizes):
        out.narrow(dim, dst, n).copy_(old.narrow(dim, src, n))
    return out
