"""A fill's density against SUMO's own edgeData: `fill --density D` on each network, then stock SUMO's
edgeData over every normal edge for the first second of the filled start, each edge's `density` times
its length over the network's car-lane km (docs/sumo-options.md, "A density in vehicles per km").

    python benchmarks/density_edgedata.py                          # the grids, berlin, cologne3 at 20
    python benchmarks/density_edgedata.py -n networks/city.net.xml --density 30 -o results/density_edgedata.json
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

NETS = ("networks/grid3x3_1lane.net.xml", "networks/grid4x4_2lane_tls.net.xml",
        "../shared/nets/berlin_doerpfeldstr/net.net.xml.gz", "../shared/nets/resco_cologne3/cologne3.net.xml")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-n", "--net-file", dest="nets", action="append", help="network (repeatable; default: "
                   + ", ".join(NETS) + ")")
    p.add_argument("--density", type=float, default=20.0, help="veh/km asked of the fill")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", help="write the rows as JSON here")
    return p.parse_args(args)


def measure(net_path: str, density: float, seed: int, work: str) -> dict:
    """One fill and SUMO's edgeData over its first second."""
    import sumolib
    from sumolib.xml import parse

    from sumo_scendiff.core.tools import sumo_binary
    out, ed = os.path.join(work, "filled"), os.path.join(work, "ed.xml")
    subprocess.run([sys.executable, "-m", "sumo_scendiff.fill", "-n", net_path, "--density", f"{density:g}",
                    "-s", str(seed), "-o", out], check=True, capture_output=True)
    with open(os.path.join(out, "fill.json")) as f:
        doc = json.load(f)
    begin = doc["state_time"]
    subprocess.run([sumo_binary("sumo"), "-c", os.path.join(out, "scenario.sumocfg"), "--edgedata-output", ed,
                    "-e", f"{begin + 1:g}", "--no-step-log", "true", "--no-warnings", "true"], check=True)
    net = sumolib.net.readNet(net_path)
    car_km = sum(ln.getLength() for e in net.getEdges(withInternal=False) for ln in e.getLanes()
                 if ln.allows("passenger")) / 1000.0
    (interval,) = list(parse(ed, "interval"))
    # an edge's density is per km of the edge (all its lanes): times its length, its vehicles
    vehicles = sum(float(e.density) * net.getEdge(e.id).getLength() / 1000.0 for e in interval.edge if e.density)
    return {"network": net_path, "asked": density, "car_lane_km": round(car_km, 3),
            "seeded": doc["summary"]["vehicles"], "edgedata": round(vehicles / car_km, 2),
            "error": round(vehicles / car_km / density - 1.0, 4)}


def main(options) -> int:
    from tqdm import tqdm
    rows = []
    for net in tqdm(options.nets or NETS, desc="fills"):
        with tempfile.TemporaryDirectory(prefix="density-edgedata-") as work:
            rows.append(measure(net, options.density, options.seed, work))
    print("| network | car-lane km | seeded | edgeData veh/km | vs asked |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['network']} | {r['car_lane_km']} | {r['seeded']} | {r['edgedata']} | {100 * r['error']:+.1f} % |")
    if options.output:
        with open(options.output, "w") as f:
            json.dump({"seed": options.seed, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
