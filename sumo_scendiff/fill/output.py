"""The fill's folder: seeded into one SUMO, saved, and described (fill.json, fill.png)."""
from __future__ import annotations

import json
import os
import tempfile
import time
from contextlib import contextmanager
from dataclasses import replace

import numpy as np

from ..sim.export import write_sumocfg
from ..sim.fleet import DRAWN_KEY
from ..sim.seeding import STATUSES
from ..sim.state import save_state
from ..sim.stops import place_ends
from ..sim.sumo import close
from .en_route import write_vtypes
from .flow_ids import number_flows
from .picture import draw_fill, edge_density
from .inflow import inflow_sample, probe_speed, write_inflow
from .seed import admit_start, refuse_at_load, seed_fill, write_start_routes
from .tiles import scene_rows

FORMAT, VERSION = "sumo-scendiff-fill", 1
# fill.json's inflow with a demand: its files (route files, additional files with vehicles) are in the
# configurations, SUMO departs what follows the state's time
ONWARD = "the demand continues (its files are in the configurations)"


def _agents(result, reports) -> list[dict]:
    """Per kept agent (fill order): its tile, world pose, size, speed, SUMO id and how it went."""
    out = []
    for k in result.order:
        scene = result.scenes[k]
        rows, rep = scene_rows(scene), reports.get(k)
        for a, r in enumerate(rows):
            vid = rep.ids.get(a) if rep is not None else None
            status, why = rep.status(a) if rep is not None else ("dropped", "its tile was not seeded")
            row = {"tile": k, "x": round(float(r[0]), 3), "y": round(float(r[1]), 3),
                   "heading": round(float(r[2]), 4), "length": round(float(r[3]), 3),
                   "width": round(float(r[4]), 3), "speed": round(float(r[5]), 3),
                   "vclass": int(scene.vclass[a]), "vehicle": vid, "status": status}
            if status == "misplaced":
                row["position_error"] = why
            elif why is not None:
                row["reason"] = why
            if rep is not None and a in rep.pulled_back:   # its nose was over the stop line (Seeder.fit_lane_ends)
                row["pulled_back_m"] = round(rep.pulled_back[a], 3)
            if rep is not None and a in rep.to_stop_line:  # waiting on red inside a junction (Seeder.fit_red_junctions)
                row["to_stop_line_m"] = round(rep.to_stop_line[a], 3)
            if a in scene.meta.get("to_space_entry", {}):  # parked in a space at T (seed._to_space_entry)
                row["to_space_entry_m"] = scene.meta["to_space_entry"][a]
            if rep is not None and a in rep.narrowed:     # wider than the network's junctions assume (Seeder.width_cap)
                row["sumo_width"] = rep.narrowed[a][1]
            fleet = scene.meta.get(DRAWN_KEY, {}).get(a)
            if fleet is not None:                          # seeded as the scenario's vType (sim/fleet.py)
                row.update(vtype=fleet[0], drawn_length=round(fleet[1], 3), drawn_width=round(fleet[2], 3))
            if (scene.meta.get("stood_at_red") or [False] * len(rows))[a]:   # a red queue given standing (--signals)
                row["stood_at_red"] = True
            d = (scene.meta.get("demand") or [None] * len(rows))[a]
            if d is not None:                              # drawn for a vehicle of the demand (fill/en_route.py)
                v = result.demand[d].vehicle
                row["demand"] = {"id": v.id, "type": v.type, "route": rep.own_route.get(a) if rep is not None else None}
            out.append(row)
    return out


