"""Scenario Dreamer's JSD set of a model on the real cities against SUMO's own floor, as one results file.

    python benchmarks/jsd_table.py -o results/jsd.json                  # evaluate each city, then the table
    python benchmarks/jsd_table.py --from compare/shipped/evaluate -o results/jsd.json   # evaluate's JSONs

Per city (``evaluate --scenes 100 -n NET --json``, the model's own count): each JSD of the set for the
model, with the scenario's fleet where the city has a demand (the sizes SUMO's vehicles get when ``run``
seeds them; docs/evaluation.md), and SUMO's own traffic in the other windows (the floor), and the ratio
to the floor (the target: every JSD within 2x). ``python benchmarks/report.py`` draws the table.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
FEATURES = ("speed", "nearest", "lane_heading", "lane_distance", "length", "width")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--from", dest="source", default=None, metavar="DIR",
                   help="evaluate --json files already written (one per city), instead of running evaluate")
    p.add_argument("--checkpoint", default=None, help="model (default: the shipped one)")
    p.add_argument("--scenes", type=int, default=100)
    p.add_argument("-o", "--output", required=True, help="the results file (JSON)")
    o = p.parse_args(args)
    if o.source and not glob.glob(os.path.join(o.source, "*.json")):
        p.error(f"--from {o.source}: no evaluate JSON files in it")
    return o


def _evaluate(o) -> list[str]:
    from sumo_scendiff.evaluate.__main__ import REAL_CITIES, SHARED_NETS
    out = os.path.join(os.path.dirname(os.path.abspath(o.output)), ".jsd")
    os.makedirs(out, exist_ok=True)
    files = []
    for city in REAL_CITIES:
        net, path = os.path.join(SHARED_NETS, city), os.path.join(out, city.split("/")[0] + ".json")
        if os.path.exists(net) and not os.path.exists(path):
            subprocess.run([sys.executable, "-m", "sumo_scendiff.evaluate", "-n", net, "--scenes", str(o.scenes),
                            "--json", path, *(["--checkpoint", o.checkpoint] if o.checkpoint else [])],
                           check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        files += [path] if os.path.exists(path) else []
    return files


def rows(files: list[str]) -> list[dict]:
    from sumo_scendiff.evaluate.__main__ import FLEET, FLOOR
    model = "Scenario Diffusion"
    out = []
    for path in sorted(files):
        with open(path) as f:
            for r in json.load(f)["distribution"]:
                j = r["jsd"]
                own = j.get(model + FLEET, j[model])
                row = {"network": r["net"], "fleet": "scenario's" if model + FLEET in j else "model's"}
                for k in FEATURES:
                    floor = j[FLOOR][f"jsd_{k}"]
                    ratio = own[f"jsd_{k}"] / floor if floor > 0 else (0.0 if own[f"jsd_{k}"] < 1e-9 else float("inf"))
                    row[k] = f"{own[f'jsd_{k}']:.2f} / {floor:.2f} ({ratio:.1f}×)"
                out.append(row)
    return out


def main(o) -> int:
    files = sorted(glob.glob(os.path.join(o.source, "*.json"))) if o.source else _evaluate(o)
    doc = {"command": "python benchmarks/jsd_table.py -o results/jsd.json",
           "about": "each JSD (scaled as Scenario Dreamer reports it): the model / SUMO's own floor (ratio); "
                    "the model with the scenario's fleet where the city has a demand",
           "rows": rows(files)}
    with open(o.output, "w") as f:
        json.dump(doc, f, indent=1)
    print(json.dumps(doc["rows"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
