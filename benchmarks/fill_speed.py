"""Benchmark: what the whole-network fill costs, against an older fill and against stock SUMO reaching
the same number of vehicles: ``python benchmarks/fill.py --speed`` (fill.py's options and command line;
this module is its ``--speed`` part).

    python benchmarks/fill.py --speed [-n NET ...] [--density 25] [--before SRC] [--repeat N] [--json FILE]

Default networks: SPEED_NETS. The fill CLI at its defaults, ``-n NET --density D`` (wall time of the
whole process, CPU time of it and its worker processes, per km of car lane), beside the same fill from
another source tree (``--before``: a checkout's folder holding ``sumo_scendiff/``, alternated with this
one ``--repeat`` times, the faster of each kept), and beside stock SUMO reaching the same number:
``randomTrips.py --validate`` (duarouter) inserting the fill's vehicles over 60 s (2 a second at
least), then SUMO (libsumo, ``--step-length``) until that many stand on normal lanes (checked every
10 s). The fill's quality beside it: veh/km as edgeData counts it, placed share, overlapping boxes
(pairs).

A benchmark of its own beside fill.py's quality benchmark: it runs no demand, no SUMO warm-up and no
check of the fill's folder in SUMO, only the two ways to a filled network, timed.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fill import ROOT, overlaps  # noqa: E402  (the quality benchmark's overlap count)
from fill_tables import _f  # noqa: E402  (and its table cells)

SPEED_NETS = ("networks/grid4x4_2lane_tls.net.xml", "networks/city.net.xml")
RT_INSERT_S = 60.0    # randomTrips inserts the fill's number of vehicles over this many seconds,
RT_MIN_RATE = 2.0     # ... and at least this many a second (short trips leave as fast as they come)
RT_LIMIT_S = 900.0    # ... and SUMO runs until the network holds them, or this long


def timed(cmd: list[str], env: dict | None = None, cwd: str = ROOT) -> tuple[subprocess.CompletedProcess, float, float]:
    """``cmd`` run to its end in ``cwd``: (the process, wall s, CPU s of it and its children)."""
    import resource
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    done = subprocess.run(cmd, check=False, cwd=cwd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t
    after_ = resource.getrusage(resource.RUSAGE_CHILDREN)
    return done, wall, (after_.ru_utime - before.ru_utime) + (after_.ru_stime - before.ru_stime)


def speed_fill(net: str, src: str | None, folder: str, o) -> dict:
    """The fill CLI at its defaults (--density) from source tree ``src`` (None: this one)."""
    env = {**os.environ, "PYTHONPATH": os.path.abspath(src)} if src else None
    cmd = [sys.executable, "-m", "sumo_scendiff.fill", "-n", os.path.join(ROOT, net), "--density", f"{o.density:g}",
           "-s", str(o.seed), "-o", os.path.abspath(folder), "--force"] + (["-q"] if src is None else [])
    # `python -m` puts its working directory first on sys.path, ahead of PYTHONPATH: the older tree's
    # package is imported only when run from there
    done, wall, cpu = timed(cmd, env, cwd=os.path.abspath(src) if src else ROOT)
    if done.returncode != 0:
        return {"error": (done.stderr or done.stdout).strip().splitlines()[-1:]}
    with open(os.path.join(folder, "fill.json")) as f:
        doc = json.load(f)
    s = doc["summary"]
    boxes = {a["vehicle"]: (a["x"], a["y"], a["heading"], a["length"], a["width"])
             for a in doc["agents"] if a["vehicle"]}
    return {"wall_s": wall, "cpu_s": cpu, "km": s["car_lane_km"], "tiles": s["tiles"], "vehicles": s["vehicles"],
            "veh_per_km": s["density_veh_per_km"], "placed_pct": 100.0 * s["placed"] / max(s["kept"], 1),
            "overlaps": overlaps(boxes), "timing_s": doc["timing_s"], "workers": (doc.get("workers") or {}).get("count")}


def on_lanes(sim) -> int:
    """Vehicles on normal lanes (as the fill's density counts them, junctions aside)."""
    return sum(not sim.vehicle.getRoadID(v).startswith(":") for v in sim.vehicle.getIDList())


def random_trips_side(net: str, km: float, vehicles: int, work: str, o) -> dict:
    """randomTrips.py (duarouter-validated) at the rate that inserts ``vehicles`` in RT_INSERT_S
    (RT_MIN_RATE at least), then SUMO (libsumo, the product's step) until that many stand on the network's normal lanes."""
    from sumo_scendiff.core.tools import sumo_home, sumo_tool
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    trips = os.path.join(work, "rt.trips.xml")
    period = min(RT_INSERT_S / max(vehicles, 1), 1.0 / RT_MIN_RATE)
    cmd = [sys.executable, sumo_tool("randomTrips.py"), "-n", os.path.abspath(net), "-o", trips, "-r",
           os.path.join(work, "rt.rou.xml"), "-e", f"{RT_LIMIT_S:g}", "-p", f"{period:.4f}", "--seed", str(o.seed),
           "--vehicle-class", "passenger", "--edge-permission", "passenger", "--validate"]
    done, wall_rt, cpu_rt = timed(cmd, {**os.environ, "SUMO_HOME": sumo_home()})
    if done.returncode != 0:
        return {"error": (done.stderr or done.stdout).strip().splitlines()[-1:]}
    t0, c0 = time.perf_counter(), time.process_time()
    sim = start(SimConfig(net=net, routes=(os.path.join(work, "rt.rou.xml"),), step_length=o.step_length,
                          seed=o.seed, begin=0.0, seeding_options=False))
    try:
        n = 0
        while sim.simulation.getTime() < RT_LIMIT_S and n < vehicles:
            sim.simulationStep(sim.simulation.getTime() + 10.0)   # checked every 10 s of simulation
            n = on_lanes(sim)
        at = sim.simulation.getTime()
    finally:
        close(sim)
    wall_sumo, cpu_sumo = time.perf_counter() - t0, time.process_time() - c0
    return {"wall_s": wall_rt + wall_sumo, "cpu_s": cpu_rt + cpu_sumo, "random_trips_s": wall_rt,
            "sumo_s": wall_sumo, "simulated_s": at, "vehicles": n, "veh_per_km": n / km, "reached": n >= vehicles}


def speed_row(net: str, work: str, o) -> dict:
    row = {"net": os.path.relpath(net, ROOT)}
    for k in range(o.repeat):     # alternated: the CPU is shared, each side sees the same load
        for side, src in (("before", o.before), ("after", None)):
            if side == "before" and not src:
                continue
            r = speed_fill(net, src, os.path.join(work, f"{side}{k}"), o)
            if side not in row or r.get("wall_s", 1e9) < row[side].get("wall_s", 1e9):
                row[side] = r
    a = row["after"]
    if "error" not in a:
        target = int(round(a["veh_per_km"] * a["km"]))
        row["random_trips"] = random_trips_side(net, a["km"], target, work, o)
    return row


def speed_table(rows: list[dict], o) -> str:
    out = [f"| network | car-lane km | side | wall s | s / km | CPU s / km | veh/km (asked {o.density:g}) | "
           "placed | overlaps | split (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for side in ("before", "after", "random_trips"):
            v = r.get(side)
            if v is None:
                continue
            if "error" in v:
                out.append(f"| {r['net']} | | {side} | failed: {v['error']} | | | | | | |")
                continue
            km = r["after"].get("km") or v.get("km") or float("nan")
            name = {"before": "fill, --before", "after": f"fill ({v.get('workers')} workers)",
                    "random_trips": "randomTrips + SUMO"}[side]
            split = (", ".join(f"{k} {x:g}" for k, x in v["timing_s"].items()) if "timing_s" in v else
                     f"randomTrips {v['random_trips_s']:.1f}, SUMO {v['sumo_s']:.1f} to t = {v['simulated_s']:g} s"
                     + ("" if v["reached"] else " (never reached it)"))
            out.append(f"| {r['net']} | {km:.1f} | {name} | {v['wall_s']:.1f} | {v['wall_s'] / km:.2f} | "
                       f"{v['cpu_s'] / km:.2f} | {v['veh_per_km']:.1f} | "
                       f"{_f(v.get('placed_pct'), '{:.1f} %')} | {v.get('overlaps', '–')} | {split} |")
    return "\n".join(out)


def speed_main(o, command: str) -> int:
    rows = []
    with tempfile.TemporaryDirectory(prefix="scendiff-bench-speed-") as work:
        for net in o.nets or [os.path.join(ROOT, n) for n in SPEED_NETS]:
            d = os.path.join(work, os.path.basename(net))
            os.makedirs(d)
            rows.append(speed_row(os.path.abspath(net), d, o))
            print(speed_table(rows[-1:], o).splitlines()[-1], file=sys.stderr, flush=True)
    text = f"Command: `{command}`\n\n" + speed_table(rows, o) + "\n"
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from report import emit
    emit(text, o.output, "Fill speed")
    if o.json:
        os.makedirs(os.path.dirname(os.path.abspath(o.json)), exist_ok=True)
        with open(o.json, "w") as f:
            json.dump({"command": command, "density": o.density, "rows": rows, "table": speed_table(rows, o)},
                      f, indent=1)
    return 0