def write_outputs(folder, req, net, gen, scen, demand, cfg, sumo, result, source, timing, progress,
                  workers: dict | None = None) -> dict:
    """The filled network seeded into the fill's SUMO (``sumo``: :func:`seeding_sumo` of ``cfg``), its
    state and portable start written with the configurations that start them, fill.json and
    fill.png; ``req``: the fill.api.FillRequest; ``demand``: the files holding the scenario's demand
    (its route files and additional files with vehicles: data.demand.demand_files)."""
    t = time.perf_counter()
    agents, ids, exact, state_time, inflow = _seed_and_save(folder, req, net, demand, cfg, sumo, result, timing,
                                                            progress)
    t += timing.get("seed", 0.0) + timing.get("inflow", 0.0)
    routes = list(scen.routes)
    options = write_configurations(folder, cfg, routes, inflow, state_time, demand_begin=scen.begin or 0.0)
    # the portable start's box centres where the state has them (a vehicle on a curve departs with
    # its lane's heading, which swings its box about its front)
    # and both starts load in SUMO: a vehicle it refuses is taken out alone (seed.admit_start)
    said: set[str] = set()            # the kinds of SUMO's messages loading the folder: each shown once
    refitted, refused = admit_start(folder, {a["vehicle"]: (a["x"], a["y"]) for a in agents if a["vehicle"] in set(ids)},
                                    place_ends(cfg.additional, net), said=said)
    refuse_at_load(agents, refused)
    start_model = mesoscopic_start(folder, scen, said)
    seeded = [a for a in agents if a["vehicle"] is not None]
    rows = np.array([[a[k] for k in ("x", "y", "heading", "length", "width", "speed")] for a in seeded]
                    ).reshape(-1, 6)
    area_km = float(sum(t.core_km for t in result.tiles))
    title = (f"{net.name}: {len(seeded)} vehicles, {len(seeded) / max(area_km, 1e-9):.1f} veh/km of car lane, "
             f"seed {req.seed}, density: {source['kind']}{'' if source['applied'] else ' (not applied)'}")
    draw_fill(os.path.join(folder, "fill.png"), net, rows, result.tiles, title)
    timing["export"] = time.perf_counter() - t
    counts = summary(net, agents, seeded, rows, area_km, len(result.tiles), exact, refused, refitted)
    doc = {"format": FORMAT, "version": VERSION, "network": os.path.abspath(scen.net),
           "configuration": scen.config, "routes": [os.path.abspath(r) for r in routes],
           "begin": cfg.begin or 0.0, "state_time": state_time, "seed": req.seed,
           "area": list(req.area) if req.area else None, "stride": req.stride,
           "tile_size": result.tiles[0].window.size, "density": source, "p_mask": req.p_mask,
           "model_sha256": gen.sha256, "model": gen.config.record(gen), "sumo_options": options,
           "inflow": inflow, "fleet": "model" if req.model_fleet else "scenario", "summary": counts,
           **({"start_model": start_model} if start_model else {}),
           "tiles": _tile_rows(result, seeded), "agents": agents,
           "files": sorted(f for f in os.listdir(folder) if not f.startswith(".")) + ["fill.json"],
           "workers": workers, "timing_s": {k: round(v, 2) for k, v in timing.items()}}
    with open(os.path.join(folder, "fill.json"), "w") as f:
        json.dump(doc, f, indent=1)
    return doc


@contextmanager
def seeding_sumo(cfg, routes, quiet: bool = True, demand=()):
    """The fill's one SUMO, (simulation, its configuration): started before the tiles are generated
    (the lights' states at the start are read from it), the tiles seeded into it after; closed at
    the end. With a demand it loads the demand's own vTypes too, for the vehicles that stand for its
    vehicles and those the model adds (sim/fleet.py; only this SUMO loads them: the folder's
    configurations load the route files themselves). ``demand``: the files holding the demand
    (data.demand.demand_files); an additional file among them is loaded without its vehicles, as
    the route files are not loaded: the demand's departures up to the state's time are the fill's."""
    from ..data.demand import write_without_demand
    from ..sim.sumo import start
    with tempfile.TemporaryDirectory(prefix="scendiff-vtypes-") as work:
        extra = os.path.join(work, "vtypes.add.xml")
        additional = tuple(write_without_demand(p, work) if p in demand else p for p in cfg.additional)
        seed_cfg = replace(cfg, additional=additional + ((extra,) if routes and write_vtypes(routes, extra) else ()))
        sim = start(seed_cfg, quiet=quiet)
        try:
            yield sim, seed_cfg
        finally:
            close(sim)


