"""Generate scenes on a SUMO network, seed them as real SUMO vehicles, let SUMO drive, export.

    python -m sumo_scendiff.run -n networks/city.net.xml                      # 4 busy places, 60 s each
    python -m sumo_scendiff.run -n city.net.xml --center 1020,980 --tokens tokens.toml --scenes 8
    python -m sumo_scendiff.run -n city.net.xml -r demand.rou.xml --ego veh42 --gui
    python -m sumo_scendiff.run -n city.net.xml --rollout 0 -o out/       # seed and export only

Without ``--center`` or ``--ego`` the windows are busy, varied places of the network (junctions,
roundabouts, merges; :mod:`~sumo_scendiff.map.locations`). With ``-r`` SUMO first runs that demand
(until the ego appears, or up to ``--begin``) and the vehicles already in a window become agent
tokens: the model fills in around them. Each scene is written to ``OUT/scene_NNN/`` (see the
README, "The scenario folder"): scene.json, scenario.rou.xml, scenario.sumocfg, state.xml.gz,
rollout.json, scene.png; ``OUT/run.json`` sums the run up. One run at a time writes into an output
directory (a second one stops with one line naming the first's pid). An interrupted run (Ctrl-C,
SIGTERM: exit 130; or killed) continues with the same command and ``--resume``: complete scenes are
kept and the missing ones are written exactly as an uninterrupted run would have written them.
"""
from __future__ import annotations

import argparse
import math
import os
import signal

from .scenes import PROG, RunError, run


