"""Does the model take the turn a token asks where the road offers a choice?

    python experiments/turn_choice.py [--cities resco_cologne3 ...] [--windows 60] [--guidance G] [-o FILE]
    python experiments/turn_choice.py --no-lane-snap      # the path as decoded (no lane snap, no lane headings)
    python experiments/turn_choice.py --decoder-alone     # the decoder on the recorded scene's latent

``token_response.py`` asks a ±0.5 rad turn of a moving vehicle wherever it is, mostly mid-edge,
where no lane turns: a model that keeps its vehicles on the road does not follow it. Here the turn
asked is one the network offers. Per real city (as ``user_tokens.py``: SUMO's own traffic on its
own demand, the evaluation cache's recordings), in each window one of SUMO's vehicles moving at
>= 3 m/s whose next 2 s of travel (its own recorded distance) can end on lanes whose directions
from it differ by >= 0.15 rad within what a token can say (``tokens.encoding.H2F_RANGE``; an approach
to a junction whose lane goes straight and turns) becomes the window's only token: x, y, heading,
speed and ``heading_to_final`` as the rightmost of those continuations, then as the leftmost (the
same noise, the rest of the traffic left to the model at p_mask 0.5, delivery off: the model's own
drawing, lane snap included). The continuations follow the lanes' centre lines through the
junction's internal lanes (``Network.successors``) from where the vehicle stands.

``--decoder-alone`` asks the autoencoder instead: the recorded window encoded (its latent says what
SUMO's vehicle did), decoded with the one token (does the decoder draw the turn the token asks,
where the latent says the other?), the decoded path as it is.

Reported per city and together: how many probes were matched both times (Hungarian within 2.2 m
and 0.2 rad, ``core.matching``), the **response** (mean drawn turn at the left ask − at the right
ask) / (mean asked left − asked right) (1: follows, 0: ignores; ``token_response.py``'s measure),
with its 90 % interval over the probes (a percentile bootstrap, :data:`BOOTSTRAP` resamples: a city
offers from a handful of probes to a few dozen, ``--windows 240`` for 20 or more on each shared city),
and the share of probes whose drawn turn is nearer the asked continuation than the other, both times.
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import replace

import numpy as np
from report import emit
from user_tokens import ROOT, cities_with_demand, heading_to_final, network_of

from sumo_scendiff.core.threads import share_cpu

share_cpu(default=1)   # before torch is imported: one thread, the machine is shared

from sumo_scendiff.core.geometry import T0, T_FINAL, wrap_angle
from sumo_scendiff.core.matching import match_agents
from sumo_scendiff.data.demand import find_demand
from sumo_scendiff.data.shards import SceneStore
from sumo_scendiff.evaluate.__main__ import record_cached
from sumo_scendiff.generation.generator import ScenarioGenerator
from sumo_scendiff.map.raster import render_agents, render_map
from sumo_scendiff.model.detection import decode_boxes
from sumo_scendiff.tokens.encoding import H2F_RANGE, agent_tokens_from_dicts, pad_tokens
from sumo_scendiff.tokens.raster import exact_values

MIN_SPEED, MIN_APART = 3.0, 0.15     # m/s, rad
BOOTSTRAP = 2000                     # resamples of the probes for the response's interval


def continuations(net, lane: int, pos: float, dist: float, depth: int = 6) -> list[np.ndarray]:
    """The world points ``dist`` m ahead of ``pos`` on ``lane`` along every chain of successor lanes
    (centre lines, internal lanes included)."""
    line = net.lines[lane]
    if pos + dist <= line.length or depth == 0 or not net.successors[lane]:
        return [np.asarray(line.interpolate(min(pos + dist, line.length)).coords[0])]
    rest = dist - (line.length - pos)
    return [p for nxt in net.successors[lane] for p in continuations(net, nxt, 0.0, rest, depth - 1)]


def choices(net, scene) -> list[tuple[int, float, float]]:
    """Per vehicle of ``scene`` that has a choice: (index, rightmost, leftmost) ``heading_to_final``
    of its continuations, relative to its box heading."""
    out = []
    w = scene.window
    for j in range(len(scene.boxes)):
        if not scene.traj_mask[j, T_FINAL] or scene.speed[j, T0] < MIN_SPEED:
            continue
        tr = scene.traj[j].astype(np.float64)
        ok = scene.traj_mask[j, T0:]
        dist = float(np.sum(np.hypot(*np.diff(tr[T0:][ok, :2], axis=0).T)))
        start = w.scene_to_world(tr[T0, :2])
        yaw = float(scene.boxes[j, 2]) + w.yaw
        m = net.match_poses(start[None], [yaw], radius=2.0, max_angle=0.5)
        if m.lane[0] < 0 or dist < 3.0:
            continue
        ends = continuations(net, int(m.lane[0]), float(m.pos[0]), dist)
        ang = np.array([wrap_angle(np.arctan2(*(e - start)[::-1]) - yaw) for e in ends])
        ang = ang[(ang >= H2F_RANGE[0]) & (ang <= H2F_RANGE[1])]     # what a token can say (no U-turns)
        if len(ang) and ang.max() - ang.min() >= MIN_APART:
            out.append((j, float(ang.min()), float(ang.max())))
    return out


def token(scene, j: int, turn: float) -> dict:
    b = scene.boxes[j]
    return {"x": float(b[0]), "y": float(b[1]), "heading": float(b[2]), "speed": float(scene.speed[j, T0]),
            "heading_to_final": turn}


def drawn_turns(scenes, toks) -> list[float | None]:
    """The ``heading_to_final`` of the agent each scene matched to its one token (None: none)."""
    return [_turn_at(s.boxes, s.traj, t) for s, t in zip(scenes, toks)]


def _turn_at(boxes, traj, t: dict) -> float | None:
    gi, _ = match_agents(np.asarray(boxes)[:, :3], np.array([[t["x"], t["y"], t["heading"]]]))
    return heading_to_final(np.asarray(traj)[gi[0]].astype(np.float64)) if len(gi) else None


def decoded_turns(gen, net, scenes, toks) -> list[float | None]:
    """:func:`drawn_turns` of the autoencoder alone: each recorded scene encoded, decoded with its
    one token (its exact values, as generation gives them), boxes kept at the generator's threshold."""
    import torch
    out = []
    for s, t in zip(scenes, toks):
        m = torch.from_numpy(render_map(net, s.window, gen.raster, signals=s.meta.get("signals") or None)[None])
        x = torch.from_numpy(render_agents(s.boxes, s.traj, s.traj_mask, gen.raster)[None])
        tok, pad = pad_tokens([agent_tokens_from_dicts([t])])
        with torch.no_grad():
            d = decode_boxes(gen.ae.decode(gen.ae.encode(x)[0], m, gen.ae.token_raster(tok, pad, exact_values([[t]], [1]))))
        keep = d.prob[0].numpy() >= gen.config.threshold
        out.append(_turn_at(d.boxes[0].numpy()[keep], d.traj[0].numpy()[keep], t))
    return out


