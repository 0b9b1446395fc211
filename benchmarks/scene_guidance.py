"""Calibrate the global token's classifier-free guidance on held-out scenes of the training networks.

    python benchmarks/scene_guidance.py [--checkpoint PATH] [--data data/val_dense] [--turned] [--scenes 128]
                                        [--weights 1 1.5 2 2.5 3] [--sigma SIGMA] [-o FILE]

Map-only generation (no agent token, p_mask = 1) of the windows of held-out scenes recorded on the
*training* networks (the validation split, never trained on), once per guidance weight w of
``GenerationConfig.scene_guidance`` (w = 1: off), applied at noise levels above ``--sigma``
(``GenerationConfig.scene_guidance_sigma``; default: the checkpoint's). The null condition is the empty scene (p_mask = 0,
no token; ``ScenarioDiffusion.null_condition``). Per weight: agents per window against the ground
truth's, the share standing (< 1 m/s) against the ground truth's, and the standard deviation of the
sampled latent against the data's (a sampler that loses agents leaves too little energy in it).

The suggested weight is where the agents per window meet the ground truth's (interpolated): a
calibration on validation data of the training distribution, so the real cities of the evaluation
stay unseen. Store both in the checkpoint with ``train export --scene-guidance W
--scene-guidance-sigma SIGMA``.
"""
from __future__ import annotations

import argparse
import os

import numpy as np
import torch
from report import emit

from sumo_scendiff.core.geometry import T0, TIMES, Window
from sumo_scendiff.data.dataset import SceneDataset, collate_scenes
from sumo_scendiff.generation.generator import (
    ScenarioGenerator,
    select_boxes,
    speeds_from_traj,
)
from sumo_scendiff.model.detection import decode_boxes
from sumo_scendiff.model.edm import SAMPLERS
from sumo_scendiff.tokens.encoding import AGENT_TOKEN_DIM, global_token, pad_tokens

ROOT = os.path.join(os.path.dirname(__file__), "..")
WINDOW = Window(0.0, 0.0)  # boxes are in the scene frame; only the window's extent matters


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None, help="default: the shipped one")
    p.add_argument("--data", default=os.path.join(ROOT, "data", "val_dense"))
    p.add_argument("--scenes", type=int, default=128)
    p.add_argument("--turned", action="store_true",
                   help="windows turned by a random angle, as training and the evaluation see them "
                        "(whole with a recording of circles: --data data/val_dense_disc)")
    p.add_argument("--weights", type=float, nargs="+", default=[1.0, 1.5, 2.0, 2.5, 3.0])
    p.add_argument("--sigma", type=float, default=None,
                   help="guide only above this noise level (default: the checkpoint's)")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: generate's)")
    p.add_argument("--sampler", choices=sorted(SAMPLERS), default=None, help="default: generate's")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, help="also write the report here")
    return p.parse_args(args)


def main(o) -> None:
    torch.set_num_threads(2)
    gen = ScenarioGenerator.load(o.checkpoint)
    sigma_lo = gen.scene_guidance_sigma if o.sigma is None else o.sigma
    steps = o.steps or gen.config.steps
    sampler = SAMPLERS[o.sampler] if o.sampler else gen.config.sampler
    ds = SceneDataset(o.data, rotate=o.turned, seed=o.seed)
    idx = np.random.default_rng(o.seed).choice(len(ds), min(o.scenes, len(ds)), replace=False)
    b = collate_scenes([ds[int(i)] for i in idx])
    n, m = len(idx), b["map"]
    gt_count = float(b["valid"].sum(1).float().mean())
    gt_still = float((b["speed"][b["valid"]][:, T0] < 1.0).float().mean())
    tok, pad = pad_tokens([np.zeros((0, AGENT_TOKEN_DIM), np.float32)] * n)
    glob = torch.from_numpy(global_token(np.full(n, 1.0)).reshape(n, -1))
    noise = torch.randn(n, gen.diffusion.cfg.unet.c_z, gen.diffusion.cfg.unet.res, gen.diffusion.cfg.unet.res,
                        generator=torch.Generator().manual_seed(o.seed))
    with torch.no_grad():
        mu, _ = gen.ae.encode(b["agents"])
    rows = []
    for w in o.weights:
        with torch.no_grad():
            z = gen.diffusion.sample(m, tok, pad, glob, steps=steps, sampler=sampler, noise=noise,
                                     scene_guidance=w,
                                     scene_guidance_sigma=sigma_lo)
            dec = decode_boxes(gen.ae.decode(z / gen.latent_scale, m))
        prob, boxes, traj = dec.prob.numpy(), dec.boxes.numpy(), dec.traj.numpy()
        counts, still = [], []
        for i in range(n):
            keep = select_boxes(WINDOW, prob[i], boxes[i], gen.config.threshold)
            counts.append(len(keep))
            v = speeds_from_traj(traj[i][keep], np.ones((len(keep), len(TIMES)), bool))
            still += list(v[:, T0] < 1.0)
        rows.append((w, float(np.mean(counts)), float(np.mean(still)) if still else float("nan"), float(z.std())))
    ws, counts = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
    order = np.argsort(counts)   # the count rises with w; interpolate where it meets the ground truth
    best = float(np.interp(gt_count, counts[order], ws[order]))
    lines = [f"checkpoint `{o.checkpoint or 'shipped'}` (sha256 {gen.sha256[:12]}…), {n} windows of "
             f"`{os.path.relpath(o.data, ROOT)}`, map only, {steps} steps of {sampler.__name__}, threshold {gen.config.threshold}, "
             f"guided at sigma > {sigma_lo:g}",
             "", "| scene guidance w | agents / window | standing share | latent std |", "|---|---|---|---|",
             f"| ground truth | {gt_count:.2f} | {gt_still:.2f} | {float((mu * gen.latent_scale).std()):.3f} |"]
    lines += [f"| {w:g} | {c:.2f} | {s:.2f} | {sd:.3f} |" for w, c, s, sd in rows]
    lines += ["", f"agents per window equal to the ground truth's at w = {best:.2f} (interpolated)"]
    emit("\n".join(lines) + "\n", o.output, "Scene guidance calibration")


if __name__ == "__main__":
    main(get_options())
