"""Training-time partial tokenisation (paper sec. 4.3.1) and feature dropout: which agents of a
recorded scene become tokens, and which of their features, for one training example.

    p_mask, keep = sample_token_mask(n_agents, rng)              # agents kept as tokens
    p_mask, keep, given = choose_tokens(features, present, rng)   # ... and the features they give
    tokens, glob, p_mask = partial_tokens(features, present, rng) # one example's conditioning

The rules and their rationale are in :mod:`~sumo_scendiff.tokens.encoding` (module docstring); encoding
is there too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .encoding import (
    FEATURE_GROUPS,
    GLOBAL_TOKEN_DIM,
    P_MASK_BINS,
    encode_agent_tokens,
    global_token,
)


@dataclass(frozen=True)
class TokenMaskConfig:
    """Partial tokenisation (paper sec. 4.3.1) and feature dropout hyper-parameters."""

    p_keep_all_tokens: float = 0.4      # P(p_mask = 0)
    p_map_only: float = 0.0             # P(p_mask = 1: no agent token, the map alone); not in the paper
    beta_a: float = 2.0                 # otherwise p_mask ~ Beta(a, b)
    beta_b: float = 1.0
    p_all_features: float = 0.5         # a kept token keeps every feature with this probability
    p_drop_group: float = 0.3           # otherwise each group is dropped with this probability
    p_drop_position: float = 0.15       # ... except position (see module docstring)
    p_drop_density: float = 0.3         # the window's density absent, so one model works without it


def sample_token_mask(n_agents: int, rng: np.random.Generator,
                      cfg: TokenMaskConfig = TokenMaskConfig()) -> tuple[float, np.ndarray]:
    """Draw p_mask (0 w.p. 0.4, 1 w.p. ``p_map_only``, else Beta(2, 1)) and drop each agent token
    with probability p_mask.

    Returns ``(p_mask, keep)`` with keep (n_agents,) bool; encode the global token with
    ``global_token(p_mask)``.
    """
    u = rng.random()
    if u < cfg.p_keep_all_tokens:
        p_mask = 0.0
    elif u < cfg.p_keep_all_tokens + cfg.p_map_only:
        p_mask = 1.0
    else:
        p_mask = float(rng.beta(cfg.beta_a, cfg.beta_b))
    keep = rng.random(n_agents) >= p_mask
    return p_mask, keep


def sample_feature_dropout(n_tokens: int, rng: np.random.Generator,
                           cfg: TokenMaskConfig = TokenMaskConfig()) -> dict[str, np.ndarray]:
    """Per-token feature keep flags, name -> (n_tokens,) bool, dropping whole feature groups."""
    full = rng.random(n_tokens) < cfg.p_all_features
    keep: dict[str, np.ndarray] = {}
    for group, names in FEATURE_GROUPS.items():
        p = cfg.p_drop_position if group == "position" else cfg.p_drop_group
        k = full | (rng.random(n_tokens) >= p)
        for name in names:
            keep[name] = k
    return keep


def choose_tokens(features: Mapping[str, np.ndarray], present: Mapping[str, np.ndarray],
                  rng: np.random.Generator, cfg: TokenMaskConfig = TokenMaskConfig()
                  ) -> tuple[float, np.ndarray, dict[str, np.ndarray]]:
    """Which agents of a scene become tokens, and which of their features: token masking, then
    feature dropout. Returns ``(p_mask, keep (n,) bool, given)``, ``given`` name -> (n,) bool: the
    agent is a token and its token gives that feature (recorded, and not dropped)."""
    n = len(next(iter(features.values()))) if features else 0
    p_mask, keep = sample_token_mask(n, rng, cfg)
    fk = sample_feature_dropout(int(keep.sum()), rng, cfg)
    given = {}
    for k in features:
        g = np.zeros(n, bool)
        g[keep] = np.asarray(present.get(k, np.ones(n, bool)))[keep] & fk[k]
        given[k] = g
    return p_mask, keep, given


def partial_tokens(features: Mapping[str, np.ndarray], present: Mapping[str, np.ndarray],
                   rng: np.random.Generator, cfg: TokenMaskConfig = TokenMaskConfig(),
                   density: float | None = None, global_dim: int = GLOBAL_TOKEN_DIM
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """One training example's conditioning: :func:`choose_tokens`, then encoding.
    ``density``: the window's vehicles per km of car lane, given to a model with the density
    condition (``global_dim``) unless dropped (``p_drop_density``).

    Returns ``(agent_tokens (K, 170), global_token (global_dim,), p_mask)`` for the K kept agents.
    """
    p_mask, keep, given = choose_tokens(features, present, rng, cfg)
    feats = {k: np.asarray(v)[keep] for k, v in features.items()}
    pres = {k: g[keep] for k, g in given.items()}
    if global_dim == P_MASK_BINS or density is None or rng.random() < cfg.p_drop_density:
        density = None
    return encode_agent_tokens(feats, pres), global_token(p_mask, density, dim=global_dim), p_mask
