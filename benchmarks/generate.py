"""Benchmark: generated scenes per second on this CPU (sampler + decoding + box filtering), batched,
and the bare UNet forward rate beside it.

    python benchmarks/generate.py [--checkpoint PATH] [--steps 20] [--batch 32] [--scenes 128]

Windows are random road points of networks/city.net.xml. Map rasters are rendered beforehand and
timed separately (they are the same for every sampler setting). The first rows are map-only
generation at the default settings (the global token's classifier-free guidance on, which doubles the
UNet batch), then without it; the last two give every window two position tokens, with and without
the tokens' guidance.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from sumo_scendiff.generate import GenerationConfig, ScenarioGenerator
from sumo_scendiff.geometry import Window
from sumo_scendiff.model.edm import sample_euler, sample_heun
from sumo_scendiff.network import Network
from sumo_scendiff.raster import render_map

ROOT = os.path.join(os.path.dirname(__file__), "..")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None)
    p.add_argument("-n", "--net-file", default=os.path.join(ROOT, "networks", "city.net.xml"))
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--scenes", type=int, default=128)
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

    rows = []
    for name, sampler, steps in (("Euler", sample_euler, o.steps), ("Heun", sample_heun, o.steps // 2)):
        gen = ScenarioGenerator.load(o.checkpoint, GenerationConfig(steps=steps, sampler=sampler,
                                                                    batch_size=o.batch))
        gen.generate(net, wins[: o.batch], seed=o.seed)  # warm-up
        t = time.perf_counter()
        scenes = gen.generate(net, wins, seed=o.seed)
        dt = time.perf_counter() - t
        rows.append((f"{name}, {steps} steps", len(wins) / dt, np.mean([len(s) for s in scenes])))
    gen = ScenarioGenerator.load(o.checkpoint, GenerationConfig(steps=o.steps, batch_size=o.batch,
                                                                scene_guidance=1.0))
    gen.generate(net, wins[: o.batch], seed=o.seed)
    t = time.perf_counter()
    scenes = gen.generate(net, wins, seed=o.seed)
    rows.append((f"Euler, {o.steps} steps, scene guidance off", len(wins) / (time.perf_counter() - t),
                 np.mean([len(s) for s in scenes])))
    # with two position tokens per window the classifier-free guidance runs a second UNet pass
    tokens = [[{"x": float(x), "y": float(y)} for x, y in rng.uniform(-30, 30, (2, 2))] for _ in wins]
    for w in (3.0, 1.0):
        gen = ScenarioGenerator.load(o.checkpoint, GenerationConfig(steps=o.steps, batch_size=o.batch,
                                                                    guidance=w))
        gen.generate(net, wins[: o.batch], tokens=tokens[: o.batch], p_mask=0.5, seed=o.seed)
        t = time.perf_counter()
        scenes = gen.generate(net, wins, tokens=tokens, p_mask=0.5, seed=o.seed)
        dt = time.perf_counter() - t
        rows.append((f"Euler, {o.steps} steps, 2 tokens, guidance {w:g}", len(wins) / dt,
                     np.mean([len(s) for s in scenes])))

    # bare UNet forward rate at the same batch size
    unet = gen.diffusion.denoiser
    cfg = gen.diffusion.cfg.unet
    z = torch.randn(o.batch, cfg.c_z, cfg.res, cfg.res)
    cond = gen.diffusion.cond(torch.zeros(o.batch, 11, 128, 128), torch.zeros(o.batch, 0, 170),
                              torch.zeros(o.batch, 0, dtype=torch.bool), torch.zeros(o.batch, 10))
    with torch.no_grad():
        unet(z, 1.0, **cond)
        t = time.perf_counter()
        reps = 10
        for _ in range(reps):
            unet(z, 1.0, **cond)
        fwd = reps * o.batch / (time.perf_counter() - t)
    print(f"{o.scenes} windows of {os.path.basename(o.net_file)}, batch {o.batch}, 2 threads\n")
    print("| setting | scenes / s (incl. map raster, decoding, box filtering) | agents / scene |")
    print("|---|---|---|")
    for name, rate, agents in rows:
        print(f"| {name} | {rate:.1f} | {agents:.1f} |")
    print(f"\nbare UNet forward: {fwd:.0f} samples/s (batch {o.batch}); map raster alone: "
          f"{1e3 * raster:.1f} ms / window")


if __name__ == "__main__":
    main(get_options())
