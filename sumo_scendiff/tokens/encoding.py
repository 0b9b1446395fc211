"""Agent and global scene tokens (paper sec. 3.3 "Token Conditioning", sec. 4.3.1, appendix D.3).

Beyond the paper, one model accepts **any subset of features per token**: every feature has a
presence bit, and an absent feature is encoded as zeros with its bit 0. The agent token is

    concat(x[64], y[64], heading[2], length[1], width[1], speed[10], final_speed[10],
           heading_to_final[10], presence[8])                                   -> 170 channels

* ``x``, ``y``: scene-frame metres relative to the window centre, one-hot over 64 bins on
  [-50, 50] (1.5625 m per bin; x = 0 falls in bin 32, values at the edge go to the end bins);
* ``heading``: yaw in the scene frame (radians, CCW), encoded as (cos, sin);
* ``length``, ``width``: metres, encoded as log1p(value);
* ``speed`` (t = 0) and ``final_speed`` (t = +2 s): m/s, one-hot over 10 bins on [0, 20] m/s,
  speeds above 20 m/s are clipped into the last bin;
* ``heading_to_final``: direction of the displacement from the t = 0 position to the t = +2 s
  position relative to the agent's heading (radians, CCW positive = turning left), one-hot over
  10 bins on [-0.7, 0.7], clipped. It is *absent* when the +2 s pose is unobserved or the agent
  moves less than :data:`MIN_DISPLACEMENT` (0.5 m) in 2 s (the direction is undefined for a
  stationary agent); a present ``heading_to_final`` therefore also tells the model "this agent
  moves".

The global scene token is p_mask bucketed into 10 one-hot bins [0, 0.1), ..., [0.9, 1.0]
(1.0 falls in the last bin). It is always present.

Training-time partial tokenisation (:mod:`~sumo_scendiff.tokens.masking`: ``sample_token_mask``,
``sample_feature_dropout``, ``partial_tokens``): 40 % of scenes keep every token (p_mask = 0), 60 % draw
p_mask ~ Beta(2, 1); each agent token is dropped with probability p_mask. Kept tokens then undergo
*feature dropout* so the model learns every feature subset: with probability 0.5 a token keeps
all its features; otherwise each feature group -- position (x, y), heading, extents
(length, width), speed, final_speed, heading_to_final -- is dropped independently with
probability 0.3, except position, which is dropped with probability 0.15: a token without a
position ("a 12 m bus somewhere", "a vehicle doing 15 m/s") is legal and useful, but it is a much
weaker, set-level constraint, and most user tokens pin a position, so training spends most of
its budget on positioned tokens. Features are dropped by whole group, so :func:`validate_token_features`
rejects half a group (x without y, length without width): the model never saw that.

Encoding is numpy (float32); :func:`pad_tokens` turns token lists into batched torch tensors.
"""
from __future__ import annotations

from typing import Any, Mapping, Optional, Sequence

import numpy as np
import torch

from ..core.geometry import T0, T_FINAL, TIMES, wrap_angle
from .features import FEATURES, SEEDING_KEYS, TokenError

FEATURE_DIMS: dict[str, int] = {"x": 64, "y": 64, "heading": 2, "length": 1, "width": 1,
                                "speed": 10, "final_speed": 10, "heading_to_final": 10}
N_FEATURES = len(FEATURES)                    # 8 presence bits
FEATURE_SLICES: dict[str, slice] = {}
_o = 0
for _f in FEATURES:
    FEATURE_SLICES[_f] = slice(_o, _o + FEATURE_DIMS[_f])
    _o += FEATURE_DIMS[_f]
PRESENCE_SLICE = slice(_o, _o + N_FEATURES)
AGENT_TOKEN_DIM = _o + N_FEATURES             # 170
P_MASK_BINS = 10
DENSITY_RANGE = (2.0, 150.0)  # vehicles per km of car lane: empty streets to stop-and-go queues
DENSITY_BINS = 12             # log-spaced: each bin about 43 % wider than the last
GLOBAL_TOKEN_DIM = P_MASK_BINS + DENSITY_BINS + 1   # p_mask, density, density's presence bit
del _o, _f

FEATURE_GROUPS: dict[str, tuple[str, ...]] = {
    "position": ("x", "y"), "heading": ("heading",), "extents": ("length", "width"),
    "speed": ("speed",), "final_speed": ("final_speed",), "heading_to_final": ("heading_to_final",),
}

