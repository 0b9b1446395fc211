"""Where a model loses agents: autoencoder reconstruction vs diffusion samples, on held-out scenes.

    python experiments/reconstruction.py [--checkpoint PATH] [--data data/val] [--scenes 96] [-o FILE]
    python experiments/reconstruction.py --autoencoder runs/ae/last.pt    # a training run's autoencoder alone
    python experiments/reconstruction.py --data data/val_dense_disc --turned   # turned whole windows

For each held-out scene (generated networks' validation split, no rotation; ``--turned``: each
window turned by a random angle as training sees it, whole when the data is a recording of circles),
three decodings go
through the same box filter as ``ScenarioGenerator`` (threshold, window, overlap removal) and are
matched one-to-one to the ground-truth agents with the token-match rule (centre within 2.2 m,
heading within 0.2 rad):

* ``autoencoder``: D(mu(E(x)), m) -- the ceiling any diffusion sample can reach;
  the column "recall on junctions" is the recall of the agents centred on a junction (the map's
  junction channel): on the real cities they are 13 % of the agents and the ones most often lost;
  "recall beyond 50 m" that of the agents in the window's corners (only a turned window of a
  recording of circles has them whole);
* ``diffusion, no tokens``: p_mask = 1, map only -- precision/recall here say how often a free sample
  happens to reproduce *this* scene, i.e. they are low by nature; the count column is the check;
* ``diffusion, every token``: p_mask = 0, every agent given as a full token -- the token match rate;
  once without and once with the classifier-free guidance of the tokens (``--guidance``, default 3),
  and guided with every token pinned in the latent (``sumo_scendiff/pinning.py``);
* ``diffusion from the data at sigma``: the scene's own latent noised to sigma, then integrated back
  to 0 (map only, 40-step schedule below sigma): where along the noise levels the model loses agents.
  A model that keeps them from sigma = 1 but not from 4 is undertrained at high noise.

The table also gives the median centre and heading errors of the nearest prediction to each
ground-truth agent, the speed MAE of matched pairs (speeds from the decoded trajectory: the
autoencoder row is the ceiling of the token tables' speed MAE), the share of decoded agents standing
(< 1 m/s; the header gives the ground truth's), and the posterior noise at agent cells (how much of
the latent the KL term leaves usable).
"""
from __future__ import annotations

import argparse
import os

import numpy as np
import torch
from report import add_model_options, emit, load_models

from sumo_scendiff.core.geometry import T0, TIMES, Window, wrap_angle
from sumo_scendiff.data.dataset import SceneDataset, collate_scenes
from sumo_scendiff.evaluate.metrics import match_agents, precision_recall_f1
from sumo_scendiff.generation.generator import (
    GenerationConfig,
    select_boxes,
    speeds_from_traj,
)
from sumo_scendiff.generation.pinning import pinned_latent
from sumo_scendiff.map.raster import MAP_CHANNELS, RasterConfig
from sumo_scendiff.model.detection import decode_boxes, on_junction
from sumo_scendiff.model.edm import karras_sigmas, sample_euler
from sumo_scendiff.tokens.encoding import (
    AGENT_TOKEN_DIM,
    feature_dicts,
    features_from_scene,
    global_token,
    pad_tokens,
    token_cells,
    tokens_from_scene,
)

ROOT = os.path.join(os.path.dirname(__file__), "..")
WINDOW = Window(0.0, 0.0)  # boxes are already in the scene frame; only the window's extent matters
CORNER = 50.0              # m from the centre: beyond it, a window's corners


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_model_options(p, "measure its reconstruction only")
    p.add_argument("--data", default=os.path.join(ROOT, "data", "val"))
    p.add_argument("--scenes", type=int, default=96)
    p.add_argument("--turned", action="store_true",
                   help="turn each window by a random angle (SceneDataset(rotate=True)), as training does")
    p.add_argument("--threshold", type=float, default=0.8)
    p.add_argument("--steps", type=int, default=None, help="sampler steps (default: generate's)")
    p.add_argument("--guidance", type=float, default=3.0, help="the guided every-token row's weight")
    p.add_argument("--sigmas", type=float, nargs="*", default=[1.0, 2.0, 4.0, 8.0],
                   help="noise levels of the 'from the data' rows")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, help="also write the report here")
    return p.parse_args(args)


