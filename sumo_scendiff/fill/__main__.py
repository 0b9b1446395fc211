"""Fill a whole SUMO network with generated traffic: a filled start for stock SUMO.

    python -m sumo_scendiff.fill -n city.net.xml -o filled/                 # the model's prior
    python -m sumo_scendiff.fill -n city.net.xml --density 25 -o filled/    # needs a density model
    python -m sumo_scendiff.fill -c scenario.sumocfg --begin 28800 -o filled/
    python -m sumo_scendiff.fill -n city.net.xml --workers 2 -o filled/    # the same fill, 2 processes
    sumo -c filled/scenario.sumocfg        # from the saved state;  filled/start.sumocfg: portable

Overlapping 100 m tiles (--stride apart) cover every car lane (or --area); they are generated in
four batches of tiles that do not overlap, each tile around the vehicles its earlier neighbours
own inside it (pinned tokens), and keep the vehicles of their own core cell (docs/fill.md).
Writes -o DIR (under DIR.partial-<pid> until complete): fill.json, state.xml.gz, scenario.sumocfg,
start.rou.xml, start.sumocfg, fill.png, and without demand inflow.rou.xml.
"""
from __future__ import annotations

import argparse
import os
import shutil
import signal
import sys
import time

PROG = "python -m sumo_scendiff.fill"


class FillError(Exception):
    """A problem with the user's input (exit code 2, one line)."""


def get_options(args=None):
    from ..core.cli import HelpFormatter, description, epilog, joined, sumo_time
    from ..generation.config import GenerationConfig, SettingError
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), epilog=epilog(__doc__),
                                formatter_class=HelpFormatter)
    p.add_argument("-c", "--configuration-file", dest="config", metavar="FILE",
                   help="a SUMO scenario (.sumocfg); its demand sets how much traffic and continues after the start")
    p.add_argument("-n", "--net-file", "--net", dest="net", help="SUMO network (.net.xml[.gz])")
    p.add_argument("-r", "--route-files", "--routes", dest="routes", default=None,
                   help="demand (comma-separated route files): its vehicles en route at --begin set the "
                        "density, and it continues after the start")
    p.add_argument("-a", "--additional-files", dest="additional", default=None,
                   help="comma-separated additional files (vTypes, TLS programs)")
    p.add_argument("-b", "--begin", type=sumo_time, default=None, metavar="TIME",
                   help="the time of the filled start (s, or clock time HH:MM:SS as SUMO reads it); with "
                        "demand default: its first departure + 600, and it must lie within the demand's "
                        "departures")
    p.add_argument("--area", metavar="X0,Y0,X1,Y1", help="fill only this rectangle (network coordinates)")
    p.add_argument("--stride", type=float, default=75.0, help="metres between tile centres (default 75)")
    amount = p.add_mutually_exclusive_group()
    amount.add_argument("--density", metavar="D", help="vehicles per km of car lane (needs a model with "
                        "the density condition; --p-mask is the fallback)")
    amount.add_argument("--edge-data", metavar="FILE", help="SUMO edgeData file: each tile's density at --begin")
    p.add_argument("--demand-level-only", action="store_true",
                   help="with demand: take only its level per tile and let the model place the vehicles "
                        "(default: the demand's own vehicles where the estimate has them, on their own routes)")
    p.add_argument("--p-mask", type=float, default=1.0, metavar="P",
                   help="global token of a tile without neighbours (default 1: the model's prior; lower: fewer vehicles)")
    p.add_argument("-s", "--seed", type=int, default=0)
    from ..sim.sumo import add_arguments, settings_problem
    add_arguments(p)       # --step-length, --lateral-resolution, --no-seeding-options
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="processes generating a colour's tiles side by side, each loading the model once "
                        "(default 1: this one); the same seed gives the same fill with any number")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="generate on --workers Ray actors of the cluster at ADDR (HOST:PORT, auto; local: "
                        "a new local instance); they read the network and checkpoint at the same paths")
    p.add_argument("-o", "--output-dir", dest="out", default="filled")
    p.add_argument("--force", action="store_true", help="replace an existing -o")
    p.add_argument("--export", choices=("openscenario",), default=None,
                   help="also write the fill as OpenSCENARIO + OpenDRIVE, its Init (docs/openscenario.md)")
    p.add_argument("-v", "--verbose", action="store_true")
    GenerationConfig.add_arguments(p)
    # bad input is one line naming the flag (argparse would print its usage first)
    p.error = lambda message: p.exit(2, f"{PROG}: error: {message}\n")
    o = p.parse_args(joined(p, args))   # --area -100,-50,...: a negative coordinate is not a flag
    from ..sim.scenario import input_flags_problem
    if input_flags_problem(o.net, o.config):
        p.error(input_flags_problem(o.net, o.config))
    from ..sim.density import DensityError, parse_density
    from .tiles import TileError, parse_area
    try:
        o.density = parse_density(o.density)
        o.area = parse_area(o.area)
    except (DensityError, TileError) as e:
        p.error(str(e))
    if o.density == "auto":
        p.error("--density: 'auto' is not a fill's level; give --edge-data, demand (-c/-r), or a number")
    if not 0.0 < o.p_mask <= 1.0:
        p.error(f"--p-mask must be in (0, 1], got {o.p_mask}")
    if o.workers < 1:
        p.error(f"--workers must be >= 1, got {o.workers}")
    if o.ray_address is not None:
        from ..core.pool import EngineError, import_ray
        try:
            import_ray("--ray-address")
        except EngineError as e:
            p.error(str(e))
    if settings_problem(o):
        p.error(settings_problem(o))
    try:
        GenerationConfig.from_options(o)
    except SettingError as e:
        p.error(str(e))
    o.parser = p
    return o


