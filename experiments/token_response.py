"""Does the model follow each token feature? Counterfactual tokens on held-out scenes.

    python experiments/token_response.py [--checkpoint PATH] [--data data/val_dense] [--scenes 96] [-o FILE]
    python experiments/token_response.py --autoencoder runs/ae/last.pt   # a training run's autoencoder alone

On held-out windows of the training networks, every agent is given as a full token; in each window
one moving agent (> 6 m/s now and at +2 s) is the probe. For each feature, the probe's value is
replaced by a low and a high value (everything else, the noise included, unchanged; tokens pinned
unless ``--no-pin-tokens``, see ``sumo_scendiff/pinning.py``) and the
generated vehicle nearest the probe's position (within 2.2 m) is read: its speed now, its speed at
+2 s, its length, the direction of its +2 s displacement. The **response** is

    (generated at high - generated at low) / (asked high - asked low)

1 when the generated vehicle does what the token asks, 0 when the feature is ignored. The row
"as recorded" gives the probe's own values and what is generated from them.

A model can only follow a speed its latent carries, so the autoencoder gets the same question: the
probe is re-rendered with its trajectory scaled about its current position (speed x 0.2 and x 1.5),
encoded and decoded (D(mu(E(x)), m)), and the decoded speed at the probe is read.
"""
from __future__ import annotations

import argparse
import os

import numpy as np
import torch
from report import add_model_options, emit, load_models

from sumo_scendiff.core.geometry import T0, TIMES, Window, wrap_angle
from sumo_scendiff.data.dataset import SceneDataset, collate_scenes
from sumo_scendiff.generation.generator import (
    GenerationConfig,
    select_boxes,
    speeds_from_traj,
)
from sumo_scendiff.generation.pinning import pinned_latent
from sumo_scendiff.map.raster import render_agents
from sumo_scendiff.model.detection import decode_boxes
from sumo_scendiff.tokens.encoding import (
    encode_agent_tokens,
    feature_dicts,
    features_from_scene,
    global_token,
    pad_tokens,
)

ROOT = os.path.join(os.path.dirname(__file__), "..")
WINDOW = Window(0.0, 0.0)  # boxes are already in the scene frame
# feature -> (low, high, what is read from the generated vehicle)
PROBES = {"speed": (2.0, 14.0, "speed now, m/s"), "final_speed": (2.0, 14.0, "speed at +2 s, m/s"),
          "length": (4.0, 12.0, "length, m"), "heading_to_final": (-0.5, 0.5, "+2 s direction, rad")}


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_model_options(p, "its speed response only")
    p.add_argument("--data", default=os.path.join(ROOT, "data", "val_dense"))
    p.add_argument("--scenes", type=int, default=96)
    p.add_argument("--guidance", type=float, default=None, help="token guidance (default: generate's)")
    p.add_argument("--no-pin-tokens", dest="pin_tokens", action="store_false",
                   help="tokens as conditions only (the paper), not pinned in the latent")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, help="also write the report here")
    return p.parse_args(args)


def probes(ds: SceneDataset, n: int, seed: int) -> list[tuple[dict, int]]:
    """(scene, index of its probe agent) for the first ``n`` windows holding a moving agent."""
    out = []
    for i in np.random.default_rng(seed).permutation(len(ds)):
        s = ds[int(i)]
        speed, seen = np.asarray(s["speed"]), np.asarray(s["traj_mask"])[:, -1]
        moving = np.flatnonzero((speed[:, T0] > 6.0) & seen & (speed[:, -1] > 6.0))
        if len(moving):
            out.append((s, int(moving[0])))
        if len(out) == n:
            break
    return out


def read(traj: np.ndarray, box: np.ndarray) -> dict[str, float]:
    """The probed quantities of one generated vehicle."""
    v = speeds_from_traj(traj[None], np.ones((1, len(TIMES)), bool))[0]
    d = traj[-1, :2] - traj[T0, :2]
    return {"speed": v[T0], "final_speed": v[-1], "length": box[3],
            "heading_to_final": float(wrap_angle(np.arctan2(d[1], d[0]) - box[2]))}


def generate(gen, batch, picked, override: tuple[str, float] | None, cfg, seed: int) -> list:
    """Per window, the probed quantities of the vehicle generated at the probe (None if none)."""
    toks, dicts = [], []
    for s, j in picked:
        feats, pres = features_from_scene(*(np.asarray(s[k]) for k in ("boxes", "traj", "traj_mask", "speed")))
        if override:
            name, value = override
            feats[name] = feats[name].copy()
            feats[name][j] = value
            pres[name] = pres[name].copy()
            pres[name][j] = True
        toks.append(encode_agent_tokens(feats, pres))
        dicts.append(feature_dicts(feats, pres))
    tok, pad = pad_tokens(toks)
    n = len(picked)
    glob = torch.from_numpy(global_token(np.zeros(n), dim=gen.diffusion.cfg.unet.global_dim).reshape(n, -1))
    with torch.no_grad():
        known = pinned_latent(gen.ae, dicts, gen.latent_scale) if cfg.pin_tokens else None
        z = gen.diffusion.sample(batch["map"], tok, pad, glob, steps=cfg.steps, sampler=cfg.solver(),
                                 guidance=cfg.guidance, generator=torch.Generator().manual_seed(seed), known=known)
        dec = decode_boxes(gen.ae.decode(z / gen.latent_scale, batch["map"]))
    return at_probes(dec, picked, cfg.threshold)