def _add_place_and_time(p, sumo_time) -> None:
    """Where the scene is (--center/--yaw, --ego) and when (--begin)."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--center", metavar="X,Y", help="window centre in network coordinates")
    p.add_argument("--yaw", type=float, default=0.0, metavar="RAD",
                   help="with --center: the window turned by this angle (radians counter-clockwise from "
                        "east; the window's x axis, the frame of window-frame tokens)")
    where.add_argument("--ego", metavar="ID", help="seed the window around and ahead of this vehicle of "
                       "the demand, once it has driven --ego-after seconds")
    p.add_argument("--ego-after", type=float, default=20.0, metavar="SECONDS",
                   help="with --ego: seconds the ego drives after it departs before seeding (default 20)")
    p.add_argument("-b", "--begin", type=sumo_time, default=None, metavar="TIME",
                   help="the time to seed at, on SUMO's clock (s, or clock time HH:MM:SS as SUMO reads "
                        "it); with demand (-r/-c) and no --ego SUMO runs the demand up to it (default: its "
                        "first departure, or the configuration's begin, + 600 s; it must lie within the "
                        "demand's departures); without demand the time --edge-data is read at")


def _add_what_to_generate(p) -> None:
    """The tokens, the global token and the traffic level."""
    p.add_argument("--tokens", metavar="FILE", help="agent tokens and global token (TOML/JSON, docs/tokens.md)")
    p.add_argument("--p-mask", type=float, default=None, help="global scene token (overrides the token file)")
    amount = p.add_mutually_exclusive_group()
    amount.add_argument("--density", metavar="D|auto|model", default=None,
                        help="vehicles per km of car lane in each window, vehicles already there included; "
                             "'auto': the host simulation's own level around the window (-c/-r), or "
                             "--edge-data's at the seeding time; 'model': the model's own level (default: "
                             "'auto' with demand, else 'model')")
    amount.add_argument("--vehicles", metavar="N", default=None,
                        help="vehicles in each window, those already there included (converted with the "
                             "window's car-lane length)")
    p.add_argument("--edge-data", metavar="FILE", default=None,
                   help="SUMO edgeData (meandata) file giving --density auto its level per edge and time")
    p.add_argument("--scenes", type=int, default=4, help="number of scenes (default 4)")
    p.add_argument("-s", "--seed", type=int, default=0)


def _add_simulation_and_output(p) -> None:
    """How SUMO runs and where the scenes go."""
    from ..sim.sumo import add_arguments
    p.add_argument("--rollout", type=float, default=60.0, help="seconds SUMO drives after seeding (0: none)")
    p.add_argument("--replay-future", type=float, default=0.0, metavar="SECONDS",
                   help="hold the agents on their generated 0..+2 s future before SUMO takes over (max 2)")
    add_arguments(p)       # --step-length, --lateral-resolution, --no-seeding-options
    p.add_argument("--gui", action="store_true", help="watch in sumo-gui (traci)")
    p.add_argument("--traci", action="store_true",
                   help="SUMO as a process of its own through traci, not libsumo in this one (slower): a SUMO "
                        "that crashes or is killed ends the run in one line with its last words")
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("-o", "--output-dir", dest="out", default="scendiff-out")
    again = p.add_mutually_exclusive_group()
    again.add_argument("--force", action="store_true", help="replace scene folders of an earlier run in -o")
    again.add_argument("--resume", action="store_true",
                       help="continue an interrupted run in -o (same command): its complete scenes are "
                            "kept, the missing ones written as the whole run would have written them")
    p.add_argument("--export", choices=("openscenario",), default=None,
                   help="also write each scene as OpenSCENARIO + OpenDRIVE (docs/openscenario.md)")
    p.add_argument("-v", "--verbose", action="store_true")


def _problems(o):
    """The flags out of range or in conflict, each as one line, in the order the checks run
    (get_options reports the first); parses --density and --vehicles on the way."""
    from ..generation.config import GenerationConfig, SettingError
    from ..sim.density import DensityError, parse_density, parse_vehicles
    from ..sim.scenario import input_flags_problem
    from ..sim.sumo import settings_problem
    yield input_flags_problem(o.net, o.config)
    if o.ego and not (o.routes or o.config):
        yield "--ego needs demand (-r/--route-files or -c) for the ego to drive in"
    try:
        o.density, o.vehicles = parse_density(o.density), parse_vehicles(o.vehicles)
    except DensityError as e:
        yield str(e)
    if o.edge_data and o.density != "auto":
        yield "--edge-data: needs --density auto (it sets the level --density auto reads)"
    if o.yaw and not o.center:
        yield "--yaw: turns a --center window; give --center X,Y with it"
    if not math.isfinite(o.yaw):
        yield f"--yaw must be a finite angle in radians, got {o.yaw}"
    if not o.ego_after >= 0:
        yield f"--ego-after must be >= 0 seconds, got {o.ego_after}"
    if o.begin is not None and o.ego:
        yield "--begin: with --ego the scene is seeded when the ego has driven --ego-after seconds; give one of them"
    if o.scenes < 1:
        yield "--scenes must be >= 1"
    if o.rollout < 0:
        yield "--rollout must be >= 0"
    yield settings_problem(o)
    try:
        GenerationConfig.from_options(o)
    except SettingError as e:
        yield str(e)
    if not 0.0 <= o.replay_future <= 2.0:
        yield f"--replay-future must be in [0, 2] seconds, got {o.replay_future}"
    if o.p_mask is not None and not 0.0 <= o.p_mask <= 1.0:
        yield f"--p-mask must be in [0, 1], got {o.p_mask}"


def get_options(args=None):
    from ..core.cli import HelpFormatter, description, epilog, joined, sumo_time
    from ..generation.config import GenerationConfig
    from ..sim.scenario import add_input_arguments
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), epilog=epilog(__doc__),
                                formatter_class=HelpFormatter)
    add_input_arguments(p, config="a SUMO scenario as its authors ship it (.sumocfg: network, route files, "
                                  "additional files, begin); -n/-r/-a replace what it names",
                        routes="demand to run first (comma-separated route files, vTypes-only files allowed); "
                               "its vehicles in a window are kept and the model fills in around them",
                        additional="comma-separated additional files (vTypes, TLS programs, detectors, stops)")
    _add_place_and_time(p, sumo_time)
    _add_what_to_generate(p)
    _add_simulation_and_output(p)
    GenerationConfig.add_arguments(p)
    o = p.parse_args(joined(p, args))   # --center -5,3: a negative coordinate is not a flag
    problem = next((line for line in _problems(o) if line), None)
    if problem:
        p.error(problem)
    o.parser = p
    return o


def print_summary(summary: dict) -> None:
    from ..sim.seeding import STATUSES
    rows = summary["scenes"]
    rolled = any(r.get("seconds", 0) > 0 for r in rows)
    wide = max([11] + [len(str(r["location"])) for r in rows])
    print(f"{'scene':10} {'where':{wide}} {'kept':>5} {'generated':>9} {'placed':>6} {'misplaced':>9} "
          f"{'refused':>7} {'existing':>8} {'dropped':>7} {'veh/km':>6} {'collisions':>10} {'teleports':>9} {'e-brakes':>8} {'speed':>6}")
    for r in rows:
        density = "–" if r.get("density_veh_per_km") is None else f"{r['density_veh_per_km']:.0f}"
        speed = f"{r['mean_speed']:6.1f}" if rolled else f"{'–':>6}"
        print(f"{r['scene']:10} {r['location']:{wide}} {r['existing_vehicles']:5d} {r['generated']:9d} "
              f"{r['placed']:6d} {r['misplaced']:9d} {r['refused']:7d} {r.get('existing', 0):8d} {r.get('dropped', 0):7d} {density:>6} "
              f"{r['collisions']:10d} {r['teleports']:9d} {r['emergency_brakes']:8d} {speed}")
    gen = sum(r["generated"] for r in rows)
    n = {s: sum(r.get(s, 0) for r in rows) for s in STATUSES}
    new = gen - n["existing"]   # the model's copies of the vehicles kept are theirs, not new traffic
    print(f"of {gen} generated agents: placed {n['placed']} ({100.0 * n['placed'] / max(new, 1):.1f} % of the "
          f"{new} new) at their pose, misplaced {n['misplaced']}, refused by SUMO {n['refused']}, dropped "
          f"{n['dropped']}" + (f", {n['existing']} the model's copies of vehicles already there (kept, the copies "
                               "not added)" if n["existing"] else "") + "; "
          f"beside {sum(r['existing_vehicles'] for r in rows)} vehicles kept from the simulation; "
          f"timing (s): " + ", ".join(f"{k} {v:.2f}" for k, v in summary["timing_s"].items()))
    print(f"wrote {len(rows)} scenario folders and run.json to {summary['output_dir']} "
          f"(open one with: sumo-gui -c {os.path.join(summary['output_dir'], rows[0]['scene'], 'scenario.sumocfg')})")


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # SIGTERM ends a run as Ctrl-C does: complete scenes are kept


def _user_errors() -> tuple[type, ...]:
    """The errors that are the user's input, one line and exit 2; imported only when one is raised,
    so that a bad input is answered before torch is loaded."""
    from ..core.outputs import OutputError
    from ..export.opendrive import ExportError
    from ..map.locations import LocationError
    from ..map.network import NetworkError
    from ..model.checkpoint import CheckpointError
    from ..sim.sumo import SimError
    from ..sim.warmup import WarmUpError
    from ..tokens.file import TokenFileError
    return (RunError, NetworkError, CheckpointError, SimError, TokenFileError, LocationError,
            FileExistsError, OutputError, ExportError, WarmUpError)


def main(o) -> int:
    from ..core.outputs import claim
    on_sigterm = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with claim(o.out):   # first of all: a second run into -o stops here, before any work
            summary = run(o)
            if o.export and summary["scenes"]:
                from ..export.batch import export_after
                export_after(o.out, [r["scene"] for r in summary["scenes"]], o.export)
    except Exception as e:
        if not isinstance(e, (RunError, FileExistsError)) and not isinstance(e, _user_errors()):
            raise
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    except KeyboardInterrupt:
        done = sum(os.path.isdir(os.path.join(o.out, f"scene_{k:03d}")) for k in range(o.scenes))
        o.parser.exit(130, f"{PROG}: interrupted: {done} of {o.scenes} scenes are complete in {o.out}; "
                           f"rerun with --resume to write the others\n")
    finally:
        signal.signal(signal.SIGTERM, on_sigterm)
    if summary.get("nothing_to_generate"):
        print(f"{PROG}: nothing to generate: {summary['nothing_to_generate']}; wrote "
              f"{os.path.join(summary['output_dir'], 'run.json')} (no scene)")
        return 0
    print_summary(summary)
    return 0