def _files(arg: str | None) -> list[str]:
    return [f for f in (arg or "").split(",") if f]


def _amount(o, net, gen, tiles, routes, begin, additional=(), options=()) -> tuple[list | None, bool, dict, list | None]:
    """Per tile the density target, whether the model is given it, the source for fill.json, and
    with demand the demand's vehicles placed on their lanes (fill/en_route.py; None: none given)."""
    import numpy as np
    import shapely

    from ..map.edgedata import EdgeData, EdgeDataError
    from .demand import DemandEstimate
    from .en_route import allows, place_en_route
    from .vtypes import vtype_bodies, vtype_table
    from .plan import demand_tiles
    from .routing import RoutingError
    name = o.checkpoint or "the shipped model"
    if (o.density is not None or o.edge_data) and not gen.has_density:
        flag = "--density" if o.density is not None else "--edge-data"
        raise FillError(f"{flag}: {name} has no density condition (trained before it); leave it out "
                        f"for the model's prior, or use --p-mask (lower: fewer vehicles) as the fallback")
    if o.density is not None:
        return [o.density] * len(tiles), True, {"kind": "density", "veh_per_km": o.density, "applied": True}, None
    if o.edge_data:
        try:
            data = EdgeData.read(o.edge_data, net)
            targets = [data.region_density(net, shapely.box(*t.core), begin) for t in tiles]
        except EdgeDataError as e:
            raise FillError(f"--edge-data: {e}") from None
        return targets, True, {"kind": "edge-data", "file": os.path.abspath(o.edge_data), "time": begin,
                               "applied": True}, None
    if routes:
        try:
            # the state is saved one seeding step after begin: the departures before then are the fill's
            est = DemandEstimate.at(net, routes, begin, additional=additional, due=begin + o.step_length,
                                    depart_speed=dict(options).get("default.departspeed"),
                                    junction_taz=str(dict(options).get("junction-taz", "false")).lower()
                                    in ("true", "1", "on", "yes", "x"))
        except RoutingError as e:
            raise FillError(f"{', '.join(routes)}: {e}") from None
        # each tile's count is kept in its core: the core's own density, so the tiles add up to the
        # estimate (a window's would spread a vehicle over every tile whose window sees it)
        targets = [est.region_density(net, shapely.box(*t.core)) for t in tiles]
        src = {"kind": "demand", "time": begin, "en_route": est.vehicles, "departed": est.departed,
               "unrouted": est.unrouted, "applied": gen.has_density,
               "method": "each departure before the state's time (--begin + one step) laid on the route SUMO's "
                         "duarouter gives it and moved by fill/travel.py's clock: its vType's desired speed "
                         "(x 0.9), the junctions' internal lanes, giving way, fixed lights as SUMO runs their "
                         "programs (queues first come, first served), actuated ones at the cycle their gap "
                         "control runs, the start from standing where it departs at speed 0 (its departSpeed, "
                         "else SUMO's default.departspeed); queues on the lanes that lead on along each route, spilling back where "
                         "they are full (fill/queues.py); no simulation"}
        if not gen.has_density:
            src["note"] = (f"{name} has no density condition: the demand's density is recorded per tile "
                           f"(target) but generation uses the model's prior scaled by --p-mask {o.p_mask:g}")
        if o.demand_level_only:
            return targets, gen.has_density, src, None
        files = [*routes, *additional]
        classes = vtype_table(files, lambda el: el.get("vClass") or "passenger")
        placed, skipped = place_en_route(net, est, vtype_bodies(files), classes)
        # each core keeps the vehicles placed in it: an edge's queue stands in the core of its stop
        # line, not spread over the edge as the per-edge density has it
        owner = demand_tiles(tiles, placed, o.area)
        per_tile = np.bincount([k for k in owner if k is not None], minlength=len(tiles))
        for t in tiles:
            km = net.car_lane_km_in(shapely.box(*t.core))
            targets[t.index] = float(per_tile[t.index]) / km if km > 0 else None
        placed = [p for p, k in zip(placed, owner) if k is not None]
        # trams, bicycles on their bike lanes: no car lane of their edge is theirs
        off = sum(not any(ln.car and ln.edge == v.edges[0] and allows(net, i, classes.get(v.type, "passenger"))
                          for i, ln in enumerate(net.lanes)) for v in skipped)
        src["vehicles"] = {"placed": len(placed), "no_room": len(skipped) - off, "no_car_lane": off,
                           "outside": len(owner) - len(placed),
                           "method": "each en-route vehicle on a lane of its edge from which its route goes on, "
                                     "waiting ones queued from the stop line, moving ones where their time on the "
                                     "edge brought them; given to its tile as a token (pose and size), the model "
                                     "draws its speed and path; it drives its own route on"}
        return targets, gen.has_density, src, placed
    return None, False, {"kind": "prior", "p_mask": o.p_mask, "applied": False}, None