def _seed_and_save(folder, req, net, demand, cfg, sumo, result, timing, progress):
    """Every tile seeded into the fill's SUMO (``sumo``: :func:`seeding_sumo`'s; fill/seed.py), its
    state saved and the portable start's routes written; without a demand the network then driven on
    to measure the inflow. Returns (agents, the seeded vehicles' ids, start_exact per vehicle, the
    state's time, the inflow record)."""
    t = time.perf_counter()
    sim, reports = seed_fill(result, net, sumo[1], seed=req.seed, quiet=not req.verbose, progress=progress,
                             demand=result.demand, routes=demand, model_fleet=req.model_fleet, sim=sumo[0])
    try:
        timing["seed"] = time.perf_counter() - t
        agents = _agents(result, reports)
        present = set(sim.vehicle.getIDList())
        ids = [a["vehicle"] for a in agents if a["vehicle"] in present]
        save_state(sim, os.path.join(folder, "state.xml.gz"))
        state_time = float(sim.simulation.getTime())
        # the portable start departs its vehicles where the state has them, at the state's time: the
        # demand's departures before it are the fill's, and SUMO skips them from its files
        exact = write_start_routes(os.path.join(folder, "start.rou.xml"), sim, ids, net, state_time,
                                   vtype_files=list(dict.fromkeys([*demand, *cfg.additional])))
        inflow = {"file": None, "reason": ONWARD}
        if not demand:
            # the state and start routes are written: now drive the filled network on, with the
            # inflow's own trips replacing those that leave, to see how fast it flows when held
            # (seed.probe_speed); those replacements are the inflow's first departures
            t = time.perf_counter()
            sample, fringe = inflow_sample(net, cfg.begin or 0.0, req.seed, len(ids))
            probe = probe_speed(sim, sample) if ids and sample else None
            inflow = write_inflow(os.path.join(folder, "inflow.rou.xml"), net, len(ids), cfg.begin or 0.0,
                                  req.seed, sample=sample, probe=probe, fringe=fringe)
            timing["inflow"] = time.perf_counter() - t
    finally:
        close(sim)
    return agents, ids, exact, state_time, inflow


def write_configurations(folder, cfg, routes, inflow: dict, state_time: float, start_last: bool = False,
                         demand_begin: float = 0.0) -> dict:
    """scenario.sumocfg (from the saved state) and start.sumocfg (the portable start), the demand
    or the inflow continuing; returns their SUMO options. ``start_last``: start.rou.xml after the
    demand's files (its vehicles are of the vTypes those define, which SUMO must read first).
    ``demand_begin``: the begin stock SUMO loads the user's demand with (their configuration's,
    else 0), which a flow without begin keeps in the folder's copy."""
    onward = list(routes) + ([os.path.join(folder, inflow["file"])] if inflow.get("file") else [])
    options = cfg.options()
    if inflow.get("max_num_vehicles"):   # the inflow's surplus waits to enter (inflow.SUPPLY), a while
        options["max-num-vehicles"] = str(inflow["max_num_vehicles"])
        options["max-depart-delay"] = f"{inflow['max_depart_delay_s']:g}"
    # SUMO starts a loaded state at the state's own time (one seeding step after --begin); a flow
    # without begin keeps the begin SUMO loaded the demand with (write_sumocfg's begin)
    loaded = {**options, "b": f"{demand_begin:g}"}   # the fill's own SUMO may have started later
    write_sumocfg(os.path.join(folder, "scenario.sumocfg"), loaded, "state.xml.gz", routes=onward, begin=state_time)
    start = [os.path.join(folder, "start.rou.xml")]
    write_sumocfg(os.path.join(folder, "start.sumocfg"), loaded, None,
                  routes=onward + start if start_last else start + onward, begin=state_time)
    # SUMO numbers a flow from 0 again when it starts after the flow's begin (fill/flow_ids.py)
    number_flows(folder, state_time)
    return options


