"""Benchmark: the whole-network fill (``python -m sumo_scendiff.fill``) against SUMO's own warm-up --
vehicles, where they are, what happens next, and what it costs.

    python benchmarks/fill.py [-n NET ...] [--warmup 600] [--hold 1800] [--density 25] [-s 0] [-o FILE]
    python benchmarks/fill.py -n ../shared/nets/resco_cologne1/cologne1.net.xml --hold 120   # a minute
    python benchmarks/fill.py -n networks/city.net.xml --density 25 --hold 300

Default networks: every real city under ../shared/nets with demand beside its network
(``benchmarks/seeding.py``'s list and wildau; ``data.demand.find_demand``), and networks/city.net.xml
with ``--density``.

**With demand** (a city): its inputs are those of the ``.sumocfg`` beside the network (route files it
names that are missing are replaced by ``find_demand``'s; no usable configuration: ``-n``/``-r``). The
start is T = the demand's begin (the configuration's, else its first departure, on the step grid) +
``--warmup`` s, given to the fill as ``--begin T``.

* **SUMO's own** (libsumo, the fill's SUMO options): the demand from its begin to T (the warm-up's wall
  time); at T the vehicles on the network (and the least and most of them over the 30 s before T,
  how far the count swings with the lights' cycles), their per-edge counts and boxes; 60 s on, counting the
  collisions and teleports of the vehicles present at T (``sim.rollout``, per 100 of them); the
  per-edge counts at T + 120 s (the *floor*: Spearman of SUMO's own counts at T against its own two
  minutes later, how far a correct state can differ); the vehicles on the network at T + ``--hold``.
* **Fill**: the real CLI in a subprocess (``-c CFG --begin T -o DIR -s SEED``; its wall time measured),
  fill.json read, then stock SUMO (libsumo) on ``DIR/scenario.sumocfg`` (the saved state, the demand
  continuing): vehicles at start, Spearman of the per-edge counts against SUMO's own at T (over the
  edges with a vehicle in either; junction-internal edges left out), the same 60-s counts for the
  vehicles present at start, vehicles at T + hold. ``DIR/start.sumocfg`` (the portable start) is
  stepped once (its vehicles depart at T): how many of the fill's vehicles are there and the share of
  fill.json's vehicles whose box centre is within 0.5 m of their fill.json pose (the saved state's
  share beside it), and its collisions / teleports in 60 s; boxes overlapping (shapely, intersection
  > 0.001 m^2, pairs) at start for all.
* **The demand estimate** (``--estimate``): the same again with ``--demand-estimate`` (the model's fill
  from the estimate of the demand's vehicles at T, fill/demand.py) beside the default (SUMO's own run
  to T, fill/warm_start.py), each with its table and cost row; SUMO's states are timed the first time
  (a fresh cache folder).
* **Cost**: the fill's wall time (the whole CLI process, model loading included; fill.json's
  ``timing_s`` in brackets) per km of car lane (fill.json ``summary.car_lane_km``, the tiles' cores)
  beside the wall time of SUMO's warm-up.

**Without demand** (``--density D``): fill ``-n NET --density D``; the filled density (vehicles per km
of car lane) against the request, then ``scenario.sumocfg`` with the fill's ``inflow.rou.xml`` for
``--hold`` s and the density then; the same portable start and 60-s checks.

**Speed** (``--speed [--before SRC] [--repeat N] [--json FILE]``): the cost alone, the fill against
an older fill's and against randomTrips + SUMO reaching the same veh/km: benchmarks/fill_speed.py.

Targets are printed beside the figures, not asserted: vehicles within +-10 % of SUMO's at T; Spearman
>= SUMO's own T vs T + 120 s floor; first-60-s collisions and teleports per 100 <= SUMO's own; at
T + hold within +-15 % of SUMO's; the portable start has the state's count and >= 99 % within 0.5 m;
density within +-10 % of the request and +-15 % of it after the hold.

SUMO runs in this process one after another (libsumo; no torch here: the fill is a subprocess). A
loaded state's steps in libsumo depend on memory layout (see benchmarks/seeding.py), so the fill's
rollout counts can move by an event between runs; the warm-ups from scratch repeat exactly. The fill
folders go to a temporary directory, or under ``--keep DIR``. Prints markdown tables (``-o``: writes
them too); a fill that fails is reported with its command and last error line, the others continue.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
SHARED = os.path.join(ROOT, "..", "shared", "nets")
CITY = os.path.join(ROOT, "networks", "city.net.xml")
EXTRA = ("--ignore-route-errors", "true")   # as benchmarks/seeding.py; SUMO skips an unroutable trip

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
# what the tables report, and Spearman (tests/test_benchmarks_fill.py reaches it here)
from fill_tables import FLOOR, NEAR, ROLLOUT, SPREAD, spearman, tables  # noqa: E402,F401


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("-n", "--net-file", "--net", dest="nets", action="append", default=None, metavar="NET",
                   help="network (repeat); default: the real cities with demand + networks/city.net.xml")
    p.add_argument("--warmup", type=float, default=600.0, help="s of demand before the start T (fill's default)")
    p.add_argument("--hold", type=float, default=1800.0, help=f"s after T for the later count (>= {ROLLOUT:g})")
    p.add_argument("--density", type=float, default=25.0, help="veh/km of car lane asked of a net without demand")
    p.add_argument("--step-length", type=float, default=0.5)
    p.add_argument("--checkpoint", default=None, help="model checkpoint for the fill (default: the shipped one)")
    p.add_argument("--keep", default=None, metavar="DIR", help="keep the fill folders under DIR/<net>")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="also write the tables here")
    p.add_argument("--speed", action="store_true",
                   help="the cost table alone, without demand: the fill at --density against --before's and "
                        "against randomTrips + SUMO reaching the same veh/km (benchmarks/fill_speed.py)")
    p.add_argument("--before", default=None, metavar="SRC",
                   help="with --speed: a source tree (holding sumo_scendiff/) whose fill runs beside this one")
    p.add_argument("--repeat", type=int, default=1, help="with --speed: alternate the sides this often")
    p.add_argument("--json", default=None, metavar="FILE", help="with --speed: the rows as JSON here")
    p.add_argument("--estimate", action="store_true",
                   help="with demand: also the fill from the demand estimate (--demand-estimate) beside the "
                        "default, SUMO's own run to T")
    o = p.parse_args(args)
    if o.hold < ROLLOUT:
        p.error(f"--hold must be >= {ROLLOUT:g} s (the collision count runs that long)")
    if o.warmup < 0 or o.density <= 0 or o.step_length <= 0:
        p.error("--warmup must be >= 0, --density and --step-length > 0")
    return o


# beyond the hand-off benchmark's cities: wildau's OSM demand (54 km of car lane, no .sumocfg)
MORE = ("wildau/net.net.xml.gz",)


def default_nets() -> list[str]:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from seeding import REAL
    return [os.path.normpath(os.path.join(SHARED, r)) for r in REAL + MORE
            if os.path.exists(os.path.join(SHARED, r))] + [CITY]


# ---- inputs --------------------------------------------------------------------------------------
def inputs(net) -> tuple[list[str], object | None]:
    """(the fill's input flags, SumoScenario or None without demand) for a loaded network: a
    ``.sumocfg`` beside it naming it (missing route files replaced by find_demand's), else -n/-r."""
    from sumo_scendiff.data.demand import find_demand
    from sumo_scendiff.sim.scenario import ScenarioError, scenario_from_files
    path = os.path.abspath(net.path)
    routes = find_demand(net)
    for cfg in sorted(glob.glob(os.path.join(os.path.dirname(path), "*.sumocfg"))):
        for r in ([], [routes]) if routes else ([],):
            try:
                scen = scenario_from_files(cfg, routes=r)
            except ScenarioError:
                continue
            if os.path.abspath(scen.net) == path and scen.routes:
                return ["-c", cfg] + (["-r", r[0]] if r else []), scen
    if routes:
        return ["-n", path, "-r", routes], scenario_from_files(net=path, routes=[routes])
    return ["-n", path], None


# ---- what SUMO shows ----------------------------------------------------------------------------
def launch(args: list[str]):
    import libsumo

    from sumo_scendiff.core.tools import sumo_binary
    libsumo.start([sumo_binary("sumo")] + list(args) + list(EXTRA) + ["--no-warnings", "true"])
    return libsumo


def snapshot(sim) -> dict:
    """Vehicles on the network now: per normal edge their count, per vehicle its box (cx, cy, yaw, l, w),
    and how many wait to enter (loaded, their departure due, not inserted)."""
    from sumo_scendiff.core.geometry import sumo_to_pose
    ids = list(sim.vehicle.getIDList())
    edges = Counter(e for e in map(sim.vehicle.getRoadID, ids) if not e.startswith(":"))
    boxes = {}
    for v in ids:
        x, y = sim.vehicle.getPosition(v)
        length = sim.vehicle.getLength(v)
        cx, cy, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(v), length)
        boxes[v] = (float(cx), float(cy), float(yaw), length, sim.vehicle.getWidth(v))
    return {"n": len(ids), "edges": edges, "boxes": boxes, "waiting": len(sim.simulation.getPendingVehicles())}


def overlaps(boxes: dict) -> int:
    """Pairs of vehicle boxes that overlap (intersection > 0.001 m^2)."""
    import numpy as np
    import shapely

    from sumo_scendiff.core.geometry import box_corners
    if len(boxes) < 2:
        return 0
    b = np.array(list(boxes.values()))
    polys = shapely.polygons(box_corners(*b.T))
    i, j = shapely.STRtree(polys).query(polys, predicate="intersects")
    keep = i < j
    return int((shapely.area(shapely.intersection(polys[i[keep]], polys[j[keep]])) > 1e-3).sum())


def after(sim, t0: float, o, marks: dict) -> dict:
    """From ``t0``: the 60-s rollout of the vehicles present, then snapshots at t0 + each of ``marks``."""
    from sumo_scendiff.sim.rollout import rollout
    r = rollout(sim, list(sim.vehicle.getIDList()), ROLLOUT)
    out = {"collisions": r.per_100("collisions"), "teleports": r.per_100("teleports"),
           "collision_events": r.collisions, "teleport_events": r.teleports}
    for name, dt in sorted(marks.items(), key=lambda kv: kv[1]):
        if sim.simulation.getTime() < t0 + dt - 1e-6:
            sim.simulationStep(t0 + dt)
        out[name] = snapshot(sim)
    return out


def sumo_own(scen, begin: float, T: float, o) -> dict:
    from sumo_scendiff.sim.sumo import SimConfig, close, start
    cfg = SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional, step_length=o.step_length,
                    seed=o.seed, begin=begin, extra=EXTRA, scenario_options=scen.options)
    sim = start(cfg)
    try:
        t = time.perf_counter()
        sim.simulationStep(max(begin, T - SPREAD))
        near = [sim.vehicle.getIDCount()]
        while sim.simulation.getTime() < T - 1e-6:   # the count's own swing just before T
            sim.simulationStep(min(T, sim.simulation.getTime() + 1.0))
            near.append(sim.vehicle.getIDCount())
        wall = time.perf_counter() - t
        at = snapshot(sim)
        return {"wall": wall, "at": at, "overlaps": overlaps(at["boxes"]), "spread": (min(near), max(near)),
                **after(sim, T, o, {"floor": FLOOR, "hold": o.hold})}
    finally:
        close(sim)


