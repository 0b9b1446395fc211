"""MultiBin heading head of the detection decoder (beyond the paper).

After the MultiBin orientation head of Mousavian et al., "3D Bounding Box Estimation Using Deep
Learning and Geometry" (CVPR 2017): the heading circle is cut into K bins of width w = 2 pi / K
centred on k w; per cell the decoder predicts K bin logits and, per bin, a residual angle r_k, and
the decoded heading is  yaw = k* w + r_k*  with  k* = argmax_k logit_k.

Why: a cos/sin regression trained with L1 returns, where the latent leaves open which of several
lanes a car is on (the lanes crossing in a junction), a heading *between* the candidates that
matches none of them (docs/history.md, "How the shipped checkpoint was found", item 12). A classification over bins
keeps the modes apart and the argmax commits to one; the residual refines within the chosen bin.

Loss (per matched box): cross-entropy on the ground-truth bin, and L1 on the residual of the
ground-truth bin and of its two neighbours (overlapping bins as in MultiBin, so the bin the argmax
picks near a boundary has a trained residual as well).

Layout of the head's 2K channels: [0, K) logits, [K, 2K) residuals in radians.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def bin_width(k: int) -> float:
    """w = 2 pi / K radians."""
    return 2.0 * math.pi / k


def bin_centres(k: int, device=None) -> torch.Tensor:
    """(K,) centres k w of the bins, radians."""
    return torch.arange(k, device=device, dtype=torch.float32) * bin_width(k)


def _wrap(a: torch.Tensor) -> torch.Tensor:
    return torch.remainder(a + math.pi, 2.0 * math.pi) - math.pi


def heading_targets(yaw: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Ground-truth headings (M,) -> (bin (M,) long, residual targets (M, K), trained mask (M, K)).

    The residual target of bin j is wrap(yaw - centre_j); the mask holds the ground-truth bin and
    its two neighbours (|target| <= 1.5 w)."""
    w = bin_width(k)
    gt = torch.remainder(torch.round(yaw / w).long(), k)
    res = _wrap(yaw[:, None] - bin_centres(k, yaw.device)[None, :])
    j = torch.arange(k, device=yaw.device)[None, :]
    d = torch.remainder(j - gt[:, None], k)
    mask = (d == 0) | (d == 1) | (d == k - 1)
    return gt, res, mask


def heading_loss(pred: torch.Tensor, yaw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Head outputs (M, 2K) against ground-truth headings (M,) -> (cross-entropy (M,), mean L1 of
    the trained residuals (M,), radians)."""
    k = pred.shape[-1] // 2
    gt, res, mask = heading_targets(yaw, k)
    ce = F.cross_entropy(pred[:, :k], gt, reduction="none")
    m = mask.to(pred.dtype)
    l1 = ((pred[:, k:] - res).abs() * m).sum(-1) / m.sum(-1)
    return ce, l1


def decode_heading(pred: torch.Tensor) -> torch.Tensor:
    """Head outputs (..., 2K) -> yaw (...) in (-pi, pi]: the argmax bin's centre plus its residual."""
    k = pred.shape[-1] // 2
    best = pred[..., :k].argmax(-1, keepdim=True)
    r = torch.gather(pred[..., k:], -1, best).squeeze(-1)
    return _wrap(best.squeeze(-1).to(pred.dtype) * bin_width(k) + r)


def heading_probability(pred: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Head outputs (M, 2K) and one yaw per row (M,) -> the softmax bin posterior at that yaw (M,),
    linear between the two nearest bin centres."""
    k = pred.shape[-1] // 2
    p = torch.softmax(pred[..., :k], -1)
    u = torch.remainder(yaw, 2.0 * math.pi) / bin_width(k)
    k0 = torch.floor(u).long() % k
    f = (u - torch.floor(u)).to(p.dtype)
    p0 = torch.gather(p, -1, k0[..., None]).squeeze(-1)
    p1 = torch.gather(p, -1, ((k0 + 1) % k)[..., None]).squeeze(-1)
    return (1.0 - f) * p0 + f * p1
