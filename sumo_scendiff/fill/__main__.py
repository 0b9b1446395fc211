"""Fill a whole SUMO network with generated traffic: a filled start for stock SUMO.

    python -m sumo_scendiff.fill -n city.net.xml -o filled/                 # the model's prior
    python -m sumo_scendiff.fill -n city.net.xml --density 25 -o filled/    # needs a density model
    python -m sumo_scendiff.fill -c scenario.sumocfg --begin 28800 -o filled/
    python -m sumo_scendiff.fill -n city.net.xml --workers 1 -o filled/    # the same fill, 1 process
    sumo -c filled/scenario.sumocfg        # from the saved state;  filled/start.sumocfg: portable

Overlapping 100 m tiles (--stride apart) cover every car lane (or --area); they are generated in
four batches of tiles that do not overlap, each tile around the vehicles its earlier neighbours
own inside it (pinned tokens), and keep the vehicles of their own core cell (docs/fill.md).
Writes -o DIR (under DIR.partial-<pid> until complete): fill.json, state.xml.gz, scenario.sumocfg,
start.rou.xml, start.sumocfg, fill.png, and without demand inflow.rou.xml.
"""
from __future__ import annotations

import argparse
import signal
import sys

from .api import FillError, FillRequest, Interrupted

PROG = "python -m sumo_scendiff.fill"