def _phase(progress: bool, text: str) -> None:
    """One line on stderr as a phase without a progress bar of its own begins (with progress)."""
    if progress:
        print(f"fill: {text} ...", file=sys.stderr, flush=True)


def run(o, folder: str) -> dict:
    from dataclasses import replace

    import shapely

    from ..sim.preflight import preflight
    from ..sim.scenario import ScenarioError, scenario_from_files

    progress = sys.stderr.isatty() or o.verbose
    timing, t = {}, time.perf_counter()
    try:   # the user's inputs judged by SUMO itself before the model is even imported
        scen = preflight(scenario_from_files(o.config, o.net, _files(o.routes), _files(o.additional)))
    except ScenarioError as e:
        raise FillError(str(e)) from None
    from ..core.threads import GENERATION_THREADS, share_cpu
    share_cpu(default=GENERATION_THREADS)   # before torch is imported (core/threads.py: why one)
    from ..data.demand import DemandError, demand_span, seeding_time
    from ..generation.generator import GenerationConfig, ScenarioGenerator
    from ..map.network import Network, NoCarLane
    from ..map.raster import RasterConfig
    from ..sim.lights import initial_light_states
    from ..sim.sumo import SimConfig, settings, step_length_for
    from .output import write_outputs
    from .plan import fill_network, whole_counts
    from .tiles import TileError, tile_grid
    from .workers import tile_engine
    o.step_length = step_length_for(scen, o.step_length)   # the scenario's (sim/sumo.py), the flag over it
    _phase(progress, f"loading {os.path.basename(scen.net)} and the model")
    try:
        net = Network.load(scen.net)
    except NoCarLane as e:
        if not o.config:     # a bare -n: the user chose a network the model cannot use
            raise
        return _nothing_to_fill(folder, o, scen, f"no car lane: {e}")
    routes = list(scen.routes)
    if o.demand_level_only and not routes:
        raise FillError("--demand-level-only: there is no demand (give -r, or -c with route files)")
    begin = o.begin if o.begin is not None else 0.0
    if routes:
        try:
            span = demand_span(routes, {ln.edge for ln in net.lanes}, scen.additional,
                               begin=scen.begin, end=scen.end)
            begin = seeding_time(o.begin, scen.begin, span, routes, config_end=scen.end)
        except DemandError as e:
            raise FillError(str(e)) from None
    try:
        tiles = tile_grid(net, o.area, o.stride, RasterConfig().size)
    except TileError as e:
        raise FillError(str(e)) from None
    if not tiles:
        raise FillError(f"--area: no car lane inside {','.join(f'{v:g}' for v in o.area)} (the network's "
                        f"car lanes span {','.join(f'{v:.0f}' for v in net.bounds)})")
    # a density asked in veh/km (or read from edgeData) is kept as SUMO's edgeData counts it; a
    # demand's vehicles are counted one by one
    gen_cfg = replace(GenerationConfig.from_options(o), count_on_edges=o.density is not None or bool(o.edge_data))
    gen = ScenarioGenerator.load(o.checkpoint, gen_cfg)
    # started here, the workers load their model while this process prepares the rest
    with tile_engine(net, gen, o.workers, o.ray_address, o.checkpoint) as engine:
        if routes:
            _phase(progress, f"routing the demand (duarouter) and estimating its vehicles at {begin:g} s")
        targets, applied, source, demand = _amount(o, net, gen, tiles, routes, begin, scen.additional, scen.options)
        if applied and targets is not None:
            # the counts the tiles' cores keep (generator: round(D x car-lane km)) add up to the total
            kms = [net.car_lane_km_in(shapely.box(*t.core)) for t in tiles]
            targets = whole_counts(targets, kms)
            source["vehicles_planned"] = int(round(sum(d * km for d, km in zip(targets, kms) if d is not None)))
        timing["load"] = time.perf_counter() - t

        cfg = SimConfig(net=scen.net, additional=scen.additional, seed=o.seed, begin=begin, **settings(o, scen))
        t = time.perf_counter()
        # with --signals, the lights as SUMO's programs show them at the start: the fill agrees with them
        signals = initial_light_states(cfg) if net.signal_links and gen.config.signals else None
        timing["lights"] = time.perf_counter() - t
        t = time.perf_counter()
        result = fill_network(net, gen, tiles, seed=o.seed, p_mask=o.p_mask, targets=targets,
                              use_density=applied, area=o.area, progress=progress, signals=signals,
                              engine=engine, demand=demand)
        timing["generate"] = time.perf_counter() - t
    workers = {"count": o.workers, "engine": "ray" if o.ray_address is not None else "local",
               "ray_address": o.ray_address,
               "note": "the fill does not depend on the workers: each tile's noise is its own and the "
                       "model calls are cut from the plan alone"}
    _phase(progress, "seeding the tiles into SUMO, then writing the state and the portable start (each loaded "
                     "once in SUMO)" + ("" if routes else " and the inflow (the filled network driven on to measure it)"))
    doc = write_outputs(folder, o, net, gen, scen, routes, cfg, result, source, timing, progress, workers)
    return doc