def summary(asked_lo, asked_hi, got_lo, got_hi) -> dict:
    both = [k for k in range(len(asked_lo)) if got_lo[k] is not None and got_hi[k] is not None]
    if not both:
        return {"n": len(asked_lo), "both": 0, "response": float("nan"), "took": float("nan"), "apart": float("nan")}
    a_lo, a_hi = np.array([asked_lo[k] for k in both]), np.array([asked_hi[k] for k in both])
    g_lo, g_hi = np.array([got_lo[k] for k in both]), np.array([got_hi[k] for k in both])
    took = (np.abs(g_lo - a_lo) < np.abs(g_lo - a_hi)) & (np.abs(g_hi - a_hi) < np.abs(g_hi - a_lo))
    # the response's spread over the probes (a city offers a handful to a few dozen): a percentile
    # bootstrap, seeded, so the same probes give the same interval
    pick = np.random.default_rng(0).integers(len(both), size=(BOOTSTRAP, len(both)))
    boot = (g_hi - g_lo)[pick].mean(1) / np.maximum((a_hi - a_lo)[pick].mean(1), 1e-9)
    lo, hi = np.percentile(boot, [5, 95])
    return {"n": len(asked_lo), "both": len(both), "apart": float(np.mean(a_hi - a_lo)),
            "response": float(np.mean(g_hi - g_lo) / np.mean(a_hi - a_lo)), "interval": (float(lo), float(hi)),
            "took": float(took.mean())}


