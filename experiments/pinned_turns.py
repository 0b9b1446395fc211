"""Pinned tokens' turns and speeds: the model's own path against the generator's default.

    python experiments/pinned_turns.py [--data data/val_dense_disc] [--scenes 200] [-o FILE]

Every fully observed agent of held-out windows (axis-aligned squares) is given as a full token
(pose, size, speed, final speed, heading to final; p_mask 0), once with ``pin_speeds`` off (the
decoder's speeds and path: the model's own) and once on (the default: the token's speeds along the
path, the token's turn, ``pinning.pace_to_pins``); lane headings and lane snap on. The generated
agent nearest each token (within 2 m) is compared with the recorded one: the turn over 0...+2 s
(heading at +2 s minus now) for the vehicles that turn more than 0.2 rad and for the rest, and the
speed and final speed MAE. The model alone does not follow a token's turn
(``experiments/token_response.py``: response 0.00).
"""
from __future__ import annotations

import argparse
import os
from dataclasses import replace

import numpy as np
from report import emit

from sumo_scendiff.core.geometry import T0, wrap_angle
from sumo_scendiff.data.shards import SceneStore
from sumo_scendiff.generation.generator import ScenarioGenerator
from sumo_scendiff.map.network import Network
from sumo_scendiff.tokens.encoding import feature_dicts, features_from_scene

ROOT = os.path.join(os.path.dirname(__file__), "..")
TURNING = 0.2   # rad over 0...+2 s
NEAR = 2.0      # m: the generated agent this close to a token is its


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None, help="scenario-diffusion checkpoint (default: shipped)")
    p.add_argument("--data", default=os.path.join(ROOT, "data", "val_dense_disc"))
    p.add_argument("--scenes", type=int, default=200)
    p.add_argument("-o", "--output", default=None, help="also write the report here")
    return p.parse_args(args)


def measure(gen: ScenarioGenerator, store: SceneStore, idx: list[int], pin_speeds: bool) -> dict:
    cfg = replace(gen.config, pin_speeds=pin_speeds)
    turning, straight, speed, final, found, total = [], [], [], [], 0, 0
    nets: dict[str, Network] = {}
    for k, i in enumerate(idx):
        sc = store.scene(i)
        # (recordings made before RECORDER_VERSION 2 can hold SUMO's invalid speed, -2^30)
        sel = np.flatnonzero(sc.traj_mask.all(1) & (sc.speed >= 0).all(1))
        if not len(sel):
            continue
        toks = feature_dicts(*features_from_scene(sc.boxes[sel], sc.traj[sel], sc.traj_mask[sel], sc.speed[sel]))
        path = store.net_path(i)
        net = nets.setdefault(path, Network.load(path))
        out = gen.generate(net, [sc.window], tokens=[toks], p_mask=0.0, seed=k, config=cfg)[0]
        for j, t in zip(sel, toks):
            total += 1
            d = np.hypot(out.boxes[:, 0] - t["x"], out.boxes[:, 1] - t["y"])
            if not len(d) or d.min() > NEAR:
                continue
            found, a = found + 1, int(d.argmin())
            rec = float(wrap_angle(sc.traj[j, -1, 2] - sc.traj[j, T0, 2]))
            got = float(wrap_angle(out.traj[a, -1, 2] - out.traj[a, T0, 2]))
            (turning if abs(rec) > TURNING else straight).append(abs(got - rec))
            speed.append(abs(out.speed[a, T0] - t["speed"]))
            final.append(abs(out.speed[a, -1] - t["final_speed"]))
    return {"found": found, "total": total, "turning": turning, "straight": straight,
            "speed": float(np.mean(speed)), "final": float(np.mean(final))}


def main(o) -> None:
    store = SceneStore(o.data)
    gen = ScenarioGenerator.load(o.checkpoint)
    idx = list(range(0, len(store), max(1, len(store) // o.scenes)))[: o.scenes]
    lines = [f"checkpoint sha256 {gen.sha256[:12]}…, {len(idx)} windows of `{os.path.relpath(o.data, ROOT)}`, "
             f"every fully observed agent a full token, p_mask 0", "",
             f"| generator | tokens matched within {NEAR:g} m | turn error, vehicles turning > {TURNING:g} rad: "
             "mean / median (n) | turn error, the others: mean | speed MAE m/s | final speed MAE m/s |",
             "|---|---|---|---|---|---|"]
    for label, on in (("the model's own (`pin_speeds=False`)", False), ("default (pinned speeds and turn)", True)):
        r = measure(gen, store, idx, on)
        lines.append(f"| {label} | {r['found']} / {r['total']} | {np.mean(r['turning']):.3f} / "
                     f"{np.median(r['turning']):.3f} ({len(r['turning'])}) | {np.mean(r['straight']):.3f} | "
                     f"{r['speed']:.2f} | {r['final']:.2f} |")
    emit("\n".join(lines) + "\n", o.output, "Pinned tokens: turns and speeds")


if __name__ == "__main__":
    main(get_options())
