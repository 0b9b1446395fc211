"""Token controllability of a generator (paper sec. 4.3.1-4.3.2, tables 2 and 3, appendix E.2).

Agent tokens are computed from the ground-truth agents of each window; with token-mask probability
p_mask each token is dropped (the global scene token carries p_mask), the model generates, and
generated agents are matched one-to-one to the *kept* tokens (Hungarian, 2.2 m and 0.2 rad):

* :func:`mask_table`: match rate and additional generated agents per scene for each p_mask (table 2);
* :func:`threshold_table`: precision / recall / F1 at several box thresholds with p_mask = 0 (E.2);
* :func:`speed_table`: match rate and current / final speed MAE for three token feature sets (table 3);
* :func:`token_tables`: the three of them, with a progress bar over their generation runs.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..core.scene import Scene
from ..tokens.encoding import feature_dicts, features_from_scene
from .metrics import token_metrics

P_MASKS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.9)
THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.9)
POSE_EXTENTS = ("x", "y", "heading", "length", "width")
FEATURE_SETS = (("pose + extents", POSE_EXTENTS),
                ("+ speed", POSE_EXTENTS + ("speed",)),
                ("+ speed + final speed", POSE_EXTENTS + ("speed", "final_speed")))


def token_dicts(scene: Scene, keep: np.ndarray, features: Sequence[str]) -> list[dict]:
    """Feature dicts (the user-facing token format) for the kept agents of a ground-truth scene."""
    feats, present = features_from_scene(scene.boxes, scene.traj, scene.traj_mask, scene.speed)
    every = feature_dicts(feats, present, features)
    return [every[i] for i in np.flatnonzero(keep)]


def _kept(scenes: Sequence[Scene], p_mask: float, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng([seed, int(round(p_mask * 1000))])
    return [rng.random(len(s)) >= p_mask for s in scenes]


def _run(generator, net, gts, keeps, features, p_mask, seed, config=None, bar=None):
    """One generation run over every window (a step of ``bar``, a tqdm, when given)."""
    tokens = [token_dicts(g, k, features) for g, k in zip(gts, keeps)]
    gen = generator.generate(net, [g.window for g in gts], tokens=tokens, p_mask=p_mask, seed=seed,
                             config=config, signals=[g.meta.get("signals") or None for g in gts])
    if bar is not None:
        bar.update(1)
    return gen, [g.select(k) for g, k in zip(gts, keeps)]


def mask_table(generator, net, gts: Sequence[Scene], seed: int = 0,
               features: Sequence[str] = POSE_EXTENTS + ("speed",), bar=None) -> list[dict]:
    rows = []
    for p in P_MASKS:
        gen, toks = _run(generator, net, gts, _kept(gts, p, seed), features, p, seed, bar=bar)
        m = token_metrics(gen, toks)
        rows.append({"p_mask": p, "match_rate": m["match_rate"],
                     "additional_per_scene": m["additional_per_scene"]})
    return rows


def threshold_table(generator, net, gts: Sequence[Scene], seed: int = 0,
                    features: Sequence[str] = POSE_EXTENTS + ("speed",), bar=None) -> list[dict]:
    from dataclasses import replace
    rows = []
    keeps = [np.ones(len(g), bool) for g in gts]
    for t in THRESHOLDS:
        cfg = replace(generator.config, threshold=t)
        gen, toks = _run(generator, net, gts, keeps, features, 0.0, seed, cfg, bar)
        m = token_metrics(gen, toks)
        rows.append({"threshold": t, "precision": m["precision"], "recall": m["recall"], "f1": m["f1"]})
    return rows


def speed_table(generator, net, gts: Sequence[Scene], seed: int = 0, bar=None) -> list[dict]:
    rows = []
    keeps = [np.ones(len(g), bool) for g in gts]
    for name, features in FEATURE_SETS:
        gen, toks = _run(generator, net, gts, keeps, features, 0.0, seed, bar=bar)
        m = token_metrics(gen, toks)
        rows.append({"features": name, "match_rate": m["match_rate"], "speed_mae": m["speed_mae"],
                     "final_speed_mae": m["final_speed_mae"]})
    return rows


def token_tables(generator, net, gts: Sequence[Scene], seed: int = 0, progress: bool = False) -> dict:
    """``{"mask", "threshold", "speed"}`` tables of one network; ``progress``: a tqdm bar over the
    generation runs (one per p_mask, threshold and feature set, each over every window)."""
    from tqdm import tqdm
    runs = len(P_MASKS) + len(THRESHOLDS) + len(FEATURE_SETS)
    with tqdm(total=runs, desc=f"token tables, {net.name}", unit="run", disable=not progress) as bar:
        return {"mask": mask_table(generator, net, gts, seed, bar=bar),
                "threshold": threshold_table(generator, net, gts, seed, bar=bar),
                "speed": speed_table(generator, net, gts, seed, bar=bar)}


def markdown_tables(results: dict) -> str:
    out = []
    for net, r in results.items():
        out.append(f"**{net}** — token mask probability (table 2)\n")
        out.append("| p_mask | " + " | ".join(f"{x['p_mask']:.1f}" for x in r["mask"]) + " |")
        out.append("|---|" + "---|" * len(r["mask"]))
        out.append("| agent token match rate | " + " | ".join(f"{x['match_rate']:.3f}" for x in r["mask"]) + " |")
        out.append("| additional agents / scene | " + " | ".join(
            f"{x['additional_per_scene']:.2f}" for x in r["mask"]) + " |\n")
        out.append("| threshold | precision | recall | F1 |\n|---|---|---|---|")
        out += [f"| {x['threshold']:.2f} | {x['precision']:.3f} | {x['recall']:.3f} | {x['f1']:.3f} |"
                for x in r["threshold"]]
        out.append("\n| token features | match rate | speed MAE (m/s) | final speed MAE (m/s) |\n|---|---|---|---|")
        out += [f"| {x['features']} | {x['match_rate']:.3f} | {x['speed_mae']:.2f} | {x['final_speed_mae']:.2f} |"
                for x in r["speed"]]
        out.append("")
    return "\n".join(out)


__all__ = ["mask_table", "threshold_table", "speed_table", "token_tables", "markdown_tables"]