def score(dec, gts: list[np.ndarray], threshold: float, speeds: list[np.ndarray],
          traj_masks: list[np.ndarray], junction: list[np.ndarray]) -> dict:
    """Counts, precision / recall / F1 under the token-match rule, median centre / heading error of
    the nearest prediction, and the speed MAE of matched pairs (speeds from the decoded trajectory,
    as ``ScenarioGenerator`` gives them; final speed where the ground truth has t = +2 s)."""
    prob, boxes, traj = dec.prob.numpy(), dec.boxes.numpy(), dec.traj.numpy()
    tp = fp = fn = 0
    hit_j = []  # ground-truth agents centred on a junction: matched or not
    hit_c = []  # ... centred beyond 50 m from the window's centre (its corners)
    counts, dist, dyaw, cur, fin, still = [], [], [], [], [], []
    for i, gt in enumerate(gts):
        keep = select_boxes(WINDOW, prob[i], boxes[i], threshold)
        gen = boxes[i][keep]
        gi, ti = match_agents(gen, gt)
        tp, fp, fn = tp + len(gi), fp + len(gen) - len(gi), fn + len(gt) - len(ti)
        hit_j += list(np.isin(np.flatnonzero(junction[i]), ti))
        hit_c += list(np.isin(np.flatnonzero(np.hypot(gt[:, 0], gt[:, 1]) > CORNER), ti))
        v = speeds_from_traj(traj[i][keep][gi], np.ones((len(gi), len(TIMES)), bool))
        cur += list(np.abs(v[:, T0] - speeds[i][ti, T0]))
        seen = traj_masks[i][ti, -1]
        fin += list(np.abs(v[seen, -1] - speeds[i][ti[seen], -1]))
        counts.append(len(gen))
        still += list(speeds_from_traj(traj[i][keep], np.ones((len(gen), len(TIMES)), bool))[:, T0] < 1.0)
        if len(gen):
            for t in gt:
                d = np.hypot(*(gen[:, :2] - t[:2]).T)
                dist.append(d.min())
                dyaw.append(abs(wrap_angle(gen[d.argmin(), 2] - t[2])))
    return {**precision_recall_f1(tp, fp, fn), "count": float(np.mean(counts)),
            "dist": float(np.median(dist)) if dist else float("nan"),
            "dyaw": float(np.median(dyaw)) if dyaw else float("nan"),
            "speed": float(np.mean(cur)) if cur else float("nan"),
            "final": float(np.mean(fin)) if fin else float("nan"),
            "still": float(np.mean(still)) if still else float("nan"),
            "recall_junction": float(np.mean(hit_j)) if hit_j else float("nan"),
            "recall_corner": float(np.mean(hit_c)) if hit_c else float("nan")}


def from_noised_data(gen, z0: torch.Tensor, m: torch.Tensor, gts: list, o, truth: tuple) -> dict:
    """Rows 'diffusion from the data at sigma': z0 + sigma * eps integrated back to 0, map only."""
    n = len(gts)
    tok, pad = pad_tokens([np.zeros((0, AGENT_TOKEN_DIM), np.float32)] * n)
    glob = global_token(np.full(n, 1.0), dim=gen.diffusion.cfg.unet.global_dim)
    cond = gen.diffusion.cond(m, tok, pad, torch.from_numpy(glob.reshape(n, -1)))
    eps = torch.randn(z0.shape, generator=torch.Generator().manual_seed(o.seed))
    schedule, rows = karras_sigmas(40), {}
    for sigma in o.sigmas:
        sigmas = torch.cat([torch.tensor([sigma]), schedule[schedule < sigma]])
        z = sample_euler(gen.diffusion.denoiser, z0 + sigma * eps, sigmas, cond=cond)
        rows[f"diffusion from the data at sigma {sigma:g} (map only)"] = score(
            decode_boxes(gen.ae.decode(z / gen.latent_scale, m)), gts, o.threshold, *truth)
    return rows