def near_share(snap: dict, poses: dict) -> float:
    """Share of fill.json's vehicles whose box centre is within NEAR m of their fill.json pose."""
    near = sum(1 for v, (x, y) in poses.items() if v in snap["boxes"]
               and math.hypot(snap["boxes"][v][0] - x, snap["boxes"][v][1] - y) <= NEAR)
    return 100.0 * near / len(poses) if poses else float("nan")


def fill_side(folder: str, doc: dict, T: float, o) -> dict:
    """Stock SUMO on the fill's folder: scenario.sumocfg (the state) and start.sumocfg (portable)."""
    from sumo_scendiff.sim.rollout import rollout
    from sumo_scendiff.sim.sumo import close
    poses = {a["vehicle"]: (a["x"], a["y"]) for a in doc["agents"] if a["vehicle"]}
    sim = launch(["-c", os.path.join(folder, "scenario.sumocfg")])
    try:
        at = snapshot(sim)
        res = {"at": at, "overlaps": overlaps(at["boxes"]), "near": near_share(at, poses),
               **after(sim, T, o, {"hold": o.hold})}
    finally:
        close(sim)
    sim = launch(["-c", os.path.join(folder, "start.sumocfg")])
    try:
        sim.simulationStep()                   # the departures at T enter where they stand
        snap = snapshot(sim)
        mine = {v: b for v, b in snap["boxes"].items() if v in poses}
        roll = rollout(sim, list(mine), ROLLOUT)
        res["portable"] = {"n": len(mine), "near": near_share(snap, poses), "overlaps": overlaps(mine),
                           "state_n": sum(v in poses for v in at["boxes"]), "collisions": roll.collisions,
                           "teleports": roll.teleports}
    finally:
        close(sim)
    return res


