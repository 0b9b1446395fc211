"""Calibrate the global token's classifier-free guidance on held-out scenes of the training networks.

Map-only generation (no agent token, p_mask = 1) of the windows of held-out scenes recorded on the
*training* networks (the validation split, never trained on), once per guidance weight w of
``GenerationConfig.scene_guidance`` (w = 1: off), applied at noise levels above ``sigma``
(``GenerationConfig.scene_guidance_sigma``; default: the checkpoint's). The null condition is the
empty scene (p_mask = 0, no token; ``ScenarioDiffusion.null_condition``). Per weight: agents per
window against the ground truth's, the share standing (< 1 m/s) against the ground truth's, and the
standard deviation of the sampled latent against the data's (a sampler that loses agents leaves too
little energy in it).

The calibrated weight is where the agents per window meet the ground truth's (interpolated): a
calibration on validation data of the training distribution, so the real cities of the evaluation
stay unseen. :func:`write_scene_guidance` stores it in the checkpoint.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ..core.geometry import T0, TIMES, Window
from ..data.dataset import SceneDataset, collate_scenes
from ..generation.generator import ScenarioGenerator, select_boxes, speeds_from_traj
from ..model import checkpoint as ckpt
from ..model.detection import decode_boxes
from ..model.edm import SAMPLERS
from ..tokens.encoding import AGENT_TOKEN_DIM, global_token, pad_tokens
from .config import CALIBRATION_WEIGHTS

WINDOW = Window(0.0, 0.0)  # boxes are in the scene frame; only the window's extent matters


@dataclass
class Calibration:
    """What :func:`calibrate` measured; ``rows`` holds (w, agents / window, standing share, latent std)."""
    sha256: str
    windows: int
    steps: int
    sampler: str
    threshold: float
    sigma: float
    gt_count: float
    gt_still: float
    gt_std: float
    rows: list[tuple[float, float, float, float]] = field(default_factory=list)
    best: float = float("nan")   # w where the agents per window meet the ground truth's

    @property
    def weight(self) -> float:
        """The weight stored in a checkpoint: :attr:`best` to two decimals, then to one."""
        return float(f"{float(f'{self.best:.2f}'):.1f}")


def calibrate(checkpoint: str | None, data: str, scenes: int = 128, turned: bool = False,
              weights=CALIBRATION_WEIGHTS, sigma: float | None = None, steps: int | None = None,
              sampler: str | None = None, seed: int = 0) -> Calibration:
    """Map-only generation of ``scenes`` windows of the recording ``data`` at each weight of ``weights``."""
    gen = ScenarioGenerator.load(checkpoint)
    sigma_lo = gen.scene_guidance_sigma if sigma is None else sigma
    steps = steps or gen.config.steps
    solver = SAMPLERS[sampler or gen.config.sampler]
    ds = SceneDataset(data, rotate=turned, seed=seed)
    idx = np.random.default_rng(seed).choice(len(ds), min(scenes, len(ds)), replace=False)
    b = collate_scenes([ds[int(i)] for i in idx])
    n, m = len(idx), b["map"]
    tok, pad = pad_tokens([np.zeros((0, AGENT_TOKEN_DIM), np.float32)] * n)
    unet = gen.diffusion.cfg.unet
    glob = torch.from_numpy(global_token(np.full(n, 1.0), dim=unet.global_dim).reshape(n, -1))
    noise = torch.randn(n, unet.c_z, unet.res, unet.res, generator=torch.Generator().manual_seed(seed))
    with torch.no_grad():
        mu, _ = gen.ae.encode(b["agents"])
    out = Calibration(gen.sha256, n, steps, solver.__name__, gen.config.threshold, sigma_lo,
                      gt_count=float(b["valid"].sum(1).float().mean()),
                      gt_still=float((b["speed"][b["valid"]][:, T0] < 1.0).float().mean()),
                      gt_std=float((mu * gen.latent_scale).std()))
    for w in weights:
        with torch.no_grad():
            z = gen.diffusion.sample(m, tok, pad, glob, steps=steps, sampler=solver, noise=noise,
                                     scene_guidance=w, scene_guidance_sigma=sigma_lo)
            dec = decode_boxes(gen.ae.decode(z / gen.latent_scale, m))
        prob, boxes, traj = dec.prob.numpy(), dec.boxes.numpy(), dec.traj.numpy()
        counts, still = [], []
        for i in range(n):
            keep = select_boxes(WINDOW, prob[i], boxes[i], gen.config.threshold)
            counts.append(len(keep))
            v = speeds_from_traj(traj[i][keep], np.ones((len(keep), len(TIMES)), bool))
            still += list(v[:, T0] < 1.0)
        out.rows.append((float(w), float(np.mean(counts)), float(np.mean(still)) if still else float("nan"),
                         float(z.std())))
    ws, counts = np.array([r[0] for r in out.rows]), np.array([r[1] for r in out.rows])
    order = np.argsort(counts)   # the count rises with w; interpolate where it meets the ground truth
    out.best = float(np.interp(out.gt_count, counts[order], ws[order]))
    return out


def write_scene_guidance(path: str, weight: float, sigma: float | None = None,
                         key: str = "scene_guidance") -> str:
    """Store the guidance weight as ``key`` (and, when given, the noise level above which it applies)
    in the ``scenario-diffusion`` checkpoint at ``path``, atomically; returns the file's new SHA-256."""
    changes = {key: float(weight)}
    if sigma is not None:
        changes["scene_guidance_sigma"] = float(sigma)
    return ckpt.update(path, "scenario-diffusion", **changes)
