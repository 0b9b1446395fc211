"""A demand's filled start made by SUMO itself: the user's scenario run to --begin, written as a fill.

    doc = sumo_start(req, net, scen, begin, start, folder, timing)

Running the scenario to T costs what stock SUMO costs (sim/warmup.py: one ``simulationStep(T)``, the
state kept for the next time) and holds exactly SUMO's vehicles, where the demand estimate
(fill/demand.py) approximates them without simulating; benchmarks/fill.py has both side by side. The
folder is a fill's: the saved state (scenario.sumocfg) and the portable start (start.rou.xml,
start.sumocfg: every vehicle on the network departing where it stands, its route on), the demand
continuing after T, fill.json describing every vehicle. Vehicles still waiting to enter at T are in the
state, not in the portable start (fill.json counts them).
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import replace

import numpy as np
import shapely

METHOD = ("the scenario run by SUMO from its start to --begin (sim/warmup.py: its own step length and options, "
          "one simulationStep; the state kept under ~/.cache/sumo-scendiff/states for the next time), every "
          "vehicle on the network at --begin")
AREA_METHOD = ("with --area, SUMO's vehicles whose box centre lies in the rectangle (its sides included), the "
               "rest and the persons outside it (a rider with its vehicle) taken out of SUMO before the state "
               "and the portable start are written; the vehicles waiting to enter stay (the demand goes on)")


def _agents(sim, ids: list[str]) -> list[dict]:
    """Per vehicle its box centre, heading (yaw), size and speed, as fill.json's agents."""
    from ..core.geometry import sumo_to_pose
    out = []
    for vid in ids:
        x, y = sim.vehicle.getPosition(vid)
        length = sim.vehicle.getLength(vid)
        x, y, yaw = sumo_to_pose(x, y, sim.vehicle.getAngle(vid), length)
        out.append({"tile": None, "x": round(float(x), 3), "y": round(float(y), 3), "heading": round(float(yaw), 4),
                    "length": round(length, 3), "width": round(sim.vehicle.getWidth(vid), 3),
                    "speed": round(sim.vehicle.getSpeed(vid), 3), "vtype": sim.vehicle.getTypeID(vid),
                    "vehicle": vid, "status": "placed"})
    return out


def _keep_area(sim, agents: list[dict], area: tuple | None) -> tuple[list[dict], dict | None]:
    """The agents whose box centre lies in ``area`` (tiles.in_area, the estimate's rule too); every
    other vehicle, and every person outside it, taken out of ``sim`` before its state is saved (TraCI
    has no container domain: a container leaves only with its vehicle). Returns (the agents kept,
    fill.json's record of what SUMO had and what was kept; None without an area)."""
    if area is None:
        return agents, None
    from .tiles import in_area
    inside = in_area([(a["x"], a["y"]) for a in agents], area)
    persons = list(sim.person.getIDList())
    # one walking or waiting goes by its position, a rider with its vehicle
    for pid in persons:
        if not sim.person.getVehicle(pid) and not in_area([sim.person.getPosition(pid)], area)[0]:
            sim.person.remove(pid)
    for a, keep in zip(agents, inside):
        if not keep:
            # its riders first: SUMO 1.28 leaves a taxi's passenger (device.taxi) pointing at the vehicle
            # TraCI removed, and its next saveState crashes (corpus: sumotest_taxi_2taxis_10persons)
            for pid in sim.vehicle.getPersonIDList(a["vehicle"]):
                sim.person.remove(pid)
            sim.vehicle.remove(a["vehicle"])
    kept = [a for a, keep in zip(agents, inside) if keep]
    record = {"on_network": len(agents), "in_area": len(kept), "outside": len(agents) - len(kept),
              "method": AREA_METHOD}
    if persons:
        after = len(sim.person.getIDList())
        record["persons"] = {"on_network": len(persons), "in_area": after, "outside": len(persons) - after}
    return kept, record