WINDOW_HALF = 50.0          # metres; positions live in [-50, 50]
POS_BINS = 64
SPEED_RANGE = (0.0, 20.0)   # m/s
SPEED_BINS = 10
H2F_RANGE = (-0.7, 0.7)     # rad
H2F_BINS = 10
MIN_DISPLACEMENT = 0.5      # metres in 2 s below which heading_to_final is undefined (absent)

assert AGENT_TOKEN_DIM == 170


# --------------------------------------------------------------------------------------------
# Encoding
# --------------------------------------------------------------------------------------------

def _bin(v: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
    """Index of the bin of v among n equal bins on [lo, hi]; values outside are clipped."""
    idx = np.floor((v - lo) / (hi - lo) * n)
    return np.clip(np.nan_to_num(idx, nan=0.0), 0, n - 1).astype(np.int64)


def _one_hot(idx: np.ndarray, n: int) -> np.ndarray:
    out = np.zeros((len(idx), n), np.float32)
    out[np.arange(len(idx)), idx] = 1.0
    return out


def _encode_feature(name: str, v: np.ndarray) -> np.ndarray:
    """(T,) raw values -> (T, FEATURE_DIMS[name]) encoding (no presence handling)."""
    if name in ("x", "y"):
        return _one_hot(_bin(v, -WINDOW_HALF, WINDOW_HALF, POS_BINS), POS_BINS)
    if name == "heading":
        return np.stack([np.cos(v), np.sin(v)], -1).astype(np.float32)
    if name in ("length", "width"):
        return np.log1p(np.maximum(v, 0.0)).astype(np.float32)[:, None]
    if name in ("speed", "final_speed"):
        return _one_hot(_bin(v, *SPEED_RANGE, SPEED_BINS), SPEED_BINS)
    if name == "heading_to_final":
        return _one_hot(_bin(v, *H2F_RANGE, H2F_BINS), H2F_BINS)
    raise TokenError(f"unknown token feature {name!r}; expected one of {', '.join(FEATURES)}")


def _to_numpy(a: Any) -> np.ndarray:
    if isinstance(a, torch.Tensor):
        a = a.detach().cpu().numpy()
    return np.asarray(a)


def encode_agent_tokens(features: Mapping[str, Any],
                        present: Optional[Mapping[str, Any]] = None) -> np.ndarray:
    """Encode T agent tokens.

    Args:
        features: feature name -> (T,) values (numpy or torch). Missing names are absent for
            every token. Values are clipped into the bins; see :func:`validate_token_features`
            for user-facing checks.
        present: feature name -> (T,) bool. Defaults, per feature, to "value is finite", so NaN
            marks a single absent value. An absent feature is encoded as zeros with its bit 0.

    Returns:
        (T, AGENT_TOKEN_DIM) float32.
    """
    present = present or {}
    for name in list(features) + list(present):
        if name not in FEATURE_DIMS:
            raise TokenError(f"unknown token feature {name!r}; expected one of {', '.join(FEATURES)}")
    lens = {len(np.atleast_1d(_to_numpy(v))) for v in list(features.values()) + list(present.values())}
    if len(lens) > 1:
        raise TokenError(f"token features have different lengths {sorted(lens)}")
    t = lens.pop() if lens else 0
    out = np.zeros((t, AGENT_TOKEN_DIM), np.float32)
    for i, name in enumerate(FEATURES):
        if name not in features:
            continue
        v = np.atleast_1d(_to_numpy(features[name])).astype(np.float64)
        p = np.isfinite(v)
        if name in present:
            p = p & np.atleast_1d(_to_numpy(present[name])).astype(bool)
        if not p.any():
            continue
        enc = _encode_feature(name, np.where(p, v, 0.0))
        out[:, FEATURE_SLICES[name]] = enc * p[:, None]
        out[:, PRESENCE_SLICE.start + i] = p
    return out


def features_from_scene(boxes: np.ndarray, traj: np.ndarray, traj_mask: np.ndarray,
                        speed: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Every token feature of every agent from the sparse scene arrays (see :mod:`.scene`).

    Returns ``(features, present)``, both name -> (N,) arrays. ``speed`` is speed[:, t0],
    ``final_speed`` speed[:, +2 s] (present iff observed), ``heading_to_final`` the direction of
    traj[:, +2 s] - traj[:, t0] relative to the box heading (present iff the +2 s pose is observed
    and the displacement is >= MIN_DISPLACEMENT).
    """
    boxes = np.asarray(boxes, np.float64).reshape(-1, 5)
    n = len(boxes)
    traj = np.asarray(traj, np.float64).reshape(n, len(TIMES), 3)
    mask = np.asarray(traj_mask, bool).reshape(n, len(TIMES))
    speed = np.asarray(speed, np.float64).reshape(n, len(TIMES))
    ones = np.ones(n, bool)
    start = np.where(mask[:, T0, None], traj[:, T0, :2], boxes[:, :2])
    disp = traj[:, T_FINAL, :2] - start
    dist = np.hypot(disp[:, 0], disp[:, 1])
    h2f = wrap_angle(np.arctan2(disp[:, 1], disp[:, 0]) - boxes[:, 2])
    feats = {"x": boxes[:, 0], "y": boxes[:, 1], "heading": boxes[:, 2], "length": boxes[:, 3],
             "width": boxes[:, 4], "speed": speed[:, T0], "final_speed": speed[:, T_FINAL],
             "heading_to_final": h2f}
    pres = {"x": ones, "y": ones, "heading": ones, "length": ones, "width": ones,
            "speed": ones.copy(), "final_speed": mask[:, T_FINAL].copy(),
            "heading_to_final": mask[:, T_FINAL] & (dist >= MIN_DISPLACEMENT)}
    return feats, pres


def feature_dicts(features: Mapping[str, np.ndarray], present: Mapping[str, np.ndarray],
                  names: Sequence[str] = FEATURES) -> list[dict]:
    """The user-facing token format (one dict per agent, present features only) of
    :func:`features_from_scene`'s arrays, restricted to ``names``."""
    n = len(next(iter(features.values()))) if features else 0
    return [{f: float(features[f][i]) for f in names if present[f][i]} for i in range(n)]


def tokens_from_scene(boxes: np.ndarray, traj: np.ndarray, traj_mask: np.ndarray,
                      speed: np.ndarray) -> np.ndarray:
    """(N, AGENT_TOKEN_DIM) tokens with every computable feature of every agent."""
    return encode_agent_tokens(*features_from_scene(boxes, traj, traj_mask, speed))


def density_bins(density) -> np.ndarray:
    """Vehicles per km of car lane -> bin index on the log scale over :data:`DENSITY_RANGE` (values
    outside fall into the end bins)."""
    edges = np.geomspace(*DENSITY_RANGE, DENSITY_BINS + 1)
    d = np.maximum(np.asarray(density, np.float64), 1e-9)
    return np.clip(np.searchsorted(edges, d, side="right") - 1, 0, DENSITY_BINS - 1)


def density_of_bin(idx) -> np.ndarray:
    """The geometric centre (veh/km) of density bin ``idx``."""
    edges = np.geomspace(*DENSITY_RANGE, DENSITY_BINS + 1)
    idx = np.asarray(idx)
    return np.sqrt(edges[idx] * edges[idx + 1])


def global_token(p_mask: float | Sequence[float] | np.ndarray, density=None,
                 dim: int = GLOBAL_TOKEN_DIM) -> np.ndarray:
    """p_mask (scalar or (B,)) -> one-hot over 10 buckets [0, .1), ..., [.9, 1.0] (1.0 falls in the
    last), then, for a model with the density condition (``dim`` = :data:`GLOBAL_TOKEN_DIM`), the
    window's density in vehicles per km of car lane one-hot over :data:`DENSITY_BINS` log bins and
    its presence bit (``density`` None or NaN: absent). Returns (dim,) or (B, dim) float32; ``dim`` =
    :data:`P_MASK_BINS` is the p_mask part alone, what models without the density condition read."""
    try:
        if isinstance(p_mask, (bool, np.bool_, str, bytes)):
            raise TypeError
        p = np.asarray(p_mask, np.float64)
    except (TypeError, ValueError):
        raise TokenError(f"p_mask must be a number in [0, 1], got {p_mask!r}") from None
    if not np.all(np.isfinite(p)) or np.any(p < 0) or np.any(p > 1):
        raise TokenError(f"p_mask must be in [0, 1], got {p_mask!r}")
    if dim not in (P_MASK_BINS, GLOBAL_TOKEN_DIM):
        raise ValueError(f"global token dim must be {P_MASK_BINS} or {GLOBAL_TOKEN_DIM}, got {dim}")
    idx = np.minimum(np.floor(p * P_MASK_BINS), P_MASK_BINS - 1).astype(np.int64)
    out = _one_hot(idx.reshape(-1), P_MASK_BINS)
    if dim == GLOBAL_TOKEN_DIM:
        d = np.broadcast_to(np.asarray(np.nan if density is None else density, np.float64),
                            out.shape[:1]).astype(np.float64)
        if np.any(d[np.isfinite(d)] < 0):
            raise TokenError(f"density must be >= 0 vehicles per km, got {density!r}")
        dens = np.zeros((len(out), DENSITY_BINS + 1), np.float32)
        present = np.isfinite(d)
        dens[present, density_bins(d[present])] = 1.0
        dens[present, -1] = 1.0
        out = np.concatenate([out, dens], axis=1)
    elif density is not None and np.any(np.isfinite(np.asarray(density, np.float64))):
        raise TokenError("this model has no density condition (a checkpoint trained before it)")
    return out[0] if p.ndim == 0 else out


# --------------------------------------------------------------------------------------------
# User-facing validation and batching
# --------------------------------------------------------------------------------------------

# no road vehicle is near these (docs/tokens.md): a token beyond them is a typo, and its number
# would overflow the model's float32 tensors
MAX_SIZE_M = 1000.0
MAX_SPEED_MS = 1000.0


def validate_token_features(features: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """Check user token features and return them as name -> (T,) float64 arrays.

    ``features`` maps feature names to a scalar (one token) or a sequence (one value per token);
    None or NaN means "absent" for that token. Raises :class:`TokenError` for an unknown name,
    a non-numeric or infinite value, mismatched lengths, a non-positive length/width, a negative
    speed/final_speed, a position outside the 100 m window, or half a feature group (x without y,
    length without width).
    """
    out: dict[str, np.ndarray] = {}
    for name, val in features.items():
        if name not in FEATURE_DIMS:
            raise TokenError(f"unknown token feature {name!r}; expected one of {', '.join(FEATURES)}")
        if val is None:
            continue
        raw = _to_numpy(val) if isinstance(val, torch.Tensor) else val
        arr = np.atleast_1d(np.asarray(raw, dtype=object))
        if arr.ndim != 1:
            raise TokenError(f"token feature {name!r} must be a number or a 1-D sequence of "
                             f"numbers, got shape {arr.shape}")
        try:
            if arr.dtype == object and any(isinstance(a, (str, bytes, bool, np.bool_)) for a in arr.ravel()):
                raise TypeError
            arr = np.array([np.nan if a is None else a for a in arr.ravel()], dtype=np.float64)
        except (TypeError, ValueError):
            raise TokenError(f"token feature {name!r} must be numeric, got {val!r}") from None
        if np.isinf(arr).any():
            raise TokenError(f"token feature {name!r} must be finite, got {val!r}")
        out[name] = arr
    lens = {len(v) for v in out.values()}
    if len(lens) > 1:
        raise TokenError(f"token features have different lengths {sorted(lens)}")
    for name, arr in out.items():
        v = arr[np.isfinite(arr)]
        if name in ("length", "width") and (v <= 0).any():
            raise TokenError(f"token feature {name!r} must be > 0 metres, got {float(v.min())}")
        if name in ("speed", "final_speed") and (v < 0).any():
            raise TokenError(f"token feature {name!r} must be >= 0 m/s, got {float(v.min())}")
        top, unit = {"length": (MAX_SIZE_M, "metres"), "width": (MAX_SIZE_M, "metres"),
                     "speed": (MAX_SPEED_MS, "m/s"), "final_speed": (MAX_SPEED_MS, "m/s")}.get(name, (None, ""))
        if top is not None and (v > top).any():
            raise TokenError(f"token feature {name!r} must be <= {top:g} {unit}, got {float(v.max())}")
        if name in ("heading", "heading_to_final") and (np.abs(v) > 2 * np.pi).any():
            raise TokenError(f"token feature {name!r} is in radians, got {float(v[np.abs(v) > 2 * np.pi][0])}")
        if name in ("x", "y") and (np.abs(v) > WINDOW_HALF).any():
            bad = float(v[np.abs(v) > WINDOW_HALF][0])
            raise TokenError(f"token feature {name!r} = {bad} m is outside the 100 m window "
                             f"[-{WINDOW_HALF:g}, {WINDOW_HALF:g}]")
    for group, names in FEATURE_GROUPS.items():
        if len(names) > 1:
            given = [np.isfinite(out[n]) if n in out else None for n in names]
            t = len(next(g for g in given if g is not None)) if any(g is not None for g in given) else 0
            given = [g if g is not None else np.zeros(t, bool) for g in given]
            if any((g != given[0]).any() for g in given[1:]):
                raise TokenError(f"features {' and '.join(names)} ({group}) must be given together")
    return out


def agent_tokens_from_dicts(agents: Sequence[Mapping[str, Any]]) -> np.ndarray:
    """User API: one dict of features per agent (any subset) -> validated (T, 170) tokens.

    Example: ``agent_tokens_from_dicts([{"x": 10, "y": -3.5, "heading": 0.0, "speed": 8},
    {"length": 12.0, "width": 2.5}])``.
    """
    cols: dict[str, list] = {}
    agents = [{k: v for k, v in a.items() if k not in SEEDING_KEYS} for a in agents]
    for i, a in enumerate(agents):
        try:
            v = validate_token_features(a)
        except TokenError as e:
            raise TokenError(f"agent token {i}: {e}") from None
        for name, arr in v.items():
            if len(arr) != 1 or np.ndim(a[name]) != 0:
                raise TokenError(f"agent token {i}: feature {name!r} must be a scalar")
    for name in FEATURES:
        vals = [a.get(name) for a in agents]
        if any(x is not None for x in vals):
            cols[name] = [np.nan if x is None else float(x) for x in vals]
    if not agents:
        return np.zeros((0, AGENT_TOKEN_DIM), np.float32)
    return encode_agent_tokens({k: np.asarray(v) for k, v in cols.items()})


def pad_tokens(tokens: Sequence[Any], dim: int = AGENT_TOKEN_DIM) -> tuple[torch.Tensor, torch.Tensor]:
    """Batch variable-length token sets.

    Args:
        tokens: B arrays/tensors of shape (T_i, dim); T_i may be 0.

    Returns:
        ``(tokens (B, Tmax, dim) float32, key_padding_mask (B, Tmax) bool)``, True where padded
        (PyTorch's key_padding_mask convention). Tmax may be 0.
    """
    b = len(tokens)
    arrs = [torch.as_tensor(_to_numpy(t), dtype=torch.float32).reshape(-1, dim) for t in tokens]
    tmax = max((len(a) for a in arrs), default=0)
    out = torch.zeros(b, tmax, dim)
    pad = torch.ones(b, tmax, dtype=torch.bool)
    for i, a in enumerate(arrs):
        out[i, :len(a)] = a
        pad[i, :len(a)] = False
    return out, pad


def token_region(tokens: torch.Tensor, pad: torch.Tensor, res: int, radius: int = 1) -> torch.Tensor:
    """(B, 1, res, res): 1 in the cells within ``radius`` cells of a positioned token, else 0; all 1
    for a window with a token that gives no position (it may be anywhere) or with no token."""
    cell, placed = token_cells(tokens, pad, res)
    out = torch.zeros(tokens.shape[0], res * res, device=tokens.device)
    rows = torch.arange(tokens.shape[0], device=tokens.device)[:, None].expand_as(cell)
    out[rows[placed], cell[placed]] = 1.0
    out = torch.nn.functional.max_pool2d(out.view(-1, 1, res, res), 2 * radius + 1, stride=1, padding=radius)
    anywhere = ((~pad) & ~placed).any(1) | pad.all(1)
    out[anywhere] = 1.0
    return out


def token_positions(tokens: np.ndarray) -> np.ndarray:
    """Scene-frame (x, y) (P, 2) of the encoded agent tokens (T, AGENT_TOKEN_DIM) that give a
    position: their bins' centres (within 0.8 m of what was asked)."""
    tokens = np.asarray(tokens)
    has = (tokens[:, PRESENCE_SLICE.start + FEATURES.index("x")] > 0.5) & \
        (tokens[:, PRESENCE_SLICE.start + FEATURES.index("y")] > 0.5)
    width = 2 * WINDOW_HALF / POS_BINS
    idx = np.stack([tokens[has, FEATURE_SLICES[f]].argmax(-1) for f in ("x", "y")], -1)
    return (idx + 0.5) * width - WINDOW_HALF


def token_cells(tokens: torch.Tensor, pad: torch.Tensor, res: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Which cell of a ``res`` x ``res`` grid over the window each token's position bin falls in.

    Args:
        tokens: (B, T, AGENT_TOKEN_DIM); pad: (B, T) bool, True = padding.

    Returns:
        ``(cell (B, T) long = row * res + col, placed (B, T) bool)``; ``placed`` is False for padding
        and for tokens without a position. Rows and columns follow
        :func:`~sumo_scendiff.core.geometry.metres_to_pixels` (row 0 at the window's +y edge, column 0 at
        its -x edge); ``res`` must divide :data:`POS_BINS`, so every bin lies in one cell.
    """
    if POS_BINS % res:
        raise ValueError(f"grid {res} does not divide the {POS_BINS} position bins")
    per = POS_BINS // res
    col = tokens[..., FEATURE_SLICES["x"]].argmax(-1) // per
    row = (res - 1) - tokens[..., FEATURE_SLICES["y"]].argmax(-1) // per
    placed = (tokens[..., PRESENCE_SLICE.start + FEATURES.index("x")] > 0.5) & ~pad
    return row * res + col, placed
