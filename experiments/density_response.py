"""Experiment: does the model put the requested density into a window?

    python experiments/density_response.py [--checkpoint PATH] [--windows 24] [--out docs/density-response.png]

For every network (the held-out generated networks and the real cities of ../shared/nets by
default), ``--windows`` windows on car lanes (seeded), each generated at every requested density
(vehicles per km of car lane in the window, the ``--density`` of ``run``) without tokens, twice: as
the model draws it with the density as a condition only (``--no-match-density``, no infill), and as
delivered at the defaults (the requested count kept, infill where the model drew too few:
generation/infill.py). Reported per network and request: the median generated density, the median
relative error |generated - requested| / requested, and whether the medians rise with the request;
the PNG plots requested against generated per network with the identity line, one panel per mode.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
REQUESTS = (5.0, 10.0, 20.0, 40.0, 70.0, 100.0)


def default_nets() -> list[str]:
    with open(os.path.join(ROOT, "networks", "splits.json")) as f:
        held = [os.path.join(ROOT, "networks", n) for n in json.load(f)["heldout"]]
    shared = os.path.join(ROOT, "..", "shared", "nets")
    cities = sorted(os.path.join(shared, d, f) for d in os.listdir(shared) if os.path.isdir(os.path.join(shared, d))
                    for f in os.listdir(os.path.join(shared, d)) if f.endswith((".net.xml", ".net.xml.gz")))
    return held + cities


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-n", "--net-file", dest="nets", action="append", help="network (repeat); default: all")
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--windows", type=int, default=24)
    p.add_argument("--density", type=float, nargs="+", default=list(REQUESTS))
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--out", default=None, help="PNG of requested against generated")
    p.add_argument("--json", default=None)
    return p.parse_args(args)


MODES = {"model": {"match_density": False, "infill_passes": 0}, "delivered": {}}


def measure(gen, net, windows, requests, seed, mode: dict) -> dict[float, np.ndarray]:
    from dataclasses import replace

    from sumo_scendiff.map.raster import render_map
    km = np.array([net.car_lane_km(w) for w in windows])
    maps = np.stack([render_map(net, w, gen.raster) for w in windows])
    cfg = replace(gen.config, **mode)
    out = {}
    for d in requests:
        scenes = gen.generate(net, windows, p_mask=1.0, seed=seed, maps=maps, density=d, config=cfg)
        out[d] = np.array([len(s) for s in scenes]) / km
    return out


def main(o) -> int:
    from sumo_scendiff.core.threads import share_cpu
    share_cpu()
    from tqdm import tqdm

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.generation.generator import ScenarioGenerator
    from sumo_scendiff.map.network import Network
    gen = ScenarioGenerator.load(o.checkpoint)
    if not gen.has_density:
        sys.exit(f"{o.checkpoint or 'the shipped model'}: no density condition (trained before it)")
    rows, curves, errors = [], {m: {} for m in MODES}, {m: [] for m in MODES}
    for path in tqdm(o.nets or default_nets(), desc="networks"):
        net = Network.load(path)
        rng = np.random.default_rng(o.seed)
        xy, yaw = net.random_road_points(4 * o.windows, rng)
        wins = [w for w in (Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw))
                if net.car_lane_km(w) > 0.05][: o.windows]
        row = {"network": net.name, "windows": len(wins)}
        for mode, settings in MODES.items():
            res = measure(gen, net, wins, o.density, o.seed, settings)
            med = [float(np.median(res[d])) for d in o.density]
            err = [np.abs(res[d] - d) / d for d in o.density]
            errors[mode] += [e for es in err for e in es]
            curves[mode][net.name] = med
            row[mode] = {"generated_median": med, "rel_error_median": [float(np.median(e)) for e in err],
                         "monotone": bool(np.all(np.diff(med) > 0))}
        rows.append(row)
    head = " / ".join(f"{d:g}" for d in o.density)
    for mode in MODES:
        print(f"\n{mode}: generated veh/km (median over windows) at requested {head}\n")
        print("| network | windows | generated | median rel. error | monotone |")
        print("|---|---|---|---|---|")
        for r in rows:
            m = r[mode]
            print(f"| {r['network']} | {r['windows']} | " + " / ".join(f"{v:.1f}" for v in m["generated_median"])
                  + f" | {np.median(m['rel_error_median']):.2f} | {'yes' if m['monotone'] else 'no'} |")
        per = np.median([e for r in rows for e in r[mode]["rel_error_median"]])
        print(f"\n{mode}: median relative error {np.median(errors[mode]):.3f} over all windows and requests "
              f"({per:.3f} over the networks' per-request medians); monotone on "
              f"{sum(r[mode]['monotone'] for r in rows)} of {len(rows)} networks; per request: "
              + ", ".join(f"{d:g}: {np.median([r[mode]['rel_error_median'][i] for r in rows]):.2f}"
                          for i, d in enumerate(o.density)))
    if o.out:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(1, len(MODES), figsize=(12, 5.5), sharey=True)
        titles = {"model": "the model's own (density as a condition only)",
                  "delivered": "delivered (count kept, infill)"}
        for ax, mode in zip(axes, MODES):
            for name, med in curves[mode].items():
                ax.plot(o.density, med, marker="o", label=name)
            ax.plot(o.density, o.density, "k--", lw=1, label="requested")
            ax.set(xscale="log", yscale="log", xlabel="requested density (vehicles per km of car lane)",
                   title=titles[mode])
        axes[0].set_ylabel("generated density (median over windows)")
        axes[-1].legend(fontsize=7, ncol=2)
        fig.suptitle("Density response, no tokens")
        fig.tight_layout()
        fig.savefig(o.out, dpi=120)
    if o.json:
        with open(o.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