def _run(req, net, scen, begin: float, start: float, folder: str, timing: dict, said: set[str]):
    """SUMO at ``begin``, only what lies in ``req.area`` kept; its state, the portable start's routes.
    What SUMO says on the way is shown once (seed.said_once; ``said``: the kinds shown). Returns
    (cfg, agents, exact, state time, vehicles waiting to enter, the area's record)."""
    from ..sim.state import save_state, waiting_in_state
    from ..sim.sumo import SimConfig, close, settings
    from ..sim.scenario import own_random
    from ..sim.warmup import start_warm, warm_config
    from .edge_stops import carry_edge_stops, park_together
    from .seed import said_once, write_start_routes
    seed, rng = own_random(scen)   # the user's SUMO seed: -s seeds the model's draws only
    cfg = SimConfig(net=scen.net, routes=tuple(scen.routes), additional=tuple(scen.additional), seed=seed,
                    begin=start, **settings(req, scen, mesoscopic=False))   # as _sim_config (fill/api.py)
    # run, saved and exported as the warm-up runs it: the user's options alone (none of the seeding's:
    # nothing is seeded) and SUMO's random number generators kept in the state, so scenario.sumocfg
    # goes on drawing what the user's own run draws
    cfg = warm_config(replace(cfg, extra=cfg.extra + rng))
    t = time.perf_counter()
    with said_once(said):   # a run made now and the start from its state load the same files
        sim = start_warm(cfg, begin, quiet=not req.verbose)
    try:
        timing["warm_up"] = time.perf_counter() - t
        agents, area = _keep_area(sim, _agents(sim, list(sim.vehicle.getIDList())), req.area)
        ids = [a["vehicle"] for a in agents]
        state = os.path.join(folder, "state.xml.gz")
        save_state(sim, state)
        state_time = float(sim.simulation.getTime())
        routes = os.path.join(folder, "start.rou.xml")
        exact = write_start_routes(routes, sim, ids, net, state_time,
                                   vtype_files=list(scen.routes) + list(scen.additional))
        carry_edge_stops(routes, state, sim, ids)
        park_together(routes, sim, ids)
        _drop_their_vtypes(routes, [*scen.routes, *scen.additional])
        _rename(routes)
        waiting = waiting_in_state(state, sim.vehicle.getIDList(), state_time)
    finally:
        close(sim)
    return cfg, agents, exact, state_time, waiting, area


# the portable start's vehicles are named so: SUMO numbers a flow's vehicles from 0 again when it
# starts after the flow's begin (sumo -b T), and would refuse the flow's "f.0" still on the road
PORTABLE_PREFIX = "start."


def _rename(path: str) -> None:
    """start.rou.xml's vehicles (and their routes) as :data:`PORTABLE_PREFIX` + the state's id."""
    import xml.etree.ElementTree as ET
    tree = ET.parse(path)
    for el in tree.getroot():
        if el.tag in ("vehicle", "route") and el.get("id"):
            el.set("id", PORTABLE_PREFIX + el.get("id"))
        if el.tag == "vehicle" and el.get("route"):
            el.set("route", PORTABLE_PREFIX + el.get("route"))
    tree.write(path, encoding="UTF-8", xml_declaration=True)


def _drop_their_vtypes(path: str, files: list[str]) -> None:
    """start.rou.xml without the vTypes the scenario's own files define, nor SUMO's own defaults
    (DEFAULT_VEHTYPE, ...): the start loads those files too (the demand continues), and SUMO refuses
    a vType defined twice, or a default one redefined once a vehicle of the demand has used it. Its
    vehicles drive the scenario's own vTypes, or SUMO's defaults as the scenario did."""
    import xml.etree.ElementTree as ET

    from ..sim.export import declared_vtypes
    theirs = set(declared_vtypes(files))
    tree = ET.parse(path)
    root = tree.getroot()
    for el in [el for el in root if el.tag == "vType" and (el.get("id") in theirs
                                                            or el.get("id", "").startswith("DEFAULT_"))]:
        root.remove(el)
    tree.write(path, encoding="UTF-8", xml_declaration=True)


