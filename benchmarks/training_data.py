"""What a recording's windows hold against a reference recording (the real cities' own traffic):
vehicles per window, speeds, the share standing, the fleet's sizes, and the Scenario Dreamer JSDs
of speed, length and width (sumo_scendiff/evaluate/jsd.py) against the reference, pooled and per
reference network.

    python benchmarks/training_data.py data/train data/train_wide --reference data/cities
    python benchmarks/training_data.py data/train_wide --reference data/cities --per-net

Windows are the recorded squares (a recording of circles is cropped to its squares). The
reference: e.g. the nine real cities with their own demand (``python -m sumo_scendiff.data -n
../shared/nets/... -r ... -o data/cities --scenes 900 --scenes-per-episode 100``).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from sumo_scendiff.core.geometry import T0
from sumo_scendiff.data.shards import SceneStore
from sumo_scendiff.evaluate.jsd import JSD_BINS, jsd

FEATURES = ("speed", "length", "width")
STANDING = 0.5   # m/s: a vehicle slower stands (at a light, in a queue)


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data", nargs="+", help="recording directories (each with manifest.json)")
    p.add_argument("--reference", required=True, help="the recording to compare with (e.g. the cities')")
    p.add_argument("--per-net", action="store_true", help="a row per network of each recording too")
    p.add_argument("-o", "--output", help="write the rows as JSON here")
    return p.parse_args(args)


def pooled(store: SceneStore, nets: set[str] | None = None) -> dict:
    """Vehicles per window and the pooled per-vehicle features of ``store``'s windows (those of
    ``nets`` only, when given)."""
    scenes = [store.scene(i) for i in range(len(store)) if nets is None or store.net_name(i) in nets]
    full = [s for s in scenes if len(s)]
    cat = (lambda f: np.concatenate([f(s) for s in full]).astype(np.float64)) if full else (lambda f: np.zeros(0))
    return {"counts": np.array([len(s) for s in scenes]), "speed": cat(lambda s: s.speed[:, T0]),
            "length": cat(lambda s: s.boxes[:, 3]), "width": cat(lambda s: s.boxes[:, 4])}


def row(name: str, v: dict, reference: dict, per_reference: dict[str, dict]) -> dict:
    """One table row: counts, speeds, sizes and the JSDs (scaled as Scenario Dreamer's tables)."""
    out = {"data": name, "windows": int(len(v["counts"])), "vehicles_per_window": float(np.mean(v["counts"])),
           "p90_per_window": float(np.percentile(v["counts"], 90)) if len(v["counts"]) else float("nan"),
           "speed_mean": float(np.mean(v["speed"])) if len(v["speed"]) else float("nan"),
           "standing": float(np.mean(v["speed"] < STANDING)) if len(v["speed"]) else float("nan"),
           "passenger_5x1.8": float(np.mean((np.abs(v["length"] - 5.0) < 0.01) & (np.abs(v["width"] - 1.8) < 0.01)))
           if len(v["length"]) else float("nan")}
    for k in FEATURES:
        lo, hi, w, scale = JSD_BINS[k]
        out[f"jsd_{k}"] = scale * jsd(v[k], reference[k], lo, hi, w)
        each = [scale * jsd(v[k], r[k], lo, hi, w) for r in per_reference.values()]
        out[f"jsd_{k}_per_city"] = float(np.nanmean(each)) if each else float("nan")
    return out


def markdown(rows: list[dict]) -> str:
    cols = [k for k in rows[0] if k != "data"]
    lines = ["| data | " + " | ".join(c.replace("_", " ") for c in cols) + " |",
             "|---|" + "---|" * len(cols)]
    for r in rows:
        lines.append(f"| {r['data']} | " + " | ".join(f"{r[c]:.3g}" if isinstance(r[c], float) else str(r[c])
                                                   for c in cols) + " |")
    return "\n".join(lines)


def main(o) -> int:
    ref_store = SceneStore(o.reference)
    ref_nets = sorted({ref_store.net_name(i) for i in range(len(ref_store))})
    reference = pooled(ref_store)
    per_reference = {n: pooled(ref_store, {n}) for n in ref_nets}
    rows = [row(f"{o.reference} (reference)", reference, reference, per_reference)]
    for d in o.data:
        store = SceneStore(d)
        rows.append(row(d, pooled(store), reference, per_reference))
        if o.per_net:
            for n in sorted({store.net_name(i) for i in range(len(store))}):
                rows.append(row(f"{d}: {n}", pooled(store, {n}), reference, per_reference))
    print(markdown(rows))
    if o.output:
        with open(o.output, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
