"""The agent tokens as a raster the decoder reads (beyond the paper).

In the paper only the diffusion model sees the tokens; the decoder D(z, m) draws each vehicle's
speed, size and -2...+2 s path from a latent of 4 channels per 6.25 m cell, which carries a
vehicle's speed and turn only roughly (docs/tokens.md). A decoder with ``C_t`` > 0 also reads the
positioned tokens, written into the output grid around each token's position bin, so the vehicle
it decodes there can take what the token gives.

Each feature is the value of its encoded bin (what the diffusion model sees too), or at generation
the exact value a token was made from (``exact``), and its presence bit; a token without a
position is not drawn (the diffusion model still sees it):

    token, heading_cos, heading_sin, heading_given, length, width, extents_given,
    speed, speed_given, final_speed, final_speed_given, heading_to_final, heading_to_final_given
"""
from __future__ import annotations

import torch

from .encoding import (
    FEATURE_SLICES,
    H2F_BINS,
    H2F_RANGE,
    PRESENCE_SLICE,
    SPEED_BINS,
    SPEED_RANGE,
    token_cells,
)
from .features import FEATURES

TOKEN_CHANNELS = ("token", "heading_cos", "heading_sin", "heading_given", "length", "width", "extents_given",
                  "speed", "speed_given", "final_speed", "final_speed_given", "heading_to_final",
                  "heading_to_final_given")
C_T = len(TOKEN_CHANNELS)
SPEED_SCALE = 10.0   # m/s per unit, so the channels are O(1)
RADIUS = 1           # cells either side of the token's own: a decoded box centre may sit a cell off


def _given(tokens: torch.Tensor, name: str) -> torch.Tensor:
    return tokens[..., PRESENCE_SLICE.start + FEATURES.index(name)]


def _bin_value(tokens: torch.Tensor, name: str, lo: float, hi: float, n: int) -> torch.Tensor:
    return lo + (tokens[..., FEATURE_SLICES[name]].argmax(-1).float() + 0.5) * (hi - lo) / n


def _value(tokens: torch.Tensor, exact: torch.Tensor | None, k: int, name: str, lo: float, hi: float,
           n: int) -> torch.Tensor:
    """A feature's value: the token's exact one where ``exact[..., k]`` is finite (clipped to the
    bins' range, as the encoding clips), else its bin's centre."""
    binned = _bin_value(tokens, name, lo, hi, n)
    if exact is None:
        return binned
    e = exact[..., k].to(binned.dtype)
    return torch.where(torch.isfinite(e), e.nan_to_num(0.0).clamp(lo, hi), binned)


def token_features(tokens: torch.Tensor, fill_speeds: bool = False,
                   exact: torch.Tensor | None = None) -> torch.Tensor:
    """(..., AGENT_TOKEN_DIM) -> (..., C_T): each token's channels of :data:`TOKEN_CHANNELS`, absent
    features zero; with ``fill_speeds`` an absent speed or final speed takes the other's value
    where that one is given (its presence bit stays 0: constant speed as the neutral reading).
    ``exact`` (..., 3): the speed, final speed and heading_to_final a token was made from (NaN:
    unknown), read instead of their bins' centres (a 2 m/s bin alone leaves the decoder ~0.5 m/s
    off the asked speed on average); the one-hot tokens the diffusion model reads are unchanged."""
    g = {f: _given(tokens, f) for f in FEATURES}
    speed = _value(tokens, exact, 0, "speed", *SPEED_RANGE, SPEED_BINS) / SPEED_SCALE * g["speed"]
    final = _value(tokens, exact, 1, "final_speed", *SPEED_RANGE, SPEED_BINS) / SPEED_SCALE * g["final_speed"]
    if fill_speeds:
        speed, final = (torch.where(g["speed"] > 0, speed, final), torch.where(g["final_speed"] > 0, final, speed))
    h2f = _value(tokens, exact, 2, "heading_to_final", *H2F_RANGE, H2F_BINS) / H2F_RANGE[1]
    head = tokens[..., FEATURE_SLICES["heading"]]
    cols = [torch.ones_like(speed), head[..., 0] * g["heading"], head[..., 1] * g["heading"], g["heading"],
            tokens[..., FEATURE_SLICES["length"]][..., 0] * g["length"],
            tokens[..., FEATURE_SLICES["width"]][..., 0] * g["width"], g["length"],
            speed, g["speed"], final, g["final_speed"],
            h2f * g["heading_to_final"], g["heading_to_final"]]
    return torch.stack(cols, -1)


def token_raster(tokens: torch.Tensor, pad: torch.Tensor, res: int = 64, radius: int = RADIUS,
                 fill_speeds: bool = False, exact: torch.Tensor | None = None) -> torch.Tensor:
    """(B, T, AGENT_TOKEN_DIM) tokens, (B, T) padding -> (B, C_T, res, res) (``fill_speeds``,
    ``exact`` (B, T, 3): see :func:`token_features`; a decoder's own encoding is
    ``ScenarioAutoencoder.token_raster``).

    Rows and columns as the map raster's (``token_cells``); each positioned token fills the
    (2 radius + 1)^2 cells around its own, clipped at the window's edge. Where two tokens' squares
    meet, the later token's values stand.
    """
    b, t = pad.shape
    out = torch.zeros(b, res, res, C_T, dtype=torch.float32, device=tokens.device)
    if t == 0:
        return out.permute(0, 3, 1, 2).contiguous()
    cell, placed = token_cells(tokens, pad, res)
    feats = token_features(tokens.float(), fill_speeds, exact)
    rows, cols = cell // res, cell % res
    batch = torch.arange(b, device=tokens.device)[:, None].expand(b, t)
    for dr in range(-radius, radius + 1):
        for dc in range(-radius, radius + 1):
            r, c = rows + dr, cols + dc
            ok = placed & (r >= 0) & (r < res) & (c >= 0) & (c < res)
            out[batch[ok], r[ok], c[ok]] = feats[ok]
    return out.permute(0, 3, 1, 2).contiguous()


EXACT_FEATURES = ("speed", "final_speed", "heading_to_final")


def exact_values(token_sets, lengths, skip=None) -> torch.Tensor:
    """(B, Tmax, 3) of :data:`EXACT_FEATURES` per token, NaN where unknown: ``token_sets`` per window
    the feature dicts its encoded tokens were made from, in their order (None, or a set whose
    length is not the window's token count (``lengths``): all unknown); ``skip(dict)`` true: that
    token keeps its bins."""
    b, t = len(lengths), max(lengths, default=0)
    out = torch.full((b, t, len(EXACT_FEATURES)), float("nan"))
    for i, (dicts, n) in enumerate(zip(token_sets, lengths)):
        if dicts is None or len(dicts) != n:
            continue
        for j, d in enumerate(dicts):
            if skip is not None and skip(d):
                continue
            for k, name in enumerate(EXACT_FEATURES):
                v = d.get(name) if hasattr(d, "get") else None
                if v is not None:
                    out[i, j, k] = float(v)
    return out