def lane_yaw(y: torch.Tensor, m: torch.Tensor, data: str, idx: np.ndarray, windows: list) -> torch.Tensor | None:
    """``lane_heading.junction_yaw`` for decoder outputs ``y`` of the scenes ``idx`` of ``data``
    (each scene's network, the ``windows`` it was rendered in); None without a heading head."""
    from sumo_scendiff.data.shards import SceneStore
    from sumo_scendiff.generation.lane_heading import junction_yaw
    from sumo_scendiff.map.network import Network
    store = SceneStore(data)
    paths = [store.net_path(int(i)) for i in idx]
    yaw = None
    for path in sorted(set(paths)):
        sel = [k for k, p in enumerate(paths) if p == path]
        part = junction_yaw(y[sel], [windows[k] for k in sel], Network.load(path),
                            m[sel, MAP_CHANNELS.index("junction")], RasterConfig().size)
        if part is None:
            return None
        yaw = torch.zeros(y.shape[0], part.shape[1]) if yaw is None else yaw
        yaw[sel] = part
    return yaw


def main(o) -> None:
    torch.set_num_threads(2)
    gen, ae, name, sha = load_models(o.checkpoint, o.autoencoder)
    ds = SceneDataset(o.data, rotate=o.turned, seed=o.seed)
    idx = np.random.default_rng(o.seed).choice(len(ds), min(o.scenes, len(ds)), replace=False)
    b = collate_scenes([ds[int(i)] for i in idx])
    n = len(idx)
    cfg = GenerationConfig()
    steps, sampler = o.steps or cfg.steps, cfg.solver()
    gts = [b["boxes"][i][b["valid"][i]].numpy() for i in range(n)]
    scene, slot = torch.where(b["valid"])
    junction = on_junction(b["boxes"][scene, slot], scene, b["map"][:, MAP_CHANNELS.index("junction")],
                           RasterConfig().size).numpy()
    truth = tuple([b[k][i][b["valid"][i]].numpy() for i in range(n)] for k in ("speed", "traj_mask")) + (
        np.split(junction, np.cumsum(b["valid"].sum(1).numpy())[:-1]),)
    m = b["map"]
    rows = {}
    with torch.no_grad():
        mu, logvar = ae.encode(b["agents"])
        y = ae.decode(mu, m)
        rows["autoencoder D(mu, m)"] = score(decode_boxes(y), gts, o.threshold, *truth)
        yaw = lane_yaw(y, m, o.data, idx, b["window"])
        if yaw is not None:   # a heading head: junction boxes take the network's most probable lane
            rows["autoencoder D(mu, m), lane headings (generator default)"] = score(
                decode_boxes(y, yaw=yaw), gts, o.threshold, *truth)
        every = [tokens_from_scene(*(b[k][i][b["valid"][i]].numpy()
                                     for k in ("boxes", "traj", "traj_mask", "speed"))) for i in range(n)]
        runs = (("diffusion, no tokens (p_mask 1)", [np.zeros((0, AGENT_TOKEN_DIM), np.float32)] * n, 1.0),
                ("diffusion, every token (p_mask 0)", every, 0.0))
        runs = [(row, toks, p, 1.0, None) for row, toks, p in runs]
        guided_row = f"diffusion, every token (p_mask 0), guidance {o.guidance:g}"
        runs.append((guided_row, every, 0.0, o.guidance, None))
        if not o.autoencoder:  # every token pinned in the latent (sumo_scendiff/pinning.py)
            dicts = [feature_dicts(*features_from_scene(*(b[k][i][b["valid"][i]].numpy() for k in
                                                          ("boxes", "traj", "traj_mask", "speed"))))
                     for i in range(n)]
            runs.append((guided_row + ", pinned", every, 0.0, o.guidance,
                         pinned_latent(ae, dicts, gen.latent_scale)))
        for row, toks, p, w, known in runs if not o.autoencoder else ():
            tok, pad = pad_tokens(toks)
            glob = global_token(np.full(n, p), dim=gen.diffusion.cfg.unet.global_dim)
            glob = torch.from_numpy(glob.reshape(n, -1))
            z = gen.diffusion.sample(m, tok, pad, glob, steps=steps, sampler=sampler, guidance=w,
                                     generator=torch.Generator().manual_seed(o.seed), known=known)
            rows[row] = score(decode_boxes(gen.decode(z, m, tok, pad)), gts, o.threshold, *truth)
            rows[row]["z_std"] = float(z.std())
        if not o.autoencoder:
            rows.update(from_noised_data(gen, mu * gen.latent_scale, m, gts, o, truth))
        # posterior std at the latent cells holding an agent vs elsewhere
        tok, pad = pad_tokens(every)
        cell, placed = token_cells(tok, pad, mu.shape[-1])
        occ = torch.zeros(n, mu.shape[-1] ** 2, dtype=torch.bool)
        occ.scatter_(1, torch.where(placed, cell, 0), placed)
        sd = (0.5 * logvar).exp().flatten(2).transpose(1, 2)            # (B, HW, C)
        mabs = mu.abs().flatten(2).transpose(1, 2)
    lines = [f"checkpoint `{name}` (sha256 {sha[:12]}…), "
             f"{n} scenes of `{os.path.relpath(o.data, ROOT)}` ({sum(map(len, gts)) / n:.2f} agents per "
             f"scene, {np.mean(np.concatenate(truth[0])[:, T0] < 1.0):.0%} of them standing, < 1 m/s, "
             f"{np.mean(np.concatenate(truth[2])):.0%} centred on a junction, "
             f"{np.mean(np.hypot(*np.concatenate(gts)[:, :2].T) > CORNER):.0%} beyond {CORNER:g} m), "
             f"{'turned' if o.turned else 'axis-aligned'} windows, "
             f"threshold {o.threshold}, {steps} steps of {sampler.__name__} (from the data at sigma: "
             f"Euler on a 40-step schedule)", "",
             "| decoding | agents/scene | precision | recall | F1 | median centre error m | median heading error rad "
             "| speed MAE m/s | final speed MAE m/s | standing share | recall on junctions | recall beyond 50 m |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for label, r in rows.items():
        lines.append(f"| {label} | {r['count']:.2f} | {r['precision']:.3f} | {r['recall']:.3f} | "
                     f"{r['f1']:.3f} | {r['dist']:.2f} | {r['dyaw']:.3f} | {r['speed']:.2f} | {r['final']:.2f} | "
                     f"{r['still']:.2f} | {r['recall_junction']:.3f} | {r['recall_corner']:.3f} |")
    lines += ["", f"latent at agent cells: |mu| {mabs[occ].mean():.2f}, posterior std {sd[occ].mean():.2f}; "
                  f"elsewhere |mu| {mabs[~occ].mean():.2f}, std {sd[~occ].mean():.2f}"]
    if not o.autoencoder:  # a sampler that loses agents leaves latents with too little energy
        lines.append(f"scaled latent std: data {float((mu * gen.latent_scale).std()):.3f}, samples " + ", ".join(
            f"{label.split(', ', 1)[1]} {r['z_std']:.3f}" for label, r in rows.items() if "z_std" in r))
    emit("\n".join(lines) + "\n", o.output, "Reconstruction vs generation on held-out scenes")


if __name__ == "__main__":
    main(get_options())