def mesoscopic_start(folder: str, scen, said: set[str] | None = None) -> dict | None:
    """start.sumocfg in the scenario's mesoscopic model (its ``mesosim`` and ``meso-*`` options), where
    it runs one: the portable start holds no state, and SUMO inserts each departure into the segment of
    its place; scenario.sumocfg loads a microscopic state, which that model does not (docs/sumo-options.md).
    Called once the start loads microscopically (seed.admit_start); where SUMO refuses it in the
    mesoscopic model, it stays microscopic; ``said``: the kinds of SUMO's messages shown (seed.said_once).
    Returns fill.json's ``start_model`` (None: no such model)."""
    from xml.sax.saxutils import quoteattr

    from ..core.sumo_xml import boolean
    from ..sim.sumo import SimError, mesoscopic_options, start_config
    from .seed import _caught
    meso = mesoscopic_options(scen.options)
    if not boolean(dict(meso).get("mesosim")):
        return None
    path = os.path.join(folder, "start.sumocfg")
    with open(path) as f:
        micro = f.read()
    with open(path, "w") as f:
        f.write(micro.replace("</configuration>", "".join(f"    <{n} value={quoteattr(v)}/>\n" for n, v in meso)
                              + "</configuration>"))

    def first_step():
        sim = start_config(path)
        try:
            sim.simulationStep()
        finally:
            close(sim)
    try:
        _caught(first_step, said)
    except SimError as e:
        with open(path, "w") as f:
            f.write(micro)
        return {"model": "microscopic", "reason": str(e)}
    return {"model": "mesoscopic"}


def summary(net, agents, seeded, rows, area_km, tiles, exact, refused, refitted) -> dict:
    """fill.json's summary: the agents by status, the portable start, the density as edgeData counts it."""
    # SUMO's edgeData counts a vehicle on the lane of its front bumper: one nosing into a junction is
    # in no normal edge's density (docs/sumo-options.md)
    front = rows[:, :2] + 0.5 * rows[:, 3:4] * np.c_[np.cos(rows[:, 2]), np.sin(rows[:, 2])]
    in_junctions = int(net.in_junction(front).sum())
    dens = edge_density(net, rows)
    return {"tiles": tiles, "kept": len(agents), "vehicles": len(seeded),
            # kept = placed + misplaced + refused + existing + dropped (SeedReport.status; none existing here)
            **{s: sum(a["status"] == s for a in agents) for s in STATUSES},
            "start_exact": sum(v for vid, v in exact.items() if vid not in refused), "start_refitted": refitted,
            "pulled_back": sum("pulled_back_m" in a for a in agents),
            "to_stop_line": sum("to_stop_line_m" in a for a in agents), "car_lane_km": round(area_km, 3),
            "demand_vehicles": sum("demand" in a for a in seeded),
            "demand_routes_followed": sum(a.get("demand", {}).get("route") == "followed" for a in seeded),
            "density_veh_per_km": round((len(seeded) - in_junctions) / max(area_km, 1e-9), 2),
            "in_junctions": in_junctions, "edges_with_vehicles": sum(v > 0 for v in dens.values())}


def _tile_rows(result, seeded) -> list[dict]:
    per_tile = {}
    for a in seeded:
        per_tile[a["tile"]] = per_tile.get(a["tile"], 0) + 1
    tiles = []
    for rec in result.records:
        tl = rec.tile
        tiles.append({"index": tl.index, "i": tl.i, "j": tl.j, "colour": tl.colour,
                      "window": dict(zip(("cx", "cy", "yaw", "size"), tl.window.as_tuple())),
                      "core": [round(v, 3) for v in tl.core], "car_lane_km": round(tl.core_km, 4),
                      "pins": rec.pins, "p_mask": rec.p_mask,
                      "target_veh_per_km": None if rec.target is None else round(float(rec.target), 2),
                      "generated": rec.generated, "kept": rec.kept, "seeded": per_tile.get(tl.index, 0),
                      "density_veh_per_km": round(per_tile.get(tl.index, 0) / tl.core_km, 2)})
    return tiles


__all__ = ["FORMAT", "ONWARD", "VERSION", "mesoscopic_start", "seeding_sumo", "summary", "write_configurations",
           "write_outputs"]
