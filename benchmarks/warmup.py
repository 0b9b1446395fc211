"""Benchmark: the warm-up (sim/warmup.py) against stock ``sumo -c CFG --end T`` of the same configuration.

    python benchmarks/warmup.py [-c CFG ...] [--after 900] [-o results/warmup.json]

For each configuration (default: every ``.sumocfg`` under ../shared/nets that SUMO loads), T = its
begin + ``--after``, side by side in one run:

* **stock**: ``sumo -c CFG --end T+step --save-state.times T`` in a subprocess (its wall time: loading
  the network, running the demand, saving the state at T; SUMO saves a state at the start of a step
  before its end), the vehicles in that state;
* **warm-up, first time**: ``start_warm(cfg, T)`` in this process (libsumo): SUMO started with the
  configuration's own step length and options, ``simulationStep(T)`` in one call, the state saved to a
  fresh cache folder and SUMO restarted from it (what ``run -c`` / ``fill -c`` pay the first time);
* **warm-up, again**: the same call, the state found in the cache (what a second run pays);
* **with the seeding's options**: SUMO started with the options the seeding adds
  (``collision.check-junctions``) and run to T in one call, nothing saved: what the warm-up costs when
  it runs the demand as the seeding's SUMO instead of as stock SUMO.

* **the demand estimate** (fill/demand.py, what ``fill --demand-estimate`` seeds from): the network read
  (sumolib) and the demand routed (duarouter) and run through the estimate's queues to T, without
  simulating; its vehicles en route at T beside SUMO's, both per km of car lane.

Stock and the first warm-up alternate ``--repeat`` times (the CPU is shared: the least of each is
kept). The ratio to stock is printed beside each (target: first time <= 1.2x stock), and the vehicles
on the network at T (fidelity: stock's). Targets are printed, not asserted.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
SHARED = os.path.join(ROOT, "..", "shared", "nets")
TARGET = 1.2


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("-c", "--configuration-file", dest="configs", action="append", default=None, metavar="CFG")
    p.add_argument("--after", type=float, default=900.0, help="T = the configuration's begin + this (s)")
    p.add_argument("--repeat", type=int, default=2, help="alternate stock and the first warm-up this often")
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="write the results as JSON here")
    return p.parse_args(args)


def state_vehicles(cfg, path: str) -> int:
    """The vehicles on the network in a saved state: SUMO started from it (libsumo) counts them."""
    from dataclasses import replace

    from sumo_scendiff.sim.sumo import close, start
    sim = start(replace(cfg, state=path))
    try:
        return sim.vehicle.getIDCount()
    finally:
        close(sim)


def stock(config: str, T: float, cfg, work: str) -> dict:
    from sumo_scendiff.core.tools import sumo_binary
    state = os.path.join(work, "stock.xml.gz")
    t = time.perf_counter()
    subprocess.run([sumo_binary("sumo"), "-c", config, "--end", f"{T + cfg.step_length:g}", "--save-state.times", f"{T:g}",
                    "--save-state.files", state, "--no-step-log", "true", "--no-warnings", "true"],
                   check=True, capture_output=True)
    return {"s": time.perf_counter() - t, "vehicles": state_vehicles(cfg, state)}


def warm(cfg, T: float, folder: str | None) -> dict:
    """start_warm into ``folder``; None: the seeding's SUMO run to T in one call, nothing saved."""
    from sumo_scendiff.sim.sumo import close, start
    from sumo_scendiff.sim.warmup import start_warm, warm_up
    t = time.perf_counter()
    if folder is None:
        sim = start(cfg)
        warm_up(sim, T)
    else:
        sim = start_warm(cfg, T, folder=folder)
    out = {"s": time.perf_counter() - t, "vehicles": sim.vehicle.getIDCount(), "at": sim.simulation.getTime()}
    close(sim)
    return out


