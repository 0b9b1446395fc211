"""Does the autoencoder reproduce the turns of the windows it was trained on?

    python experiments/turn_fit.py                                  # the shipped autoencoder
    python experiments/turn_fit.py --autoencoder runs/ae/last.pt --data data/signals/train

Windows of ``--data`` (turned as in training) are encoded and decoded, D(mu(E(x)), m); every
recorded vehicle the training loss would call *turning* (the range of its heading over -2…+2 s
above the loss's ``turn_threshold``) is matched to its decoded cell as the loss matches it
(``detection.match_boxes``), and its pose at +2 s relative to its box at t = 0 (the loss's
trajectory target) is compared with the decoded one: least-squares slope through the origin of
decoded on recorded, for the lateral offset (m) and the heading change (rad), with the mean
magnitudes. 1 reproduces the turns; 0 draws every vehicle straight on. On the training windows
themselves this separates a model that has not fitted the turns from one that fits and does not
generalise (``token_response.py`` asks the held-out question).
"""
from __future__ import annotations

import argparse
import os

import numpy as np
from report import add_model_options, load_models

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_model_options(p, "its autoencoder")
    p.add_argument("--data", default=os.path.join(ROOT, "data", "signals", "train"))
    p.add_argument("--scenes", type=int, default=96)
    p.add_argument("-s", "--seed", type=int, default=0)
    return p.parse_args(args)


def slope(rec: np.ndarray, dec: np.ndarray) -> float:
    return float((rec * dec).sum() / max((rec * rec).sum(), 1e-12))


def main(o) -> None:
    import torch

    from sumo_scendiff.core.geometry import T0
    from sumo_scendiff.data.dataset import SceneDataset, collate_scenes
    from sumo_scendiff.model.detection import (
        C_Y,
        TURNING,
        accumulate_deltas,
        match_boxes,
        trajectory_category,
        trajectory_targets,
    )
    _, ae, name, sha = load_models(o.checkpoint, o.autoencoder)
    ds = SceneDataset(o.data, rotate=True, seed=o.seed)
    idx = np.random.default_rng(o.seed).choice(len(ds), min(o.scenes, len(ds)), replace=False)
    rec, dec = [], []
    for s in range(0, len(idx), 16):
        b = collate_scenes([ds[int(i)] for i in idx[s:s + 16]])
        with torch.no_grad():
            y = ae.decode(ae.encode(b["agents"])[0], b["map"])
            bb, n, c = match_boxes(y, b["boxes"], b["valid"], ae.cfg.loss)
            rel_gt = trajectory_targets(b["boxes"][bb, n], b["traj"][bb, n])
            rel = accumulate_deltas(y.flatten(2)[bb, :, c][:, 7:C_Y])
            mask = b["traj_mask"][bb, n]
            turning = (trajectory_category(rel_gt, mask, ae.cfg.loss) == TURNING) & mask[:, T0 + 2]
        rec.append(rel_gt[turning, T0 + 2, 1:3].numpy())
        dec.append(rel[turning, T0 + 2, 1:3].numpy())
    rec, dec = np.concatenate(rec), np.concatenate(dec)
    print(f"{name} (sha256 {sha[:12]}…), {len(idx)} windows of {o.data}, {len(rec)} turning vehicles")
    print("| +2 s, box frame at t = 0 | recorded mean abs | decoded mean abs | slope decoded on recorded |")
    print("|---|---|---|---|")
    for k, what in ((0, "lateral offset, m"), (1, "heading change, rad")):
        print(f"| {what} | {np.abs(rec[:, k]).mean():.2f} | {np.abs(dec[:, k]).mean():.2f} | "
              f"{slope(rec[:, k], dec[:, k]):.2f} |")


if __name__ == "__main__":
    main(get_options())
