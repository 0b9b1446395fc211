"""Benchmark: generated scenes per second on this CPU (sampler + decoding + box filtering), batched,
and the bare UNet forward rate beside it.

    python benchmarks/generate.py [--checkpoint PATH] [--batch 32] [--scenes 128] [--repeats 2]

Windows are random road points of networks/city.net.xml. Map rasters are rendered beforehand and
timed separately (they are the same for every sampler setting). The first rows are map-only
generation: at the defaults, then with other solvers and guidance intervals (a guided step runs a
second UNet pass), then without the global token's guidance; the last two give every window two
position tokens, with and without the tokens' guidance. Every setting runs ``--repeats`` times, the
settings taking turns, and the table gives the best run beside all of them: this machine's speed
drifts by +-25 % within minutes, and whichever setting ran first used to read slowest.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.raster import render_map

ROOT = os.path.join(os.path.dirname(__file__), "..")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None)
    p.add_argument("-n", "--net-file", default=os.path.join(ROOT, "networks", "city.net.xml"))
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--scenes", type=int, default=128)
    p.add_argument("--repeats", type=int, default=2, help="timed runs per setting, in turns")
    p.add_argument("-s", "--seed", type=int, default=0)
    return p.parse_args(args)


def main(o) -> None:
    torch.set_num_threads(2)
    net = Network.load(o.net_file)
    rng = np.random.default_rng(o.seed)
    xy, yaw = net.random_road_points(o.scenes, rng)
    wins = [Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw)]
    t = time.perf_counter()
    for w in wins:
        render_map(net, w)
    raster = (time.perf_counter() - t) / len(wins)

    # (label, GenerationConfig overrides, with two position tokens per window)
    settings = [("defaults", {}, False),
                ("Euler, 20 steps, scene guidance at every step", dict(sampler="euler", steps=20,
                                                                   scene_guidance_sigma=0.0), False),
                ("Euler, 20 steps, scene guidance at sigma > 1", dict(sampler="euler", steps=20,
                                                                  scene_guidance_sigma=1.0), False),
                ("DPM-Solver++(2M), 10 steps", dict(sampler="dpmpp-2m", steps=10), False),
                ("Heun, 10 steps", dict(sampler="heun", steps=10), False),
                ("defaults, lane headings off", dict(lane_headings=False), False),
                ("defaults, lane snap off", dict(lane_snap=False), False),
                ("defaults, lane headings and lane snap off", dict(lane_headings=False, lane_snap=False), False),
                ("defaults, scene guidance off", dict(scene_guidance=1.0), False),
                ("defaults, 2 tokens, guidance 3", dict(guidance=3.0), True),
                ("defaults, 2 tokens, guidance off", dict(guidance=1.0), True)]
    tokens = [[{"x": float(x), "y": float(y)} for x, y in rng.uniform(-30, 30, (2, 2))] for _ in wins]
    gens, rates, agents = {}, {name: [] for name, _, _ in settings}, {}
    for name, overrides, with_tokens in settings:
        gens[name] = gen = ScenarioGenerator.load(o.checkpoint, GenerationConfig(batch_size=o.batch, **overrides))
        kw = dict(tokens=tokens, p_mask=0.5) if with_tokens else {}
        gen.generate(net, wins[: o.batch], seed=o.seed, **{k: v[: o.batch] if k == "tokens" else v
                                                           for k, v in kw.items()})  # warm-up
    for _ in range(o.repeats):
        for name, _, with_tokens in settings:
            kw = dict(tokens=tokens, p_mask=0.5) if with_tokens else {}
            t = time.perf_counter()
            scenes = gens[name].generate(net, wins, seed=o.seed, **kw)
            rates[name].append(len(wins) / (time.perf_counter() - t))
            agents[name] = np.mean([len(s) for s in scenes])

    # bare UNet forward rate at the same batch size
    gen = gens[settings[0][0]]
    unet = gen.diffusion.denoiser
    cfg = gen.diffusion.cfg.unet
    z = torch.randn(o.batch, cfg.c_z, cfg.res, cfg.res)
    cond = gen.diffusion.cond(torch.zeros(o.batch, gen.diffusion.cfg.C_m, 128, 128), torch.zeros(o.batch, 0, 170),
                              torch.zeros(o.batch, 0, dtype=torch.bool), torch.zeros(o.batch, cfg.global_dim))
    with torch.no_grad():
        unet(z, 1.0, **cond)
        t = time.perf_counter()
        reps = 10
        for _ in range(reps):
            unet(z, 1.0, **cond)
        fwd = reps * o.batch / (time.perf_counter() - t)
    print(f"{o.scenes} windows of {os.path.basename(o.net_file)}, batch {o.batch}, 2 threads\n")
    print("| setting | scenes / s, best run (incl. map raster, decoding, box filtering) | all runs | agents / scene |")
    print("|---|---|---|---|")
    for name, _, _ in settings:
        print(f"| {name} | {max(rates[name]):.1f} | {', '.join(f'{r:.1f}' for r in rates[name])} | "
              f"{agents[name]:.1f} |")
    print(f"\nbare UNet forward: {fwd:.0f} samples/s (batch {o.batch}); map raster alone: "
          f"{1e3 * raster:.1f} ms / window")


if __name__ == "__main__":
    main(get_options())