def run_fill(flags: list[str], folder: str, o) -> tuple[dict | None, float, str]:
    """The fill CLI into ``folder``: (fill.json or None, wall time, the command / its error)."""
    cmd = [sys.executable, "-m", "sumo_scendiff.fill", *flags, "-s", str(o.seed), "--step-length",
           f"{o.step_length:g}", "-o", folder, "--force"] + (["--checkpoint", o.checkpoint] if o.checkpoint else [])
    shown = " ".join("DIR" if c == folder else os.path.relpath(c, ROOT) if os.path.isabs(c) else c
                     for c in ["python"] + cmd[1:])
    t = time.perf_counter()
    done = subprocess.run(cmd, check=False, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        err = (done.stderr or done.stdout).strip().splitlines()
        return None, wall, f"`{shown}` exited {done.returncode}: {err[-1] if err else ''}"
    with open(os.path.join(folder, "fill.json")) as f:
        return json.load(f), wall, shown


def bench_net(path: str, o, work: str, bar) -> dict | None:
    from sumo_scendiff.data.demand import check_demand
    from sumo_scendiff.map.network import Network
    net = Network.load(path)
    flags, scen = inputs(net)
    if scen is None and o.nets is None and os.path.abspath(path) != os.path.abspath(CITY):
        print(f"{net.name}: no demand beside the net, skipped", file=sys.stderr)
        return None
    r = {"net": net.name, "demand": scen is not None}
    folder = os.path.join(work, net.name)
    if scen is not None:   # the demand's begin as the fill takes it: the configuration's, else the first departure
        begin = scen.begin if scen.begin is not None else math.floor(check_demand(
            list(scen.routes), {ln.edge for ln in net.lanes}, scen.additional) / o.step_length) * o.step_length
        T = begin + o.warmup
        r.update(begin=begin, T=T, inputs=" ".join(os.path.basename(f) if i % 2 else f
                                                   for i, f in enumerate(flags)))
        bar.set_postfix_str(f"{net.name}: SUMO's own warm-up")
        r["sumo"] = sumo_own(scen, begin, T, o)
        flags = flags + ["--begin", f"{T:g}"]
    else:
        T = 0.0
        r.update(T=T, inputs=f"-n {os.path.basename(path)} --density {o.density:g}")
        flags = flags + ["--density", f"{o.density:g}"]
    bar.set_postfix_str(f"{net.name}: fill")
    r.update(fill_and_check(flags, folder, T, o))
    if scen is not None and o.estimate and "error" not in r:
        bar.set_postfix_str(f"{net.name}: fill from the demand estimate")
        r["estimate"] = {**r, **fill_and_check(flags + ["--demand-estimate"], folder + "_estimate", T, o)}
    return r


def fill_and_check(flags: list[str], folder: str, T: float, o) -> dict:
    """The fill CLI with ``flags``, then stock SUMO on its folder (fill_side)."""
    doc, wall, command = run_fill(flags, folder, o)
    if doc is None:
        return {"error": command, "fill_wall": wall, "command": command}
    return {"fill_wall": wall, "command": command, "fill": fill_side(folder, doc, T, o),
            "doc": {k: doc[k] for k in ("summary", "timing_s", "density", "inflow", "state_time")}}


def main(o) -> int:
    from tqdm import tqdm
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    command = "python benchmarks/fill.py " + " ".join(sys.argv[1:]) if sys.argv[0].endswith(
        "fill.py") else "benchmarks/fill.py (in-process)"
    if o.speed:     # the cost table alone: a benchmark of its own (fill_speed.py)
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from fill_speed import speed_main
        return speed_main(o, command)
    t, results = time.perf_counter(), []
    with tempfile.TemporaryDirectory(prefix="scendiff-bench-fill-") as tmp, \
            tqdm(o.nets or default_nets(), desc="fill benchmark", unit="net") as bar:
        # SUMO's runs to T (the fill's default start with a demand) are timed the first time: no
        # state kept by an earlier run (sim/warmup.py)
        os.environ["XDG_CACHE_HOME"] = os.path.join(tmp, "cache")
        for path in bar:
            r = bench_net(path, o, os.path.abspath(o.keep) if o.keep else tmp, bar)
            if r is not None:
                results.append(r)
    text = tables(results, o, command) + f"\n\nTotal wall time {time.perf_counter() - t:.0f} s.\n"
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from report import emit
    emit(text, o.output, "Fill benchmark")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
