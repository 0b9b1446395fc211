"""Benchmark: map-raster time per window on the smallest and the largest real networks.

    python benchmarks/raster.py [--windows 300] [--pixels 128]

Windows are centred on random road points (uniform along car lanes, the lane's heading as yaw), so
each net is measured where its roads are. Prints a markdown table: load time, lanes, car lanes per
window, ms per window (median and mean), and the ratio to the smallest net.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.raster import RasterConfig, render_map

SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "nets")
NETS = {  # smallest and largest real nets (by extent and by lanes)
    "ingolstadt1 (smallest)": "resco_ingolstadt1/ingolstadt1.net.xml",
    "ingolstadt21": "resco_ingolstadt21/ingolstadt21.net.xml",
    "wildau (largest extent)": "wildau/net.net.xml.gz",
    "ingolstadt_cutmap (most lanes)": "ingolstadt_cutmap/Forschungskreuzung_cutmap.net.xml.gz",
}


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--windows", type=int, default=300)
    p.add_argument("--pixels", type=int, default=128)
    p.add_argument("--nets-dir", default=SHARED)
    p.add_argument("-s", "--seed", type=int, default=0)
    return p.parse_args(args)


def main(o) -> None:
    from tqdm import tqdm
    cfg = RasterConfig(pixels=o.pixels)
    rows = []
    for label, rel in NETS.items():
        path = os.path.join(o.nets_dir, rel)
        t = time.perf_counter()
        net = Network.load(path)
        load = time.perf_counter() - t
        rng = np.random.default_rng(o.seed)
        xy, yaw = net.random_road_points(o.windows, rng)
        wins = [Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw)]
        for w in wins[:10]:
            render_map(net, w, cfg)  # warm caches (lane rings)
        times, lanes = [], []
        for w in tqdm(wins, desc=label, leave=False):
            t = time.perf_counter()
            render_map(net, w, cfg)
            times.append(time.perf_counter() - t)
            lanes.append(sum(net.lanes[i].car for i in net.lanes_in(w)))
        rows.append((label, load, len(net.lanes), np.mean(lanes), 1e3 * np.median(times), 1e3 * np.mean(times)))
    base = rows[0][4]
    print(f"map raster {cfg.pixels}x{cfg.pixels}, {o.windows} windows per net, 1 process\n")
    print("| network | load (s) | lanes | car lanes / window | ms / window (median) | ms / window (mean) | ratio to smallest |")
    print("|---|---|---|---|---|---|---|")
    for label, load, n, lpw, med, mean in rows:
        print(f"| {label} | {load:.2f} | {n} | {lpw:.0f} | {med:.2f} | {mean:.2f} | {med / base:.2f}x |")


if __name__ == "__main__":
    main(get_options())