def _parser():
    from ..core.cli import HelpFormatter, description, epilog, sumo_time
    from ..generation.config import GenerationConfig
    from ..sim.sumo import add_arguments
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), epilog=epilog(__doc__),
                                formatter_class=HelpFormatter)
    p.add_argument("-c", "--configuration-file", dest="config", metavar="FILE",
                   help="a SUMO scenario (.sumocfg); its demand sets how much traffic and continues after the start")
    p.add_argument("-n", "--net-file", "--net", dest="net", help="SUMO network (.net.xml[.gz])")
    p.add_argument("-r", "--route-files", "--routes", dest="routes", default=None,
                   help="demand (comma-separated route files): its vehicles en route at --begin set the "
                        "density, and it continues after the start")
    p.add_argument("-a", "--additional-files", dest="additional", default=None,
                   help="comma-separated additional files (vTypes, TLS programs; vehicles, flows or persons "
                        "in them are demand, as -r's)")
    p.add_argument("-b", "--begin", type=sumo_time, default=None, metavar="TIME",
                   help="the time of the filled start (s, or clock time HH:MM:SS as SUMO reads it); with "
                        "demand default: its first departure + 600, and it must lie within the demand's "
                        "departures")
    p.add_argument("--area", metavar="X0,Y0,X1,Y1", help="fill only this rectangle (network coordinates; with demand: "
                   "the vehicles of SUMO's own run whose centre lies in it)")
    p.add_argument("--stride", type=float, default=75.0, help="metres between tile centres (default 75)")
    amount = p.add_mutually_exclusive_group()
    amount.add_argument("--density", metavar="D", help="vehicles per km of car lane (needs a model with "
                        "the density condition; --p-mask is the fallback)")
    amount.add_argument("--edge-data", metavar="FILE", help="SUMO edgeData file: each tile's density at --begin")
    p.add_argument("--demand-level-only", action="store_true",
                   help="with demand: take only its level per tile and let the model place the vehicles "
                        "(default: the demand's own vehicles where the estimate has them, on their own routes)")
    p.add_argument("--demand-estimate", action="store_true",
                   help="with demand: the model fills the network from an estimate of the demand's vehicles "
                        "at --begin, without simulating (fill/demand.py; default: SUMO runs the scenario to "
                        "--begin, as fast as stock SUMO and exact, its state kept for the next time)")
    p.add_argument("--p-mask", type=float, default=1.0, metavar="P",
                   help="global token of a tile without neighbours (default 1: the model's prior; lower: fewer vehicles)")
    p.add_argument("-s", "--seed", type=int, default=0,
                   help="the model's seed (its draws); SUMO's own run of a demand keeps the configuration's "
                        "seed (default: SUMO's)")
    add_arguments(p)       # --step-length, --lateral-resolution, --no-seeding-options
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes generating the tiles side by side, each loading the model once (default: "
                        "one per core; 1: this one); the same seed gives the same fill with any number")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="generate on --workers Ray actors of the cluster at ADDR (HOST:PORT, auto; local: "
                        "a new local instance); they read the network and checkpoint at the same paths")
    p.add_argument("-o", "--output-dir", dest="out", default="filled")
    p.add_argument("--force", action="store_true", help="replace an existing -o")
    p.add_argument("--export", choices=("openscenario",), default=None,
                   help="also write the fill as OpenSCENARIO + OpenDRIVE, its Init (docs/openscenario.md)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("-v", "--verbose", action="store_true", help="SUMO's warnings too")
    GenerationConfig.add_arguments(p)
    # bad input is one line naming the flag (argparse would print its usage first)
    p.error = lambda message: p.exit(2, f"{PROG}: error: {message}\n")
    return p


def _problem(o) -> str | None:
    """What is wrong with the parsed flags (one line naming the flag), or None; parses --density
    and --area in place."""
    from ..generation.config import GenerationConfig, SettingError
    from ..sim.density import DensityError, parse_density
    from ..sim.scenario import input_flags_problem
    from ..sim.sumo import settings_problem
    from .tiles import TileError, parse_area
    if input_flags_problem(o.net, o.config):
        return input_flags_problem(o.net, o.config)
    try:
        o.density = parse_density(o.density)
        o.area = parse_area(o.area)
    except (DensityError, TileError) as e:
        return str(e)
    if o.density == "auto":
        return "--density: 'auto' is not a fill's level; give --edge-data, demand (-c/-r), or a number"
    if not 0.0 < o.p_mask <= 1.0:
        return f"--p-mask must be in (0, 1], got {o.p_mask}"
    if o.workers is not None and o.workers < 1:
        return f"--workers must be >= 1, got {o.workers}"
    if o.ray_address is not None:
        from ..core.pool import EngineError, import_ray
        try:
            import_ray("--ray-address")
        except EngineError as e:
            return str(e)
    try:
        o.generation = GenerationConfig.from_options(o)
    except SettingError as e:
        return str(e)
    return settings_problem(o)


def get_options(args=None):
    from ..core.cli import joined
    p = _parser()
    o = p.parse_args(joined(p, args))   # --area -100,-50,...: a negative coordinate is not a flag
    problem = _problem(o)
    if problem:
        p.error(problem)
    o.parser = p
    return o


def _files(arg: str | None) -> tuple[str, ...]:
    return tuple(f for f in (arg or "").split(",") if f)


def request(o) -> FillRequest:
    """The library's request of the parsed flags."""
    return FillRequest(net=o.net, config=o.config, routes=_files(o.routes), additional=_files(o.additional),
                       begin=o.begin, area=o.area, stride=o.stride, density=o.density, edge_data=o.edge_data,
                       demand_level_only=o.demand_level_only, p_mask=o.p_mask, seed=o.seed,
                       step_length=o.step_length, lateral_resolution=o.lateral_resolution,
                       seeding_options=o.seeding_options, model_fleet=o.model_fleet, checkpoint=o.checkpoint,
                       workers=o.workers, ray_address=o.ray_address, export=o.export, verbose=o.verbose,
                       generation=o.generation, progress=not o.quiet, demand_estimate=o.demand_estimate)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def main(o) -> int:
    from .api import fill_request, user_errors
    on_sigterm = signal.signal(signal.SIGTERM, _interrupt)
    try:
        done = fill_request(request(o), o.out, o.force)
    except Interrupted as e:
        return _exit(o, 130, f"{PROG}: interrupted: " + (f"{o.out} was complete and is kept\n" if e.complete
                                                          else f"nothing written to {o.out}\n"))
    except Exception as e:
        if not isinstance(e, FillError) and not isinstance(e, user_errors()):
            raise
        return _exit(o, 2, f"{PROG}: error: {e}\n")
    finally:
        signal.signal(signal.SIGTERM, on_sigterm)
    _report(o, done.doc)
    return 0


def _exit(o, code: int, message: str) -> int:
    o.parser.exit(code, message)
    return code


def _headline(doc: dict) -> str:
    """Where the start's vehicles came from: SUMO's own run of the demand (the model fills no tile
    there: SUMO's vehicles are the start), else the tiles the model filled and what it drew."""
    s = doc["summary"]
    why = f"; {s['refused']} refused, fill.json says why" if s["refused"] else ""
    if doc["density"].get("start") == "sumo":
        return (f"started from SUMO's own run of the demand to {doc['begin']:g} s: {s['vehicles']} of its "
                f"{s['kept']} vehicles{' in the area' if doc.get('area') else ''} are in the start{why}; "
                f"the model filled no tile (SUMO's run gives every vehicle)")
    return (f"filled {len(doc['tiles'])} tiles: {s['vehicles']} of {s['kept']} drawn vehicles seeded ({s['placed']} at "
            f"their pose{why})")


def _report(o, doc: dict) -> None:
    """What the fill did, on stdout (warnings on stderr)."""
    import os
    from ..sim.scenario import meso_notice
    if meso_notice(o.config, fill=True):
        print(f"{PROG}: warning: {meso_notice(o.config, fill=True)}", file=sys.stderr)
    if (doc.get("start_model") or {}).get("reason"):    # SUMO refused the start in its mesoscopic model
        print(f"{PROG}: warning: {os.path.join(o.out, 'start.sumocfg')}: microscopic too: SUMO's mesoscopic "
              f"model refused it: {doc['start_model']['reason']}", file=sys.stderr)
    if doc.get("nothing_to_generate"):
        print(f"{PROG}: nothing to generate: {doc['nothing_to_generate']}; wrote "
              f"{os.path.join(o.out, 'fill.json')} (no state: the scenario itself is the start)")
        return
    s = doc["summary"]
    print(_headline(doc) + f", {s['density_veh_per_km']} veh/km of car lane as SUMO's edgeData counts them "
          f"(+{s['in_junctions']} nosing into junctions); density source: {doc['density']['kind']}"
          + ("" if doc["density"]["applied"] else " (not applied)"))
    workers = (doc.get("workers") or {}).get("count")
    print("timing (s): " + ", ".join(f"{k} {v:.1f}" for k, v in doc["timing_s"].items())
          + (f" ({workers} worker{'s' if workers > 1 else ''})" if workers else ""))
    inside = doc["density"].get("vehicles", {}).get("in_area") if doc["density"].get("start") == "sumo" else None
    if inside is not None:
        print(f"--area: {inside} of the {doc['density']['en_route']} vehicles SUMO has on the network at "
              f"{doc['begin']:g} s lie in it (box centre), the others taken out of the start")
    if doc["density"]["kind"] == "demand" and not doc["density"].get("en_route"):
        print(f"warning: no vehicle of the demand is en route at {doc['begin']:g} s (persons and containers "
              f"are not seeded; fill.json's density.departed counts what departed before)", file=sys.stderr)
    asked = doc["density"].get("veh_per_km")
    if asked and s["density_veh_per_km"] < 0.9 * asked:
        print(f"warning: {s['density_veh_per_km']} of the {asked:g} veh/km asked found room (the model "
              f"draws fewer where lanes are full; fill.json has each tile's)", file=sys.stderr)
    print(f"wrote {o.out} (run it: sumo -c {os.path.join(o.out, 'scenario.sumocfg')})")


if __name__ == "__main__":
    sys.exit(main(get_options()))