def at_probes(dec, picked, threshold: float) -> list:
    """Per window, the probed quantities of the decoded vehicle nearest the probe (None beyond 2.2 m)."""
    prob, boxes, traj = dec.prob.numpy(), dec.boxes.numpy(), dec.traj.numpy()
    out = []
    for k, (s, j) in enumerate(picked):
        keep = select_boxes(WINDOW, prob[k], boxes[k], threshold)
        d = np.hypot(*(boxes[k][keep][:, :2] - np.asarray(s["boxes"])[j, :2]).T) if len(keep) else np.zeros(0)
        out.append(read(traj[k][keep][d.argmin()], boxes[k][keep][d.argmin()]) if len(d) and d.min() <= 2.2
                   else None)
    return out


def autoencoder_row(ae, ds, picked, threshold: float) -> str:
    """The autoencoder's speed response: the probe re-rendered at 0.2 / 1.5 times its speed."""
    got, asked = {}, {}
    for scale in (0.2, 1.5):
        xs = []
        for s, j in picked:
            traj, tm = np.asarray(s["traj"]).copy(), np.asarray(s["traj_mask"])
            c = traj[j, T0, :2].copy()
            traj[j, :, :2] = c + scale * (traj[j, :, :2] - c)
            xs.append(render_agents(np.asarray(s["boxes"]), traj, tm, ds.raster))
        m = torch.from_numpy(np.stack([np.asarray(s["map"]) for s, _ in picked]))
        with torch.no_grad():
            got[scale] = at_probes(decode_boxes(ae.decode(ae.encode(torch.from_numpy(np.stack(xs)))[0], m)),
                                   picked, threshold)
        asked[scale] = [scale * float(np.asarray(s["speed"])[j, T0]) for s, j in picked]
    both = [k for k in range(len(picked)) if got[0.2][k] and got[1.5][k]]
    a_lo, a_hi = (float(np.mean([asked[sc][k] for k in both])) for sc in (0.2, 1.5))
    g_lo, g_hi = (float(np.mean([got[sc][k]["speed"] for k in both])) for sc in (0.2, 1.5))
    return (f"| autoencoder D(mu(E(x)), m), probe re-rendered | speed now, m/s | – | {a_lo:.2f} → {g_lo:.2f} | "
            f"{a_hi:.2f} → {g_hi:.2f} | {(g_hi - g_lo) / (a_hi - a_lo):.2f} | {len(both)} / {len(picked)} |")


def main(o) -> None:
    torch.set_num_threads(2)
    gen, ae, name, sha = load_models(o.checkpoint, o.autoencoder)
    cfg = GenerationConfig(pin_tokens=o.pin_tokens,
                           **({"guidance": o.guidance} if o.guidance is not None else {}))
    ds = SceneDataset(o.data, rotate=False)
    picked = probes(ds, o.scenes, o.seed)
    lines = [f"checkpoint `{name}` (sha256 {sha[:12]}…), {len(picked)} windows of "
             f"`{os.path.relpath(o.data, ROOT)}` with a moving probe agent, every agent a full token, "
             f"{cfg.steps} steps of {cfg.solver().__name__}, token guidance {cfg.guidance:g}, tokens "
             f"{'pinned' if cfg.pin_tokens else 'conditions only'}", "",
             "| feature | read from the generated vehicle | as recorded: asked / generated | asked low → generated "
             "| asked high → generated | response (1 = follows, 0 = ignores) | probes found |",
             "|---|---|---|---|---|---|---|"]
    if gen is not None:
        lines += diffusion_rows(gen, picked, cfg, o.seed)
    lines.append(autoencoder_row(ae, ds, picked, cfg.threshold))
    emit("\n".join(lines) + "\n", o.output, "Token feature response on held-out scenes")


def diffusion_rows(gen, picked, cfg, seed: int) -> list[str]:
    """One row per feature of PROBES: the diffusion model's response to a counterfactual token."""
    batch = collate_scenes([s for s, _ in picked])
    asked = [features_from_scene(*(np.asarray(s[k]) for k in ("boxes", "traj", "traj_mask", "speed")))[0]
             for s, _ in picked]
    base = generate(gen, batch, picked, None, cfg, seed)
    rows = []
    for name, (lo, hi, what) in PROBES.items():
        low = generate(gen, batch, picked, (name, lo), cfg, seed)
        high = generate(gen, batch, picked, (name, hi), cfg, seed)
        both = [k for k in range(len(picked)) if low[k] and high[k]]
        rec = [k for k in range(len(picked)) if base[k]]
        g_lo, g_hi = (float(np.mean([r[k][name] for k in both])) for r in (low, high))
        rec_asked = float(np.mean([asked[k][name][picked[k][1]] for k in rec]))
        rec_gen = float(np.mean([base[k][name] for k in rec]))
        rows.append(f"| `{name}` | {what} | {rec_asked:.2f} / {rec_gen:.2f} | {lo:g} → {g_lo:.2f} | "
                    f"{hi:g} → {g_hi:.2f} | {(g_hi - g_lo) / (hi - lo):.2f} | {len(both)} / {len(picked)} |")
    return rows


if __name__ == "__main__":
    main(get_options())
