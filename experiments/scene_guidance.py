"""Calibrate the global token's classifier-free guidance on held-out scenes of the training networks.

    python experiments/scene_guidance.py [--checkpoint PATH] [--data data/val_dense] [--turned] [--scenes 128]
                                         [--weights 1 1.5 2 2.5 3] [--sigma SIGMA] [-o FILE]

The table behind ``python -m sumo_scendiff.train calibrate`` (sumo_scendiff/train/calibrate.py, which
says what is measured), printed for every weight tried; this script writes no checkpoint.
"""
from __future__ import annotations

import argparse
import os

import torch
from report import emit

from sumo_scendiff.generation.config import SAMPLER_NAMES
from sumo_scendiff.train.calibrate import calibrate
from sumo_scendiff.train.config import CALIBRATION_WEIGHTS

ROOT = os.path.join(os.path.dirname(__file__), "..")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None, help="default: the shipped one")
    p.add_argument("--data", default=os.path.join(ROOT, "data", "val_dense"))
    p.add_argument("--scenes", type=int, default=128)
    p.add_argument("--turned", action="store_true",
                   help="windows turned by a random angle, as training and the evaluation see them "
                        "(whole with a recording of circles: --data data/val_dense_disc)")
    p.add_argument("--weights", type=float, nargs="+", default=list(CALIBRATION_WEIGHTS))
    p.add_argument("--sigma", type=float, default=None,
                   help="guide only above this noise level (default: the checkpoint's)")
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: generate's)")
    p.add_argument("--sampler", choices=SAMPLER_NAMES, default=None, help="default: generate's")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, help="also write the report here")
    return p.parse_args(args)


def main(o) -> None:
    torch.set_num_threads(2)
    c = calibrate(o.checkpoint, o.data, scenes=o.scenes, turned=o.turned, weights=o.weights, sigma=o.sigma,
                  steps=o.steps, sampler=o.sampler, seed=o.seed)
    lines = [f"checkpoint `{o.checkpoint or 'shipped'}` (sha256 {c.sha256[:12]}…), {c.windows} windows of "
             f"`{os.path.relpath(o.data, ROOT)}`, map only, {c.steps} steps of {c.sampler}, threshold {c.threshold}, "
             f"guided at sigma > {c.sigma:g}",
             "", "| scene guidance w | agents / window | standing share | latent std |", "|---|---|---|---|",
             f"| ground truth | {c.gt_count:.2f} | {c.gt_still:.2f} | {c.gt_std:.3f} |"]
    lines += [f"| {w:g} | {n:.2f} | {s:.2f} | {sd:.3f} |" for w, n, s, sd in c.rows]
    lines += ["", f"agents per window equal to the ground truth's at w = {c.best:.2f} (interpolated)"]
    emit("\n".join(lines) + "\n", o.output, "Scene guidance calibration")

if __name__ == "__main__":
    main(get_options())
