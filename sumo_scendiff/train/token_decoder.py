"""What a decoder that reads the tokens (``AutoencoderConfig.C_t``) is trained on: each example's
tokens, drawn as the diffusion model's are, and the agent raster its (frozen) encoder sees.

On a recorded scene the encoder's latent and the tokens agree. A generated latent does not always
agree with the token it was asked for: the diffusion model follows a speed or a turn only roughly.
A decoder trained on agreeing pairs alone learns to trust the latent and ignores the token. So,
with probability ``p_mislead`` per token and feature, the encoder is shown that vehicle moving
otherwise (its past steps scaled for a given speed, its future steps scaled for a given final
speed, its future turned for a given heading_to_final) while the loss asks for the recorded
motion: only the token says what it was. A decoder taught only that may still learn to side with
whichever of the two looks more plausible in its scene; so, for a share ``p_counterfactual`` of the
agents moved so, it is the other way round: the encoder sees the recorded motion, and the token and
the loss the moved one (a vehicle slower, faster or turning otherwise than its neighbours suggest,
as a user may ask for): the token's word wins either way.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from ..core.geometry import T0
from ..core.scene import speeds_from_traj
from ..map.raster import RasterConfig, render_agents
from ..tokens.encoding import encode_agent_tokens, features_from_scene, pad_tokens
from ..tokens.masking import TokenMaskConfig, choose_tokens
from ..tokens.raster import EXACT_FEATURES

MISLEAD_SCALE = (0.1, 2.0)   # the steps scaled by a factor drawn uniformly in this range
MISLEAD_TURN = 0.6           # rad: the future turned by an angle drawn uniformly in +- this


def _rotate(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)


def mislead(traj: np.ndarray, given: dict[str, np.ndarray], rng: np.random.Generator, p: float) -> np.ndarray:
    """A copy of ``traj`` (N, 5, 3; scene frame) in which, for each agent whose token gives
    ``speed`` / ``final_speed`` / ``heading_to_final``, with probability ``p`` each: the steps
    before t = 0 / after it are scaled about the t = 0 position, the future turned about it."""
    out = np.array(traj, dtype=np.float64, copy=True)
    n = len(out)
    if n == 0 or p <= 0:
        return out.astype(traj.dtype)
    p0 = out[:, T0:T0 + 1, :2]
    for name, steps in (("speed", slice(0, T0)), ("final_speed", slice(T0 + 1, None))):
        hit = given[name] & (rng.random(n) < p)
        k = rng.uniform(*MISLEAD_SCALE, n)[hit, None, None]
        out[hit, steps, :2] = p0[hit] + k * (out[hit, steps, :2] - p0[hit])
    hit = given["heading_to_final"] & (rng.random(n) < p)
    a = rng.uniform(-MISLEAD_TURN, MISLEAD_TURN, n)[hit]
    future = slice(T0 + 1, None)
    out[hit, future, :2] = p0[hit] + _rotate(out[hit, future, :2] - p0[hit], a)
    out[hit, future, 2] += a[:, None]
    return out.astype(traj.dtype)


def decoder_conditioning(batch: dict, seed: int, step: int, rank: int, mask_cfg: TokenMaskConfig,
                         p_mislead: float, read_tokens: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
                         raster: RasterConfig = RasterConfig(), p_counterfactual: float = 0.0
                         ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(x, t, traj, told)``: the agent raster the encoder sees ((B, C_x, H, W): the batch's own
    where no token misleads it), the tokens' raster as the decoder reads them (``read_tokens(tokens,
    pad, exact)``: ``ScenarioAutoencoder.token_raster`` given the tokens' exact speeds and turn, as
    generation gives them, not their bins' centres), the
    trajectories the loss asks for (the batch's, but for the counterfactual agents) and which agents
    ((B, N) bool) a token gives a speed or final speed of."""
    toks, xs, values = [], [], []
    target = batch["traj"].clone()
    speed_given = torch.zeros(batch["valid"].shape, dtype=torch.bool)
    for i in range(batch["boxes"].shape[0]):
        v = batch["valid"][i].cpu().numpy()
        boxes, traj, mask, speed = (batch[k][i].cpu().numpy()[v] for k in ("boxes", "traj", "traj_mask", "speed"))
        feats, present = features_from_scene(boxes, traj, mask, speed)
        rng = np.random.default_rng([seed, step, int(batch["index"][i]), rank])
        _, keep, given = choose_tokens(feats, present, rng, mask_cfg)
        moved = mislead(traj, given, rng, p_mislead)
        changed = (moved != traj).any((1, 2))
        swap = changed & (rng.random(len(traj)) < p_counterfactual)
        if swap.any():   # the encoder sees the recorded motion; the token and the loss the moved one
            seen, told = np.where(swap[:, None, None], traj, moved), np.where(swap[:, None, None], moved, traj)
            speed = speed.copy()
            speed[swap] = speeds_from_traj(told[swap], mask[swap])
            feats, present = features_from_scene(boxes, told, mask, speed)
            target[i, torch.from_numpy(np.flatnonzero(v))] = torch.from_numpy(told).to(target.dtype)
            moved = seen
        told_given = {k: (g & present[k])[keep] for k, g in given.items()}
        gives = keep & ((given["speed"] & present["speed"]) | (given["final_speed"] & present["final_speed"]))
        speed_given[i, torch.from_numpy(np.flatnonzero(v)[gives])] = True
        toks.append(encode_agent_tokens({k: f[keep] for k, f in feats.items()}, told_given))
        values.append(np.stack([np.where(told_given[k], feats[k][keep], np.nan) for k in EXACT_FEATURES], -1)
                      .reshape(-1, len(EXACT_FEATURES)))
        xs.append(render_agents(boxes, moved, mask, raster) if not np.array_equal(moved, traj)
                  else batch["agents"][i].cpu().numpy())
    tokens, pad = pad_tokens(toks)
    x = torch.from_numpy(np.stack(xs)).to(batch["agents"].device)
    speed_given = speed_given.to(x.device)
    vals = torch.full((len(values), tokens.shape[1], len(EXACT_FEATURES)), float("nan"))
    for i, v in enumerate(values):
        vals[i, :len(v)] = torch.from_numpy(v).float()
    return x, read_tokens(tokens.to(x.device), pad.to(x.device), exact=vals.to(x.device)), target, speed_given
