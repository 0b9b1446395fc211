"""The filled network in one SUMO, and the files that start stock SUMO from it.

    sim, reports = seed_fill(result, net, SimConfig(net=path, begin=t), seed=0)
    sim.simulation.saveState("state.xml.gz")
    write_start_routes("start.rou.xml", sim, ids, net, begin=t)
    write_sumocfg("scenario.sumocfg", options, "state.xml.gz", routes=[...])   # sim.export

Every tile's kept agents go through the one :class:`~sumo_scendiff.sim.seeding.Seeder` in the fill's
order (its routes: the generated trajectory, then on to a destination, sim/routes.py), with the
vehicles of earlier tiles around them as the leaders they may be behind; then one simulation step
puts them all where they were generated, and every tile's report is verified and settled against
the leaders SUMO itself sees (across tile borders too).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile

import numpy as np

from ..sim.export import write_routes
from ..sim.seeding import Seeder
from ..sim.sumo import start
from .demand import TYPICAL_SPEED_FACTOR

INFLOW_SECONDS = 3600.0     # how long the continuing inflow runs after the start


class InflowError(RuntimeError):
    """randomTrips.py could not make the inflow (one line: its last message)."""




def seed_fill(result, net, cfg, seed: int = 0, quiet: bool = True, progress: bool = False):
    """Start SUMO (``cfg``), seed every tile, step once, verify and settle. Returns (sim, reports
    per tile index)."""
    from tqdm import tqdm
    sim = start(cfg, quiet=quiet)
    seeder = Seeder(sim, net, prefix="fill", seed=seed)
    reports: dict[int, object] = {}
    rows = result.accepted.rows
    for k in tqdm(result.order, desc="seeding", unit=" tile", disable=not progress):
        scene = result.scenes[k]
        if scene is None or not len(scene):
            continue
        w = scene.window
        # the earlier tiles' vehicles in this window: leaders the Seeder fits gaps and speeds to
        pins = rows[result.records[k].pin_ids]
        others = np.zeros((len(pins), 5))
        if len(pins):
            others[:, :2] = w.world_to_scene(pins[:, :2])
            others[:, 2] = w.yaw_to_scene(pins[:, 2])
            others[:, 3:] = pins[:, 3:5]
        seeder.prefix, seeder.count = f"fill{k}.", 0
        reports[k] = seeder.seed(scene, others=(others, pins[:, 5] if len(pins) else np.zeros(0)))
    sim.simulationStep()
    for rep in reports.values():
        seeder.verify(rep)
    for rep in reports.values():
        seeder.settle(rep)
    return sim, reports


def write_start_routes(path: str, sim, ids, net, begin: float) -> dict[str, bool]:
    """start.rou.xml: every seeded vehicle departing at ``begin`` where it stands (its vType, its
    remaining route, departLane/departPos/departPosLat/departSpeed); vehicles inside a junction
    start at the end of the lane leading into it (``exact`` False)."""
    exact = write_routes(path, sim, ids, net)
    if begin:
        # export.write_routes departs everyone at 0 (a scene folder starts at 0); here at --begin
        with open(path) as f:
            text = f.read()
        with open(path, "w") as f:
            f.write(re.sub(r' depart="0" ', f' depart="{begin:g}" ', text))
    return exact


def fringe_sources(net) -> list[str]:
    """Car edges nothing leads onto but their own reverse: where traffic enters the network."""
    snet = net.sumo_net
    out = []
    for e in snet.getEdges(withInternal=False):
        if not e.allows("passenger"):
            continue
        inc = [p for p in e.getIncoming() if p.allows("passenger")
               and not (p.getFromNode() is e.getToNode() and p.getToNode() is e.getFromNode())]
        if not inc:
            out.append(e.getID())
    return sorted(out)


def _random_trips(net_file: str, path: str, begin: float, period: float, seed: int, fringe: bool) -> list[list[str]]:
    """Run randomTrips.py (validated by duarouter: every trip has a route) into ``path``; returns
    the routes it found. Its intermediate files stay in a temporary folder."""
    from ..core.tools import sumo_home, sumo_tool
    args = [sys.executable, sumo_tool("randomTrips.py"), "-n", os.path.abspath(net_file),
            "-o", os.path.abspath(path), "-r", "routes.rou.xml", "-b", f"{begin:g}",
            "-e", f"{begin + INFLOW_SECONDS:g}", "-p", f"{period:.3f}", "--seed", str(seed),
            "--prefix", "inflow", "--vehicle-class", "passenger", "--edge-permission", "passenger",
            "--validate"] + (["--fringe-factor", "max"] if fringe else [])
    with tempfile.TemporaryDirectory(prefix="scendiff-inflow-") as work:
        done = subprocess.run(args, check=False, env={**os.environ, "SUMO_HOME": sumo_home()}, cwd=work,
                              capture_output=True, text=True)
        if done.returncode != 0 or not os.path.exists(path):
            msg = (done.stderr or done.stdout).strip().splitlines()
            raise InflowError(f"randomTrips.py failed: {msg[-1] if msg else done.returncode}")
        routes = os.path.join(work, "routes.rou.xml")
        if not os.path.exists(routes):
            return []
        from sumolib.xml import parse
        return [r.edges.split() for r in parse(routes, "route")]


def trip_seconds(net, routes: list[list[str]]) -> float:
    """The mean free-flow time of the routes (at the typical share of the speed limits)."""
    snet = net.sumo_net
    times = [sum(snet.getEdge(e).getLength() / max(snet.getEdge(e).getSpeed() * TYPICAL_SPEED_FACTOR, 0.1)
                 for e in r if snet.hasEdge(e)) for r in routes]
    return float(np.mean(times)) if times else 0.0


def write_inflow(path: str, net, vehicles: int, begin: float, seed: int) -> dict:
    """inflow.rou.xml: randomTrips.py trips from the fringe (or anywhere, for a network without
    one) at the rate that holds ``vehicles`` on the network: in a steady state as many enter as
    leave, ``vehicles / trip time`` per second (Little's law). The trip time is measured on a first
    sample of the same random trips (their routes at free flow), then the file is drawn at that rate."""
    if vehicles <= 0:
        return {"file": None, "reason": "no vehicles to hold"}
    sources = fringe_sources(net)
    sample = _random_trips(net.path, path, begin, INFLOW_SECONDS / 200.0, seed, bool(sources))
    trip_s = trip_seconds(net, sample)
    if trip_s <= 0:
        os.remove(path)
        return {"file": None, "reason": "randomTrips.py found no route"}
    period = max(trip_s / vehicles, 0.1)
    _random_trips(net.path, path, begin, period, seed, bool(sources))
    return {"file": os.path.basename(path), "period_s": round(period, 3), "trip_s": round(trip_s, 1),
            "from": "fringe" if sources else "anywhere (the network has no fringe)",
            "fringe_sources": len(sources), "seconds": INFLOW_SECONDS}


__all__ = ["InflowError", "fringe_sources", "seed_fill", "trip_seconds", "write_inflow", "write_start_routes"]
