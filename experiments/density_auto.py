"""Experiment: `run -c scenario.sumocfg --density auto` on real cities with their own demand.

    python experiments/density_auto.py [--checkpoint PATH] [--scenes 8] [--begin 600]

For every scenario of ../shared/nets with a .sumocfg (or ``-c`` given), ``run`` seeds ``--scenes``
busy windows at the level of the demand's own traffic around them (``--density auto``) and reports,
per window, SUMO's own vehicles there (kept), the vehicles after seeding (kept + generated) and the
auto target. The issue's measure: vehicles after seeding against SUMO's own in the same windows at the
same time, window by window median of the ratio.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-c", "--configuration-file", dest="configs", action="append")
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--scenes", type=int, default=8)
    p.add_argument("--begin", type=float, default=600.0)
    p.add_argument("-s", "--seed", type=int, default=0)
    return p.parse_args(args)


def main(o) -> int:
    configs = o.configs or sorted(glob.glob(os.path.join(ROOT, "..", "shared", "nets", "*", "*.sumocfg")))
    print("| scenario | windows | SUMO's own (median) | after seeding (median) | ratio after / own (median) "
          "| auto target veh/km (median) |")
    print("|---|---|---|---|---|---|")
    for cfg in configs:
        with tempfile.TemporaryDirectory() as out:
            cmd = [sys.executable, "-m", "sumo_scendiff.run", "-c", cfg, "--density", "auto", "--scenes",
                   str(o.scenes), "--rollout", "0", "--begin", f"{o.begin:g}", "-s", str(o.seed), "-o", out]
            if o.checkpoint:
                cmd += ["--checkpoint", o.checkpoint]
            res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
            name = os.path.basename(cfg)
            if res.returncode:
                print(f"| {name} | – | – | – | – | {res.stderr.strip().splitlines()[-1]} |")
                continue
            rows = json.load(open(os.path.join(out, "run.json")))["scenes"]
        own = np.array([r["existing_vehicles"] for r in rows], float)
        after = np.array([r["vehicles_in_window"] for r in rows], float)
        target = [r["target_veh_per_km"] for r in rows if r.get("target_veh_per_km") is not None]
        ratio = after[own > 0] / own[own > 0]
        print(f"| {name} | {len(rows)} | {np.median(own):.1f} | {np.median(after):.1f} | "
              f"{np.median(ratio) if len(ratio) else float('nan'):.2f} | "
              f"{np.median(target) if target else float('nan'):.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