def _nothing_to_fill(folder: str, o, scen, why: str) -> dict:
    """A scenario stock SUMO runs on which the model has nowhere to draw a vehicle (a railway): the
    folder holds fill.json alone, saying why; no state, nothing to run (README: bad input)."""
    import json

    from .output import FORMAT, VERSION
    doc = {"format": FORMAT, "version": VERSION, "network": os.path.abspath(scen.net),
           "configuration": scen.config, "begin": o.begin, "seed": o.seed, "nothing_to_generate": why,
           "summary": {"tiles": 0, "kept": 0, "vehicles": 0}, "tiles": [], "agents": [], "files": ["fill.json"]}
    with open(os.path.join(folder, "fill.json"), "w") as f:
        json.dump(doc, f, indent=1)
    return doc


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _user_errors() -> tuple[type, ...]:
    """The errors that are the user's input, one line and exit 2; imported only when one is raised,
    so that a bad input is answered before torch is loaded."""
    from ..core.outputs import OutputError
    from ..core.pool import EngineError
    from ..export.opendrive import ExportError
    from ..map.network import NetworkError
    from ..model.checkpoint import CheckpointError
    from ..sim.sumo import SimError
    from .seed import InflowError
    return FillError, NetworkError, CheckpointError, SimError, OutputError, InflowError, EngineError, ExportError