def sumo_start(req, net, scen, begin: float, start: float, folder: str, timing: dict) -> dict:
    """The fill's folder from SUMO's own run of ``scen`` from ``start`` to ``begin``; returns fill.json."""
    from ..sim.stops import place_ends
    from .output import FORMAT, ONWARD, VERSION, mesoscopic_start, summary, write_configurations
    from .picture import draw_fill
    from .seed import admit_start, refuse_at_load
    said: set[str] = set()            # the kinds of SUMO's messages shown: each once
    cfg, agents, exact, state_time, waiting, area = _run(req, net, scen, begin, start, folder, timing, said)
    t = time.perf_counter()
    inflow = {"file": None, "reason": ONWARD}
    options = write_configurations(folder, replace(cfg, routes=()), list(scen.routes), inflow, state_time,
                                   start_last=True, demand_begin=scen.begin or 0.0)
    refitted, refused = admit_start(folder, {PORTABLE_PREFIX + a["vehicle"]: (a["x"], a["y"]) for a in agents},
                                    place_ends(cfg.additional, net),
                                    state_ids={PORTABLE_PREFIX + a["vehicle"]: a["vehicle"] for a in agents}, said=said)
    refused = {vid.removeprefix(PORTABLE_PREFIX): why for vid, why in refused.items()}
    refuse_at_load(agents, refused)
    start_model = mesoscopic_start(folder, scen, said)
    seeded = [a for a in agents if a["vehicle"] is not None]
    rows = np.array([[a[k] for k in ("x", "y", "heading", "length", "width", "speed")] for a in seeded]
                    ).reshape(-1, 6)
    km = net.car_lane_km_in(_bounds_box(net) if req.area is None else shapely.box(*req.area))
    draw_fill(os.path.join(folder, "fill.png"), net, rows, [],
              f"{net.name}: {len(seeded)} vehicles, SUMO's own run to {state_time:g} s"
              + ("" if req.area is None else " (in the area)"))
    timing["export"] = time.perf_counter() - t
    source = {"kind": "demand", "start": "sumo", "time": begin,
              "en_route": len(agents) if area is None else area["on_network"],
              "waiting_to_enter": waiting, "applied": True, "method": METHOD}
    if area is not None:
        source["vehicles"] = area
    doc = {"format": FORMAT, "version": VERSION, "network": os.path.abspath(scen.net),
           "configuration": scen.config, "routes": [os.path.abspath(r) for r in scen.routes],
           "begin": begin, "state_time": state_time, "seed": req.seed, "sumo_seed": cfg.seed,
           "area": None if req.area is None else [float(v) for v in req.area], "stride": None,
           "portable_ids": f"{PORTABLE_PREFIX}<vehicle> in start.rou.xml",
           "density": source, "sumo_options": options, "inflow": inflow, "fleet": "scenario",
           **({"start_model": start_model} if start_model else {}),
           "summary": summary(net, agents, seeded, rows, km, 0, exact, refused, refitted),
           "tiles": [], "agents": agents,
           "files": sorted(f for f in os.listdir(folder) if not f.startswith(".")) + ["fill.json"],
           "workers": None, "timing_s": {k: round(v, 2) for k, v in timing.items()}}
    with open(os.path.join(folder, "fill.json"), "w") as f:
        json.dump(doc, f, indent=1)
    return doc


def _bounds_box(net):
    from .tiles import car_bounds
    x0, y0, x1, y1 = car_bounds(net)
    return shapely.box(x0 - 1.0, y0 - 1.0, x1 + 1.0, y1 + 1.0)


__all__ = ["METHOD", "PORTABLE_PREFIX", "sumo_start"]