def estimate(scen, T: float, sumo_random: tuple) -> dict:
    """The fill's demand estimate at T: (wall s, vehicles en route, car-lane km), the network's loading
    included (SUMO's warm-up includes its own); its router under ``sumo_random`` (seed, option words)."""
    import shapely

    from sumo_scendiff.fill.demand import DemandEstimate
    from sumo_scendiff.fill.tiles import car_bounds
    from sumo_scendiff.map.network import Network
    t = time.perf_counter()
    net = Network.load(scen.net)
    est = DemandEstimate.at(net, list(scen.routes), T, additional=scen.additional, sumo_random=sumo_random)
    wall = time.perf_counter() - t
    x0, y0, x1, y1 = car_bounds(net)
    return {"s": wall, "vehicles": est.vehicles, "km": net.car_lane_km_in(shapely.box(x0 - 1, y0 - 1, x1 + 1, y1 + 1))}


def bench(config: str, o, work: str) -> dict:
    from dataclasses import replace

    from sumo_scendiff.sim.scenario import own_random, scenario_from_files
    from sumo_scendiff.sim.sumo import SimConfig, step_length_for
    scen = scenario_from_files(config=config)
    T = (scen.begin or 0.0) + o.after
    # the seed stock ``sumo -c`` runs with (the configuration's, else SUMO's default), as the product's
    # warm-up and estimate take it: the three draw alike
    seed, rng = own_random(scen)
    cfg = SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional, begin=scen.begin,
                    step_length=step_length_for(scen), scenario_options=scen.options, seeding_options=False,
                    seed=seed, extra=rng)
    row = {"config": os.path.relpath(config, ROOT), "T": T, "step_length": cfg.step_length}
    for k in range(o.repeat):
        s, f = stock(config, T, cfg, work), warm(cfg, T, os.path.join(work, f"states{k}"))
        row["stock"] = min(row.get("stock", s), s, key=lambda r: r["s"])
        row["first"] = min(row.get("first", f), f, key=lambda r: r["s"])
    row["again"] = warm(cfg, T, os.path.join(work, "states0"))
    row["first_seeding_options"] = warm(replace(cfg, seeding_options=True), T, None)
    row["estimate"] = estimate(scen, T, (seed, rng))
    for k in ("first", "again", "first_seeding_options", "estimate"):
        row[k]["ratio"] = round(row[k]["s"] / row["stock"]["s"], 3)
    return row


def table(rows: list[dict]) -> str:
    out = [f"| configuration | T | step | car-lane km | stock s (veh, veh/km) | warm-up first s (veh) | ratio "
           f"(<= {TARGET}) | again s | one call, seeding options, no cache s (ratio) | demand estimate s (ratio; "
           "veh, veh/km, vs stock) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s, f, a, x, e = r["stock"], r["first"], r["again"], r["first_seeding_options"], r["estimate"]
        km = e["km"]
        held = 100.0 * (e["vehicles"] - s["vehicles"]) / max(s["vehicles"], 1)
        out.append(f"| {r['config']} | {r['T']:g} | {r['step_length']:g} | {km:.1f} | {s['s']:.2f} ({s['vehicles']}, "
                   f"{s['vehicles'] / km:.1f}) | {f['s']:.2f} ({f['vehicles']}) | {f['ratio']:.2f} "
                   f"{'ok' if f['ratio'] <= TARGET else 'MISSED'} | {a['s']:.2f} ({a['ratio']:.2f}x) | "
                   f"{x['s']:.2f} ({x['ratio']:.2f}x) | {e['s']:.2f} ({e['ratio']:.2f}x; {e['vehicles']}, "
                   f"{e['vehicles'] / km:.1f}, {held:+.0f} %) |")
    return "\n".join(out)


def default_configs() -> list[str]:
    return sorted(glob.glob(os.path.join(SHARED, "*", "*.sumocfg")))


def main(o) -> int:
    rows = []
    for config in o.configs or default_configs():
        with tempfile.TemporaryDirectory(prefix="bench-warmup-") as work:
            try:
                rows.append(bench(config, o, work))
            except Exception as e:   # a configuration SUMO refuses: said, the others go on
                print(f"{config}: {type(e).__name__}: {str(e).strip().splitlines()[-1:]}", file=sys.stderr)
    command = "python benchmarks/warmup.py " + " ".join(sys.argv[1:])
    print(table(rows))
    print(f"\n(command: {command})")
    if o.output:
        os.makedirs(os.path.dirname(os.path.abspath(o.output)), exist_ok=True)
        with open(o.output, "w") as f:
            json.dump({"command": command, "target_ratio": TARGET, "rows": rows, "table": table(rows)}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