def main(o) -> int:
    from ..core.outputs import claim, clean_stale, partial_path
    out = os.path.abspath(o.out.rstrip("/") or o.out)
    on_sigterm = signal.signal(signal.SIGTERM, _interrupt)
    owner, complete = None, False
    try:
        if os.path.exists(out) and not o.force and (not os.path.isdir(out) or os.listdir(out)):
            raise FillError(f"-o: {o.out}: exists (choose another output directory or add --force)")
        try:
            os.makedirs(os.path.dirname(out), exist_ok=True)
        except OSError as e:
            up = next((d for d in _parents(out) if os.path.exists(d) and not os.path.isdir(d)), None)
            raise FillError(f"-o: {o.out}: " + (f"{up} is a file, not a folder" if up else
                                                f"its folder cannot be created ({e.strerror or e})")) from None
        clean_stale(os.path.dirname(out), {os.path.basename(out)})   # what dead runs left half-written
        with claim(partial_path(out)) as owner:
            doc = run(o, owner.directory)
            if os.path.lexists(out):
                if not o.force and (not os.path.isdir(out) or os.listdir(out)):
                    raise FillError(f"-o: {o.out}: was written by another run meanwhile")
                shutil.rmtree(out) if os.path.isdir(out) else os.remove(out)
            owner.rename(out)   # complete: only now the folder has its name
            complete = True
            if o.export and not doc.get("nothing_to_generate"):
                from ..export.batch import export_after
                export_after(os.path.dirname(out), [os.path.basename(out)], o.export)
    except Exception as e:
        if not isinstance(e, FillError) and not isinstance(e, _user_errors()):
            raise
        _abandon(owner)
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    except KeyboardInterrupt:
        _abandon(owner)
        o.parser.exit(130, f"{PROG}: interrupted: " + (f"{o.out} was complete and is kept\n" if complete else
                                                       f"nothing written to {o.out}\n"))
    finally:
        signal.signal(signal.SIGTERM, on_sigterm)
    if doc.get("nothing_to_generate"):
        print(f"{PROG}: nothing to generate: {doc['nothing_to_generate']}; wrote "
              f"{os.path.join(o.out, 'fill.json')} (no state: the scenario itself is the start)")
        return 0
    s = doc["summary"]
    why = f"; {s['refused']} refused, fill.json says why" if s["refused"] else ""
    print(f"filled {len(doc['tiles'])} tiles: {s['vehicles']} of {s['kept']} drawn vehicles seeded ({s['placed']} at "
          f"their pose{why}), {s['density_veh_per_km']} veh/km of car lane as SUMO's edgeData counts them "
          f"(+{s['in_junctions']} nosing into junctions); "
          f"density source: {doc['density']['kind']}" + ("" if doc["density"]["applied"] else " (not applied)"))
    print("timing (s): " + ", ".join(f"{k} {v:.1f}" for k, v in doc["timing_s"].items())
          + (f" ({o.workers} workers)" if o.workers > 1 else ""))
    if doc["density"]["kind"] == "demand" and not doc["density"].get("en_route"):
        print(f"warning: no vehicle of the demand is en route at {doc['begin']:g} s (persons and containers "
              f"are not seeded; fill.json's density.departed counts what departed before)", file=sys.stderr)
    asked = doc["density"].get("veh_per_km")
    if asked and s["density_veh_per_km"] < 0.9 * asked:
        print(f"warning: {s['density_veh_per_km']} of the {asked:g} veh/km asked found room (the model "
              f"draws fewer where lanes are full; fill.json has each tile's)", file=sys.stderr)
    print(f"wrote {o.out} (run it: sumo -c {os.path.join(o.out, 'scenario.sumocfg')})")
    return 0


def _parents(path: str):
    while os.path.dirname(path) != path:
        path = os.path.dirname(path)
        yield path


def _abandon(owner) -> None:
    """An unfinished fill leaves nothing behind that could be taken for one."""
    if owner is not None and os.path.basename(owner.directory).count(".partial-"):
        shutil.rmtree(owner.directory, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main(get_options()))
