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
encoded and decoded (D(mu(E(x)), m)), and the decoded speed at the probe is read; likewise its
future alone scaled (final speed), and its future redrawn as the arc that turns by
``heading_to_final`` -0.5 / +0.5 rad at its own distances (pinning.token_trajectories' arc). A decoder
that reads the tokens (C_t) is also asked with the recorded scene's latent and the probe's token
changed: does the token's word win over the latent's? And with the latent and the token agreeing, the
probe's token giving only its speed, only its final speed, or both (as a user writes them): is what
the decoder draws what the token says (mean signed error: a decoder that reads a missing final speed
as 0 m/s draws a speed-only token too fast)?
"""
from __future__ import annotations

import argparse
import os

import numpy as np
from report import add_model_options, emit, load_models

from sumo_scendiff.core.threads import share_cpu

share_cpu(default=1)   # before torch is imported: one thread, the machine is shared

import torch

from sumo_scendiff.core.geometry import T0, TIMES, Window, wrap_angle
from sumo_scendiff.data.dataset import SceneDataset, collate_scenes
from sumo_scendiff.generation.generator import (
    GenerationConfig,
    select_boxes,
    speeds_from_traj,
)
from sumo_scendiff.generation.pinning import _arc, pinned_latent
from sumo_scendiff.map.raster import render_agents
from sumo_scendiff.tokens.features import is_pinnable
from sumo_scendiff.tokens.raster import exact_values
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
    p.add_argument("--plain-guidance", dest="local_guidance", action="store_false", default=None,
                   help="the tokens' guidance over the whole window, the paper's (default: local and projected)")
    p.add_argument("--steps", type=int, default=None, help="ODE steps (default: generate's)")
    p.add_argument("--sampler", default=None, help="ODE solver (default: generate's)")
    p.add_argument("--p-mask", type=float, default=0.0,
                   help="the global token's p_mask (default 0: every agent is a token)")
    p.add_argument("--binned-token-values", dest="exact_token_values", action="store_false", default=None,
                   help="the decoder reads the tokens' speeds and turn as their bins' centres (generate's flag)")
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


def asked_tokens(picked, override: tuple[str, float] | None) -> tuple[list, list]:
    """Per window, every agent as a full token (encoded, and as feature dicts), the probe's feature
    ``override`` = (name, value) set."""
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
    return toks, dicts


def generate(gen, batch, picked, override: tuple[str, float] | None, cfg, seed: int, p_mask: float = 0.0) -> list:
    """Per window, the probed quantities of the vehicle generated at the probe (None if none)."""
    toks, dicts = asked_tokens(picked, override)
    tok, pad = pad_tokens(toks)
    n = len(picked)
    glob = torch.from_numpy(global_token(np.full(n, p_mask), dim=gen.diffusion.cfg.unet.global_dim).reshape(n, -1))
    with torch.no_grad():
        known = pinned_latent(gen.ae, dicts, gen.latent_scale) if cfg.pin_tokens else None
        z = gen.diffusion.sample(batch["map"], tok, pad, glob, steps=cfg.steps, sampler=cfg.solver(),
                                 guidance=cfg.guidance, local=cfg.local_guidance,
                                 generator=torch.Generator().manual_seed(seed), known=known)
        # as the generator: pinned tokens keep their bins (their latent's calibration is the bins')
        skip = (lambda d: is_pinnable(d)) if cfg.pin_tokens else None
        exact = exact_values(dicts, [len(t) for t in toks], skip) if cfg.exact_token_values else None
        dec = decode_boxes(gen.decode(z, batch["map"], tok, pad, exact))
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


def _future_scaled(traj: np.ndarray, j: int, scale: float) -> np.ndarray:
    """The probe's future (t > 0) displacement from t = 0 scaled: its final speed x ``scale``."""
    t = np.asarray(TIMES)
    c = traj[j, T0, :2].copy()
    traj[j, t > 0, :2] = c + scale * (traj[j, t > 0, :2] - c)
    return traj


def _all_scaled(traj: np.ndarray, j: int, scale: float) -> np.ndarray:
    c = traj[j, T0, :2].copy()
    traj[j, :, :2] = c + scale * (traj[j, :, :2] - c)
    return traj


def _turned(traj: np.ndarray, j: int, alpha: float) -> np.ndarray:
    """The probe's future redrawn as the arc from its pose now whose chord leaves at ``alpha``, at
    its own distances along its path."""
    t = np.asarray(TIMES)
    steps = np.linalg.norm(np.diff(traj[j, :, :2], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    s = s - s[T0]
    traj[j, t > 0] = _arc(*traj[j, T0], s, alpha, t)[t > 0]
    return traj


# feature -> (how the probe is redrawn, low and high value, and what is asked at each)
AE_PROBES = {
    "speed": (_all_scaled, 0.2, 1.5, lambda s, j, v: v * float(np.asarray(s["speed"])[j, T0]), "speed now, m/s"),
    "final_speed": (_future_scaled, 0.2, 1.5, lambda s, j, v: v * float(np.asarray(s["speed"])[j, -1]),
                    "speed at +2 s, m/s"),
    "heading_to_final": (_turned, -0.5, 0.5, lambda s, j, v: v, "+2 s direction, rad"),
}


def autoencoder_rows(ae, ds, picked, threshold: float) -> list[str]:
    """The autoencoder's response: the probe re-rendered with its speed, final speed or turn changed
    (:data:`AE_PROBES`), encoded and decoded, and read at the probe."""
    rows = []
    m = torch.from_numpy(np.stack([np.asarray(s["map"]) for s, _ in picked]))
    for name, (redraw, lo, hi, asked_of, what) in AE_PROBES.items():
        got, asked = {}, {}
        for v in (lo, hi):
            xs = []
            for s, j in picked:
                traj = redraw(np.asarray(s["traj"], np.float64).copy(), j, v)
                xs.append(render_agents(np.asarray(s["boxes"]), traj.astype(np.float32), np.asarray(s["traj_mask"]),
                                        ds.raster))
            with torch.no_grad():
                got[v] = at_probes(decode_boxes(ae.decode(ae.encode(torch.from_numpy(np.stack(xs)))[0], m)),
                                   picked, threshold)
            asked[v] = [asked_of(s, j, v) for s, j in picked]
        both = [k for k in range(len(picked)) if got[lo][k] and got[hi][k]]
        a_lo, a_hi = (float(np.mean([asked[v][k] for k in both])) for v in (lo, hi))
        g_lo, g_hi = (float(np.mean([got[v][k][name] for k in both])) for v in (lo, hi))
        rows.append(f"| autoencoder D(mu(E(x)), m), probe re-rendered | {what} | – | {a_lo:.2f} → {g_lo:.2f} | "
                    f"{a_hi:.2f} → {g_hi:.2f} | {(g_hi - g_lo) / (a_hi - a_lo):.2f} | {len(both)} / {len(picked)} |")
    return rows


def recorded_latents(ae, picked) -> tuple[torch.Tensor, torch.Tensor]:
    """(mu(E(x)), m) of the probed windows as recorded."""
    m = torch.from_numpy(np.stack([np.asarray(s["map"]) for s, _ in picked]))
    with torch.no_grad():
        return ae.encode(torch.from_numpy(np.stack([np.asarray(s["agents"]) for s, _ in picked])))[0], m


def decoder_token_rows(ae, picked, threshold: float, mu: torch.Tensor, m: torch.Tensor) -> list[str]:
    """A decoder that reads the tokens (C_t): the recorded scene's latent D(mu(E(x)), m, t) with
    every agent a full token and the probe's feature set low and high in its token only; the latent
    says what was recorded, the token something else: which does the decoder draw?"""
    rows = []
    for name, (lo, hi, what) in PROBES.items():
        got = {}
        for v in (lo, hi):
            tok, pad = pad_tokens(asked_tokens(picked, (name, v))[0])
            with torch.no_grad():
                got[v] = at_probes(decode_boxes(ae.decode(mu, m, ae.token_raster(tok, pad))), picked, threshold)
        both = [k for k in range(len(picked)) if got[lo][k] and got[hi][k]]
        g_lo, g_hi = (float(np.mean([got[v][k][name] for k in both])) for v in (lo, hi))
        rows.append(f"| decoder D(mu(E(x)), m, t), the probe's token changed | {what} | – | {lo:g} → {g_lo:.2f} | "
                    f"{hi:g} → {g_hi:.2f} | {(g_hi - g_lo) / (hi - lo):.2f} | {len(both)} / {len(picked)} |")
    return rows


def decoder_partial_rows(ae, picked, threshold: float, mu: torch.Tensor, m: torch.Tensor) -> list[str]:
    """A decoder that reads the tokens, the recorded scene's latent and the probe alone a token of its
    position and its own speed / final speed / both: the mean signed error of what is drawn."""
    rows = []
    for given in (("speed",), ("final_speed",), ("speed", "final_speed")):
        toks = []
        for s, j in picked:
            feats, pres = features_from_scene(*(np.asarray(s[k]) for k in ("boxes", "traj", "traj_mask", "speed")))
            toks.append(encode_agent_tokens({k: v[j:j + 1] for k, v in feats.items()},
                                            {k: v[j:j + 1] & (k in ("x", "y") + given) for k, v in pres.items()}))
        tok, pad = pad_tokens(toks)
        with torch.no_grad():
            got = at_probes(decode_boxes(ae.decode(mu, m, ae.token_raster(tok, pad))), picked, threshold)
        err = {name: [g[name] - float(np.asarray(s["speed"])[j, t]) for g, (s, j) in zip(got, picked) if g]
               for name, t in (("speed", T0), ("final_speed", -1))}
        rows.append(f"| decoder D(mu(E(x)), m, t), the probe's token x, y, {' and '.join(given)} as recorded | "
                    f"speed now / at +2 s, mean signed error m/s | – | {np.mean(err['speed']):+.2f} | "
                    f"{np.mean(err['final_speed']):+.2f} | – | {len(err['speed'])} / {len(picked)} |")
    return rows


def turning_row(ae, ds, n: int, seed: int, threshold: float) -> str:
    """Can the latent carry a turn at all? Recorded agents that turn (|heading_to_final| >= 0.1 rad,
    moving >= 0.5 m in 2 s) in ``n`` held-out windows, each window encoded and decoded as recorded:
    the decoded vehicle at each such agent (within 2.2 m) is read, and its +2 s direction compared
    with the recorded one (least-squares slope through the origin; share turning the same way within
    0.2 rad, user_tokens.py's turn agreement)."""
    rec, dec = [], []
    order = np.random.default_rng(seed).permutation(len(ds))
    batch: list = []
    for i in order:
        s = ds[int(i)]
        feats, pres = features_from_scene(*(np.asarray(s[k]) for k in ("boxes", "traj", "traj_mask", "speed")))
        turning = np.flatnonzero(pres["heading_to_final"] & (np.abs(feats["heading_to_final"]) >= 0.1))
        batch += [((s, int(j)), float(feats["heading_to_final"][j])) for j in turning]
        if len({id(b[0][0]) for b in batch}) >= n:
            break
    scenes = {id(p[0]): p[0] for p, _ in batch}
    ids = list(scenes)
    m = torch.from_numpy(np.stack([np.asarray(scenes[k]["map"]) for k in ids]))
    x = torch.from_numpy(np.stack([render_agents(np.asarray(scenes[k]["boxes"]), np.asarray(scenes[k]["traj"]),
                                                 np.asarray(scenes[k]["traj_mask"]), ds.raster) for k in ids]))
    with torch.no_grad():
        d = decode_boxes(ae.decode(ae.encode(x)[0], m))
    for (sc, j), h in batch:
        k = ids.index(id(sc))
        got = at_probes(_Index(d, k), [(sc, j)], threshold)[0]
        if got:
            rec.append(h)
            dec.append(got["heading_to_final"])
    rec, dec = np.array(rec), np.array(dec)
    slope = float((rec * dec).sum() / (rec * rec).sum())
    agree = float(np.mean((np.sign(dec) == np.sign(rec)) & (np.abs(dec - rec) <= 0.2)))
    return (f"| autoencoder D(mu(E(x)), m), recorded turning agents | +2 s direction, rad | mean |asked| "
            f"{np.abs(rec).mean():.2f} / decoded {np.abs(dec).mean():.2f} | – | – | slope {slope:.2f}, turn agreement "
            f"{agree:.2f} | {len(rec)} agents / {len(ids)} windows |")


class _Index:
    """One window of a batched decoding, as at_probes reads it."""
    def __init__(self, d, k: int):
        self.prob, self.boxes, self.traj = d.prob[k:k + 1], d.boxes[k:k + 1], d.traj[k:k + 1]


def main(o) -> None:
    gen, ae, name, sha = load_models(o.checkpoint, o.autoencoder)
    cfg = GenerationConfig(pin_tokens=o.pin_tokens, **{k: getattr(o, k) for k in ("guidance", "local_guidance", "steps", "sampler",
                                                                                "exact_token_values")
                                                       if getattr(o, k) is not None}).validate()
    ds = SceneDataset(o.data, rotate=False)
    picked = probes(ds, o.scenes, o.seed)
    lines = [f"checkpoint `{name}` (sha256 {sha[:12]}…), {len(picked)} windows of "
             f"`{os.path.relpath(o.data, ROOT)}` with a moving probe agent, every agent a full token, "
             f"{cfg.steps} steps of {cfg.solver().__name__}, token guidance {cfg.guidance:g}"
             f"{'' if cfg.local_guidance else ' (plain)'}, tokens "
             f"{'pinned' if cfg.pin_tokens else 'conditions only'}, p_mask {o.p_mask:g}", "",
             "| feature | read from the generated vehicle | as recorded: asked / generated | asked low → generated "
             "| asked high → generated | response (1 = follows, 0 = ignores) | probes found |",
             "|---|---|---|---|---|---|---|"]
    if gen is not None:
        lines += diffusion_rows(gen, picked, cfg, o.seed, o.p_mask)
    lines += autoencoder_rows(ae, ds, picked, cfg.threshold)
    if ae.cfg.C_t:
        mu, m = recorded_latents(ae, picked)
        lines += decoder_token_rows(ae, picked, cfg.threshold, mu, m)
        lines += decoder_partial_rows(ae, picked, cfg.threshold, mu, m)
    lines.append(turning_row(ae, ds, o.scenes, o.seed, cfg.threshold))
    emit("\n".join(lines) + "\n", o.output, "Token feature response on held-out scenes")


def diffusion_rows(gen, picked, cfg, seed: int, p_mask: float = 0.0) -> list[str]:
    """One row per feature of PROBES: the diffusion model's response to a counterfactual token."""
    batch = collate_scenes([s for s, _ in picked])
    asked = [features_from_scene(*(np.asarray(s[k]) for k in ("boxes", "traj", "traj_mask", "speed")))[0]
             for s, _ in picked]
    base = generate(gen, batch, picked, None, cfg, seed, p_mask)
    rows = []
    for name, (lo, hi, what) in PROBES.items():
        low = generate(gen, batch, picked, (name, lo), cfg, seed, p_mask)
        high = generate(gen, batch, picked, (name, hi), cfg, seed, p_mask)
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