def row(city: str, r: dict) -> str:
    ci = " (–)" if np.isnan(r["response"]) else f" ({r['interval'][0]:.2f}–{r['interval'][1]:.2f})"
    return (f"| {city} | {r['n']} | {r['both']} | {r['apart']:.2f} | {r['response']:.2f}{ci} | {r['took']:.2f} |")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cities", nargs="+", default=None,
                   help="folders of /work/shared/nets holding a network and its .rou.xml (default: every one "
                        "whose network has demand)")
    p.add_argument("--windows", type=int, default=30, help="recorded windows per city")
    p.add_argument("--p-mask", type=float, default=0.5)
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("--cache", default=os.path.join(ROOT, ".cache", "eval"))
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--guidance", type=float, default=None, help="token guidance weight (default: generate's)")
    p.add_argument("--no-lane-snap", action="store_true", help="the paths as decoded: no lane snap, no lane headings")
    p.add_argument("--decoder-alone", action="store_true",
                   help="the autoencoder on the recorded window with the one token, not the diffusion model")
    p.add_argument("-o", "--output", default=None, help="also write the table here (markdown)")
    return p.parse_args(args)


def main(o) -> int:
    gen = ScenarioGenerator.load(o.checkpoint)
    cfg = replace(gen.config, deliver_tokens=False,
                  **({} if o.guidance is None else {"guidance": o.guidance}),
                  **({"lane_snap": False, "lane_headings": False} if o.no_lane_snap else {})).validate()
    lines = ["| city | probes | matched both times | asked apart, rad | response (90 % interval) | nearer the asked, both times |",
             "|---|---|---|---|---|---|"]
    pooled = [[], [], [], []]
    for city in o.cities or cities_with_demand():
        net = network_of(city)
        store = SceneStore(record_cached([net.path], [find_demand(net)], o.windows, o.seed, o.cache,
                                         f"gt-{net.name}"))
        rng = np.random.default_rng(o.seed)
        probes = []
        for i in range(min(o.windows, len(store))):
            s = store.scene(i)
            c = choices(net, s)
            if c:
                probes.append((s, c[int(rng.integers(len(c)))]))
        if not probes:
            continue
        got = {}
        for side in (1, 2):     # the rightmost, then the leftmost continuation
            toks = [token(s, c[0], c[side]) for s, c in probes]
            if o.decoder_alone:
                got[side] = decoded_turns(gen, net, [s for s, _ in probes], toks)
                continue
            scenes = gen.generate(net, [s.window for s, _ in probes], tokens=[[t] for t in toks], p_mask=o.p_mask,
                                  seed=o.seed, signals=[s.meta.get("signals") or None for s, _ in probes],
                                  config=cfg)
            got[side] = drawn_turns(scenes, toks)
        parts = ([c[1] for _, c in probes], [c[2] for _, c in probes], got[1], got[2])
        for acc, part in zip(pooled, parts):
            acc += part
        lines.append(row(net.name, summary(*parts)))
        print(lines[-1], file=sys.stderr)
    lines.append(row("**all**", summary(*pooled)))
    emit("\n".join(lines) + "\n", o.output, "A turn where the road offers one")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
