"""The fill's demand estimate (fill/demand.py, its clock fill/travel.py) against SUMO running the demand.

    python experiments/demand_clock.py                      # the seven real cities with demand
    python experiments/demand_clock.py --generated          # held-out generated networks, randomTrips
    python experiments/demand_clock.py --generated --density 30,90 --seed 1

For each network SUMO (libsumo) runs the demand from its begin; every --every s from begin + --from
to begin + --to it counts the vehicles on the network, and the estimate is taken for the same time
from the route files alone. Printed per network: the mean counts and their ratio (SUMO's / the
estimate's), the range of the per-time ratio, how many times the estimate is within ±10 % of
SUMO's count, and the mean per-edge Spearman. Settings of the clock are chosen on --generated (the
project's held-out networks, the recorder's vTypes), and reported on the real cities.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
SHARED = os.path.join(ROOT, "..", "shared", "nets")
REAL = [("resco_cologne1/cologne1.sumocfg", None), ("resco_cologne3/cologne3.sumocfg", None),
        ("resco_cologne8/cologne8.sumocfg", None), ("resco_ingolstadt1/ingolstadt1.sumocfg", None),
        ("resco_ingolstadt7/ingolstadt7.sumocfg", None), ("resco_ingolstadt21/ingolstadt21.sumocfg", None),
        ("berlin_doerpfeldstr/scenario.sumocfg", "berlin_doerpfeldstr/samplertrips.rou.xml")]
HELD_OUT = ["arterial_tls", "city", "grid5x5_jitter", "random_sparse"]   # networks/splits.json's val


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--generated", action="store_true", help="the held-out generated networks with random trips")
    p.add_argument("--density", default="30,90", help="randomTrips insertion densities, veh/h per km of lane")
    p.add_argument("--from", dest="t0", type=float, default=600.0, help="s after the demand's begin")
    p.add_argument("--to", dest="t1", type=float, default=1500.0)
    p.add_argument("--every", type=float, default=60.0)
    p.add_argument("-s", "--seed", type=int, default=1)
    return p.parse_args(args)


def cases(o, work: str):
    """(name, network, route files, additional files, begin, SUMO's seed and random options) per
    network to compare: the seed the user's own ``sumo -c`` runs the demand with (sim.scenario.own_random),
    as the fill's estimate and its SUMO run take it."""
    from sumo_scendiff.data.demand import RandomDemand, check_demand, random_trips, write_vtypes
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.sim.scenario import SUMO_DEFAULT_SEED, own_random, scenario_from_files
    if o.generated:
        vtypes = write_vtypes(os.path.join(work, "vtypes.add.xml"))
        for name in HELD_OUT:
            path = os.path.join(ROOT, "networks", f"{name}.net.xml")
            for d in (float(x) for x in o.density.split(",")):
                routes = random_trips(path, os.path.join(work, f"{name}_{d:g}.rou.xml"),
                                      RandomDemand(d, o.t1 + 300.0, o.seed))
                # no configuration: stock ``sumo -n -r`` runs these trips under SUMO's default seed
                yield f"{name} at {d:g}", Network.load(path), [routes], [vtypes], 0.0, (SUMO_DEFAULT_SEED, ())
        return
    for cfg, extra in REAL:
        if not os.path.exists(os.path.join(SHARED, cfg)):
            continue
        scen = scenario_from_files(os.path.join(SHARED, cfg), None,
                                   [os.path.join(SHARED, extra)] if extra else [], [])
        net = Network.load(scen.net)
        begin = scen.begin if scen.begin is not None else math.floor(
            check_demand(list(scen.routes), {ln.edge for ln in net.lanes}, scen.additional))
        yield cfg.split("/")[0], net, list(scen.routes), list(scen.additional), begin, own_random(scen)


def compare(net, routes, additional, begin: float, sumo_random: tuple, o) -> dict:
    from scipy.stats import spearmanr

    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    seed, rng = sumo_random       # SUMO's run and the estimate's router draw alike
    sim = start(SimConfig(net=net.path, routes=tuple(routes), additional=tuple(additional), begin=begin,
                          seed=seed, extra=rng))
    sumo, est, rho = [], [], []
    try:
        for t in np.arange(begin + o.t0, begin + o.t1 + 1e-6, o.every):
            sim.simulationStep(float(t))
            sumo.append(sim.vehicle.getIDCount())
            on: dict[str, int] = {}
            for v in sim.vehicle.getIDList():
                road = sim.vehicle.getRoadID(v)
                if road and not road.startswith(":"):
                    on[road] = on.get(road, 0) + 1
            e = DemandEstimate.at(net, routes, float(t), additional=additional, sumo_random=sumo_random)
            est.append(e.vehicles)
            keys = sorted(set(on) | set(e.on_edge))
            if len(keys) > 2:
                rho.append(spearmanr([on.get(k, 0) for k in keys], [e.on_edge.get(k, 0) for k in keys]).statistic)
    finally:
        close(sim)
    s, e = np.array(sumo, float), np.maximum(np.array(est, float), 1e-9)
    return {"sumo": s.mean(), "est": e.mean(), "ratio": s.mean() / e.mean(), "lo": (s / e).min(),
            "hi": (s / e).max(), "within": int((np.abs(e / np.maximum(s, 1e-9) - 1) <= 0.1).sum()), "n": len(s),
            "rho": float(np.nanmean(rho)) if rho else float("nan")}


def main(o) -> int:
    from tqdm import tqdm
    print("| network | SUMO's mean count | estimate's | ratio | per-time ratio | within ±10 % | per-edge Spearman |")
    print("|---|---|---|---|---|---|---|")
    within = total = 0
    with tempfile.TemporaryDirectory(prefix="scendiff-clock-") as work:
        for name, net, routes, additional, begin, sumo_random in tqdm(list(cases(o, work)), unit="net", file=sys.stderr):
            r = compare(net, routes, additional, begin, sumo_random, o)
            within, total = within + r["within"], total + r["n"]
            print(f"| {name} | {r['sumo']:.1f} | {r['est']:.1f} | {r['ratio']:.2f} | {r['lo']:.2f}…{r['hi']:.2f} | "
                  f"{r['within']} / {r['n']} | {r['rho']:.2f} |", flush=True)
    print(f"\nwithin ±10 %: {within} of {total} times")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
