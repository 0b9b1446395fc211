"""Benchmark: generated scenes per second on this CPU (sampler + decoding + box filtering), batched,
and the bare UNet forward rate beside it.

    python benchmarks/generate.py [--checkpoint PATH] [--batch 32] [--scenes 128] [--repeats 2] [--threads 2]
    python benchmarks/generate.py --only-defaults     # the defaults' row and the ratio to the UNet bound

Windows are random road points of networks/city.net.xml. Map rasters are rendered beforehand and
timed separately (they are the same for every sampler setting). The first rows are map-only
generation: at the defaults, then with other solvers and guidance intervals (a guided step runs a
second UNet pass), then without the global token's guidance; the last two give every window two
position tokens, with and without the tokens' guidance. Every setting runs ``--repeats`` times, the
settings taking turns, and the table gives the best run beside all of them: this machine's speed
drifts by +-25 % within minutes, and whichever setting ran first used to read slowest.

Beside the defaults, in the same turns: the bare UNet's forward rate at the same batch (its bound in
scenes/s is that rate over the UNet passes the defaults' sampler makes at their steps), and the
model alone (map encoder, sampler, decoder: the generator without box decoding and post-processing).
The last line is the generator's rate at the defaults over that bound.
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
from sumo_scendiff.model.edm import karras_sigmas, num_evaluations
from sumo_scendiff.tokens.encoding import global_token

ROOT = os.path.join(os.path.dirname(__file__), "..")
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}
clock = CLOCKS["wall"]


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--checkpoint", default=None)
    p.add_argument("-n", "--net-file", default=os.path.join(ROOT, "networks", "city.net.xml"))
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--scenes", type=int, default=128)
    p.add_argument("--repeats", type=int, default=2, help="timed runs per setting, in turns")
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    p.add_argument("--clock", choices=tuple(CLOCKS), default="wall",
                   help="time rates by wall seconds, or by this process's CPU seconds (all threads): on a "
                        "machine busy with other jobs, CPU seconds measure the work")
    p.add_argument("--only-defaults", action="store_true", help="the defaults' row and the bounds only")
    p.add_argument("-s", "--seed", type=int, default=0)
    return p.parse_args(args)


def main(o) -> None:
    global clock
    clock = CLOCKS[o.clock]
    torch.set_num_threads(o.threads)
    net = Network.load(o.net_file)
    rng = np.random.default_rng(o.seed)
    xy, yaw = net.random_road_points(o.scenes, rng)
    wins = [Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw)]
    t = clock()
    for w in wins:
        render_map(net, w)
    raster = (clock() - t) / len(wins)

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
    settings = settings[:1] if o.only_defaults else settings
    tokens = [[{"x": float(x), "y": float(y)} for x, y in rng.uniform(-30, 30, (2, 2))] for _ in wins]
    gens, rates, agents = {}, {name: [] for name, _, _ in settings}, {}
    for name, overrides, with_tokens in settings:
        gens[name] = gen = ScenarioGenerator.load(o.checkpoint, GenerationConfig(batch_size=o.batch, **overrides))
        kw = dict(tokens=tokens, p_mask=0.5) if with_tokens else {}
        gen.generate(net, wins[: o.batch], seed=o.seed, **{k: v[: o.batch] if k == "tokens" else v
                                                           for k, v in kw.items()})  # warm-up
    maps = np.stack([render_map(net, w) for w in wins])
    bound = {"unet": [], "model": []}
    for _ in range(o.repeats):
        for name, _, with_tokens in settings:
            kw = dict(tokens=tokens, p_mask=0.5) if with_tokens else {}
            t = clock()
            scenes = gens[name].generate(net, wins, seed=o.seed, **kw)
            rates[name].append(len(wins) / (clock() - t))
            agents[name] = np.mean([len(s) for s in scenes])
            if name == settings[0][0]:    # the bounds beside the defaults, in the same turn
                bound["unet"].append(bare_unet(gens[name], o.batch))
                bound["model"].append(model_alone(gens[name], maps, o.batch))

    print(f"{o.scenes} windows of {os.path.basename(o.net_file)}, batch {o.batch}, {o.threads} thread(s), "
          f"{o.clock} seconds\n")
    print("| setting | scenes / s, best run (incl. map raster, decoding, box filtering) | all runs | agents / scene |")
    print("|---|---|---|---|")
    for name, _, _ in settings:
        print(f"| {name} | {max(rates[name]):.1f} | {', '.join(f'{r:.1f}' for r in rates[name])} | "
              f"{agents[name]:.1f} |")
    gen = gens[settings[0][0]]
    passes = num_evaluations(gen.config.solver(), karras_sigmas(gen.config.steps))
    fwd, model = max(bound["unet"]), max(bound["model"])
    best = max(rates[settings[0][0]])
    print(f"\nbare UNet forward: {fwd:.0f} samples/s (batch {o.batch}; runs {', '.join(f'{r:.0f}' for r in bound['unet'])}),"
          f" so at the defaults' {gen.config.steps} steps ({passes} UNet passes a scene) a bound of "
          f"{fwd / passes:.1f} scenes/s; map raster alone: {1e3 * raster:.1f} ms / window")
    print(f"the model alone (map encoder, sampler, decoder; no box decoding or post-processing): {model:.1f} scenes/s "
          f"= {100 * model * passes / fwd:.0f} % of that bound")
    print(f"**generator at defaults / UNet bound: {100 * best * passes / fwd:.0f} %** "
          f"({best:.1f} scenes/s; best runs, measured in turns); / the model alone: {100 * best / model:.0f} %")


@torch.no_grad()
def bare_unet(gen, batch: int, reps: int = 10) -> float:
    """Samples per second of the bare denoiser (one UNet pass) at ``batch``, map encoded beforehand."""
    unet, cfg = gen.diffusion.denoiser, gen.diffusion.cfg.unet
    z = torch.randn(batch, cfg.c_z, cfg.res, cfg.res)
    cond = gen.diffusion.cond(torch.zeros(batch, gen.diffusion.cfg.C_m, 128, 128), torch.zeros(batch, 0, 170),
                              torch.zeros(batch, 0, dtype=torch.bool), torch.zeros(batch, cfg.global_dim))
    unet(z, 1.0, **cond)
    t = clock()
    for _ in range(reps):
        unet(z, 1.0, **cond)
    return reps * batch / (clock() - t)


@torch.no_grad()
def model_alone(gen, maps: np.ndarray, batch: int) -> float:
    """Scenes per second of the generator's torch work alone at the defaults (map-only windows): the
    map encoder and sampler (``diffusion.sample``) and the decoder, nothing before or after."""
    cfg, df = gen.config, gen.diffusion
    t = clock()
    for s in range(0, len(maps), batch):
        m = torch.from_numpy(maps[s:s + batch]).contiguous(memory_format=torch.channels_last)
        n = len(m)
        glob = torch.from_numpy(global_token(np.ones(n), None, dim=df.cfg.unet.global_dim).reshape(n, -1))
        z = df.sample(m, torch.zeros(n, 0, 170), torch.zeros(n, 0, dtype=torch.bool), glob, steps=cfg.steps,
                      sampler=cfg.solver(), noise=torch.randn(n, df.cfg.unet.c_z, df.cfg.unet.res, df.cfg.unet.res),
                      scene_guidance=gen.scene_guidance, scene_guidance_sigma=gen.scene_guidance_sigma)
        gen.decode(z, m)
    return len(maps) / (clock() - t)

if __name__ == "__main__":
    main(get_options())
