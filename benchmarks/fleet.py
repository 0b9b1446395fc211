"""Benchmark: are the seeded vehicles the city's own fleet? (sim/fleet.py, docs/tokens.md "vType")

    python benchmarks/fleet.py [--cities resco_cologne3 resco_ingolstadt7 wildau] [--scenes 8] [-s 0] [-o DIR]

Per city of ``../shared/nets`` with a demand: ``run`` seeds ``--scenes`` windows (``--rollout 0``);
every seeded vehicle's length and width (scene.json: its vType's) against the city's own traffic,
SUMO's vehicles present at an instant (every ``SNAPSHOT_S`` s over the demand, road motor vehicles
as the fleet counts them). The distance is Scenario Dreamer's scaled JSD: 0.1 m bins over [0, 25] m
(length) and [0, 5] m (width), squared Jensen-Shannon distance (natural log) x 100. Its floor is the
city's own sample-to-sample distance: two disjoint samples of its vehicles of the seeded sample's
size (the mean over ``DRAWS`` pairs). "drawn" is the distance of the boxes the model drew (what was
seeded before the fleet). Overlaps: pairs of boxes sharing more than OVERLAP_AREA among the seeded
vehicles and the host's around them, with the vTypes' boxes and with the drawn ones (same centres).
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys

import numpy as np
from scipy.spatial.distance import jensenshannon

HERE = os.path.dirname(os.path.abspath(__file__))
NETS = os.path.join(HERE, "..", "..", "shared", "nets")
# city -> run's scenario flags (its configuration, or network and the route file with a varied fleet)
CITIES = {"resco_cologne3": ["-c", "resco_cologne3/cologne3.sumocfg"],
          "resco_ingolstadt7": ["-c", "resco_ingolstadt7/ingolstadt7.sumocfg"],
          "wildau": ["-n", "wildau/net.net.xml.gz", "-r", "wildau/flows_SUMOV2.2.rou.xml"]}
SNAPSHOT_S = 60.0
DRAWS = 200
RANGES = {"length": 25.0, "width": 5.0}
BIN = 0.1


def scaled_jsd(a, b, hi: float) -> float:
    """Scenario Dreamer's scaled JSD of two samples: BIN-m histograms over [0, hi], squared
    Jensen-Shannon distance (natural log) x 100."""
    n = int(round(hi / BIN))

    def hist(v):   # bin by the value in BIN steps, rounded first: 1.8 m read as float32 is 1.8 m
        k = np.floor(np.round(np.asarray(v, np.float64) / BIN, 4)).astype(int)
        return np.bincount(np.clip(k, 0, n - 1), minlength=n)
    return 100.0 * float(jensenshannon(hist(a), hist(b))) ** 2


def city_traffic(flags: list[str]) -> np.ndarray:
    """(length, width) of every road motor vehicle SUMO has present, every SNAPSHOT_S s of the demand."""
    import libsumo as sim

    from sumo_scendiff.data.demand import demand_span
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.fleet import NOT_DRAWN
    from sumo_scendiff.sim.scenario import scenario_from_files
    opts = dict(zip(flags[::2], flags[1::2]))
    scen = scenario_from_files(opts.get("-c"), opts.get("-n"), [opts["-r"]] if "-r" in opts else [], [])
    net = Network.load(scen.net)
    begin, end = demand_span(scen.routes, {ln.edge for ln in net.lanes}, scen.additional,
                             begin=scen.begin, end=scen.end)
    end = min(end, begin + 3600.0)   # a flow without an end: the first hour
    sim.start(["sumo", "-n", scen.net, "-r", ",".join(scen.routes), "-b", f"{begin:g}", "--no-step-log",
               "--no-warnings"] + (["-a", ",".join(scen.additional)] if scen.additional else []))
    rows, t = [], begin
    try:
        while t < end:
            sim.simulationStep(t + SNAPSHOT_S)
            t = sim.simulation.getTime()
            for v in sim.vehicle.getIDList():
                tid = sim.vehicle.getTypeID(v)
                if sim.vehicletype.getVehicleClass(tid) not in NOT_DRAWN:
                    rows.append((sim.vehicle.getLength(v), sim.vehicle.getWidth(v)))
    finally:
        sim.close()
    return np.asarray(rows, np.float64).reshape(-1, 2)


def seeded(out: str) -> tuple[np.ndarray, np.ndarray, list[str], tuple[int, int]]:
    """From run's scene.json files: the seeded vehicles' (length, width), the drawn boxes' (length,
    width), whether each is of a scenario vType, and the overlapping pairs (vTypes', drawn)."""
    from sumo_scendiff.core.geometry import OVERLAP_AREA, Window, box_polygons
    sizes, drawn, vtypes, overlaps = [], [], [], [0, 0]
    for path in sorted(glob.glob(os.path.join(out, "scene_*", "scene.json"))):
        with open(path) as f:
            doc = json.load(f)
        w = Window(**doc["window"])
        mine = [a for a in doc["agents"] if a.get("vehicle")]
        host = [t for t in doc["tokens"] if t.get("source") != "user" and t.get("x") is not None]
        hb = np.array([[t["x"], t["y"], t["heading"], t["length"], t["width"]] for t in host]).reshape(-1, 5)
        if len(hb):
            hb[:, :2] = w.scene_to_world(hb[:, :2])
            hb[:, 2] = w.yaw_to_world(hb[:, 2])
        for k, key in enumerate(("length", "drawn_length")):
            wk = "width" if k == 0 else "drawn_width"
            b = np.array([[a["x"], a["y"], a["heading"], a.get(key, a["length"]), a.get(wk, a["width"])]
                          for a in mine]).reshape(-1, 5)
            polys = box_polygons(np.concatenate([b, hb]))
            for i in range(len(b)):
                for j in range(i + 1, len(polys)):
                    overlaps[k] += polys[i].intersection(polys[j]).area > OVERLAP_AREA
        sizes += [(a["length"], a["width"]) for a in mine]
        drawn += [(a.get("drawn_length", a["length"]), a.get("drawn_width", a["width"])) for a in mine]
        vtypes += [a.get("vtype") for a in mine]
    return np.asarray(sizes).reshape(-1, 2), np.asarray(drawn).reshape(-1, 2), vtypes, tuple(overlaps)


def measure(city: str, flags: list[str], o) -> dict:
    out = os.path.join(o.out, city)
    if not glob.glob(os.path.join(out, "scene_*", "scene.json")):
        cmd = [sys.executable, "-m", "sumo_scendiff.run", *[os.path.join(NETS, f) if f.startswith(city) else f
                                                            for f in flags],
               "--scenes", str(o.scenes), "--rollout", "0", "-s", str(o.seed), "-o", out, "--force"]
        subprocess.run(cmd, check=True, cwd=os.path.join(HERE, ".."))
    sizes, drawn, vtypes, overlaps = seeded(out)
    pool = city_traffic([os.path.join(NETS, f) if f.startswith(city) else f for f in flags])
    rng = np.random.default_rng(o.seed)
    n = len(sizes)
    kinds, counts = np.unique(np.round(pool, 2), axis=0, return_counts=True)
    print(f"{city}: its traffic's sizes (length, width: share) "
          + ", ".join(f"{a:g}x{b:g}: {c / len(pool):.3f}" for (a, b), c in zip(kinds, counts)), file=sys.stderr)
    row = {"city": city, "seeded": n, "of_scenario_vtypes": sum(v is not None for v in vtypes),
           "city_pool": len(pool), "overlaps": overlaps[0], "overlaps_drawn": overlaps[1]}
    for k, (name, hi) in enumerate(RANGES.items()):
        floor, fleet, model = [], [], []
        for _ in range(DRAWS):
            pick = rng.choice(len(pool), 2 * n, replace=len(pool) < 2 * n)
            a, b = pool[pick[:n], k], pool[pick[n:], k]
            floor.append(scaled_jsd(a, b, hi))
            fleet.append(scaled_jsd(sizes[:, k], a, hi))
            model.append(scaled_jsd(drawn[:, k], a, hi))
        row[name] = {"floor": float(np.mean(floor)), "seeded": float(np.mean(fleet)), "drawn": float(np.mean(model))}
    return row


def main(args=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cities", nargs="+", default=list(CITIES), choices=list(CITIES))
    p.add_argument("--scenes", type=int, default=8)
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--out", default="runs/bench_fleet", help="run's output folders (reused when there)")
    o = p.parse_args(args)
    print("| city | seeded | of its vTypes | length JSD seeded / floor / drawn | width JSD seeded / floor / drawn "
          "| overlapping pairs (vTypes / drawn) |")
    print("|---|---|---|---|---|---|")
    for city in o.cities:
        r = measure(city, CITIES[city], o)
        ln, wd = r["length"], r["width"]
        print(f"| {city} | {r['seeded']} | {r['of_scenario_vtypes']} | {ln['seeded']:.3f} / {ln['floor']:.3f} / "
              f"{ln['drawn']:.2f} | {wd['seeded']:.3f} / {wd['floor']:.3f} / {wd['drawn']:.2f} | "
              f"{r['overlaps']} / {r['overlaps_drawn']} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
