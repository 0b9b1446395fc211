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
import json
import math
import os
import signal
import sys
import time

PROG = "python -m sumo_scendiff.run"
EGO_AHEAD_M = 25.0   # the ego window's centre ahead of the ego: it sees its own lane 75 m ahead


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
    from .sim.sumo import add_arguments
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
    from .generation.config import GenerationConfig, SettingError
    from .sim.density import DensityError, parse_density, parse_vehicles
    from .sim.scenario import input_flags_problem
    from .sim.sumo import settings_problem
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
    from .core.cli import HelpFormatter, description, epilog, joined, sumo_time
    from .generation.config import GenerationConfig
    from .sim.scenario import add_input_arguments
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


class RunError(Exception):
    """A problem with the user's input that stops the run (exit code 2, one line)."""


def _check_output(o) -> set[str]:
    """Called as the owner of -o (main claims it). Returns the scenes kept from an earlier run
    (--resume: those complete, i.e. under their final name); removes what dead runs left half-written."""
    from .core.outputs import clean_stale
    names = [f"scene_{k:03d}" for k in range(o.scenes)] + ["run.json"]
    clean_stale(o.out, set(names))
    taken = [n for n in names if os.path.exists(os.path.join(o.out, n))]
    if taken and not (o.force or o.resume):
        raise RunError(f"{os.path.join(o.out, taken[0])}: exists (choose another --output-dir, "
                       f"add --resume to continue that run or --force to replace it)")
    return {n for n in taken if n != "run.json"} if o.resume else set()


def _check_kept(o, kept: set[str], windows) -> None:
    """--resume: the kept scenes must be this run's (same windows and seed), not another command's."""
    for k, w in enumerate(windows):
        name = f"scene_{k:03d}"
        if name not in kept:
            continue
        with open(os.path.join(o.out, name, "scene.json")) as f:
            doc = json.load(f)
        if doc.get("seed") != o.seed or doc.get("window") != {"cx": w.cx, "cy": w.cy, "yaw": w.yaw, "size": w.size}:
            raise RunError(f"{os.path.join(o.out, name)}: written by another command (other seed or window); "
                           f"--resume needs the interrupted run's own options")


def _files(arg: str | None) -> list[str]:
    return [f for f in (arg or "").split(",") if f]


def _counts(net, window, row: dict) -> dict:
    """The window's traffic after seeding in traffic terms: vehicles kept from the host simulation,
    generated ones seeded, and their density per km of car lane."""
    from .core.scene import per_km
    km = net.car_lane_km(window)
    total = row["existing_vehicles"] + row["placed"]
    density = per_km(total, km)
    return {**row, "vehicles_in_window": total, "car_lane_km": round(km, 4),
            "density_veh_per_km": None if density is None else round(density, 2)}


def _edge_data(o, net):
    from .map.edgedata import EdgeData, EdgeDataError
    try:
        return EdgeData.read(o.edge_data, net) if o.edge_data else None
    except EdgeDataError as e:
        raise RunError(f"--edge-data: {e}") from None


def _level(o, density) -> str | None:
    """The traffic level of run.json: as asked, or the default one says it is the default."""
    if o.vehicles is not None:
        return f"vehicles {o.vehicles}"
    if density is None:
        return "model"
    return density if o.density is not None else f"{density} (default with demand)"


def _requests(o, net, session, windows, spec, gen, edge_data, host: bool) -> list:
    """Each window's request to the generator (sim/request.py): the user's tokens, the vehicles
    already there, p_mask, density target and lights, as the simulation shows them at the seeding
    time; the user's tokens heading against their road warned about, one line each."""
    from .map.edgedata import EdgeDataError
    from .sim.fleet import Fleet
    from .sim.request import DensityUnsupported, window_request
    fleet = Fleet.read(session.sim)    # a token's vtype: one of the scenario's, its size
    asked_p_mask = o.p_mask if o.p_mask is not None else spec.asked_p_mask() if spec else None
    out = []
    try:
        for k, w in enumerate(windows):
            existing = session.existing(w)
            req = window_request(net, session.sim, w, existing, spec.for_window(w) if spec else [],
                                 source=spec.source if spec else "tokens", fleet=fleet,
                                 p_mask=asked_p_mask, density=o.density, vehicles=o.vehicles, host=host,
                                 has_density=gen.has_density, edge_data=edge_data,
                                 signals=gen.config.signals)
            for line in req.warnings:
                print(f"{PROG}: warning: scene_{k:03d}: {o.tokens}: {line}", file=sys.stderr)
            out.append(req)
    except EdgeDataError as e:
        raise RunError(f"--edge-data: {e}") from None
    except DensityUnsupported:
        raise RunError(f"--density/--vehicles: {o.checkpoint or 'the shipped model'} has no density "
                       f"condition (trained before it); leave them out or use a newer model") from None
    return out


def _wait_for_ego(sim, o, progress: bool) -> None:
    """Run the demand until the ego is on the road and has driven ``--ego-after`` seconds."""
    from tqdm import tqdm
    dt = sim.simulation.getDeltaT()
    bar = tqdm(desc=f"waiting for {o.ego}", unit=" s", disable=not progress, leave=False)
    while o.ego not in sim.vehicle.getIDList():
        if sim.simulation.getMinExpectedNumber() == 0:
            raise RunError(f"--ego: vehicle {o.ego!r} never appears (the demand ended at "
                           f"t = {sim.simulation.getTime():.0f} s)")
        sim.simulationStep()
        bar.update(dt)
    # at its departure the ego stands at the network's fringe with nothing around it: seed once
    # it has driven into the network
    for k in range(int(round(o.ego_after / dt))):
        sim.simulationStep()
        bar.update(dt)
        if o.ego not in sim.vehicle.getIDList():
            raise RunError(f"--ego-after: vehicle {o.ego!r} left the network {(k + 1) * dt:.0f} s after "
                           f"it departed; give a smaller --ego-after")
    bar.close()


def _windows(o, net, sim, cosim):
    from .map.locations import auto_windows, parse_center, window_at
    if o.ego:
        w = cosim.ego_window(o.ego, ahead_m=EGO_AHEAD_M)
        return [(w, "ego")] * o.scenes
    if o.center:
        x, y = parse_center(o.center)
        return [(window_at(net, x, y, yaw=o.yaw), "center")] * o.scenes
    return [(loc.window, loc.kind) for loc in auto_windows(net, o.scenes, seed=o.seed)]


def _scenario(o):
    """The user's inputs as SUMO reads them, and SUMO judging them (its preflight, a Future: the
    network loads meanwhile; :func:`_verdict` takes it before the model is even imported)."""
    from concurrent.futures import ThreadPoolExecutor

    from .sim.preflight import preflight
    from .sim.scenario import ScenarioError, meso_notice, scenario_from_files
    try:
        scen = scenario_from_files(o.config, o.net, _files(o.routes), _files(o.additional))
    except ScenarioError as e:
        raise RunError(str(e)) from None
    if meso_notice(o.config):
        print(f"{PROG}: warning: {meso_notice(o.config)}", file=sys.stderr)
    pool = ThreadPoolExecutor(max_workers=1)   # its thread mostly waits for SUMO's process
    judged = pool.submit(preflight, scen)
    pool.shutdown(wait=False)
    return scen, judged


def _verdict(judged) -> None:
    """SUMO's refusal of the inputs as the run's error (it comes first, whatever else failed)."""
    from .sim.scenario import ScenarioError
    try:
        judged.result()
    except ScenarioError as e:
        raise RunError(str(e)) from None


def _demand_times(o, scen, net, demand: list[str]) -> tuple[float | None, float | None]:
    """(the time SUMO starts at, the seeding time it runs the demand up to; None: the ego decides,
    or there is no demand), as :func:`_session` says. ``demand``: the files holding it
    (``data.demand.demand_files``: route files, and additional files with vehicles in them)."""
    from .data.demand import DemandError, demand_span, seeding_time
    if not demand:
        return (o.begin if o.begin is not None else scen.begin), None
    try:  # the route files as the set SUMO loads, against this network
        span = demand_span(scen.routes, {ln.edge for ln in net.lanes}, scen.additional,
                           begin=scen.begin, end=scen.end)
        at = seeding_time(o.begin, scen.begin, span, demand, config_end=scen.end) if span and not o.ego else None
    except DemandError as e:
        raise RunError(str(e)) from None
    first = span[0] if span else None
    return (scen.begin if scen.begin is not None else first), at


def _session(o, scen, net, gen, sumo_settings: dict, times: tuple, progress: bool, demand: list[str]):
    """The simulation of the scenario and the warm-up that runs its demand up to the seeding time
    (sim/session.py); with demand SUMO starts at the configuration's begin, else the demand's first
    departure (before it the network is empty), and without demand at --begin."""
    from .sim.session import Session
    from .sim.sumo import SimConfig
    begin, at = times
    cfg = SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional, gui=o.gui, traci=o.traci,
                    seed=o.seed, begin=begin, **sumo_settings)
    session = Session(cfg, net, gen, quiet=not o.verbose, model_fleet=o.model_fleet)
    if not demand:
        return session, session.prepare
    if o.ego:
        return session, lambda: session.prepare(lambda sim: _wait_for_ego(sim, o, progress))
    if progress:
        print(f"running the demand to t = {at:g} s as SUMO runs it (its state kept for the next run)",
              file=sys.stderr)
    return session, lambda: session.prepare_at(at)


def _generate(o, net, gen, requests, progress: bool, timing: dict) -> list:
    """The scenes of ``requests``, their map rasters drawn with the lights each scene meets."""
    import numpy as np

    from .map.raster import render_map
    from .sim.request import generation_inputs
    t = time.perf_counter()
    windows = [r.window for r in requests]
    maps = np.stack([render_map(net, r.window, gen.raster, signals=r.lights) for r in requests])
    timing["raster"] = time.perf_counter() - t
    t = time.perf_counter()
    scenes = gen.generate(net, windows, seed=o.seed, maps=maps, progress=progress,
                          **generation_inputs(requests))
    timing["generate"] = time.perf_counter() - t
    return scenes


def _realise(o, net, gen, session, places, requests, scenes, kept: set[str], progress: bool) -> list[dict]:
    """Seed, export and roll out each scene (--resume: a kept scene's row read back)."""
    from tqdm import tqdm
    results = []
    for k in tqdm(range(len(scenes)), desc="seeding and rolling out", disable=not progress):
        name, req = f"scene_{k:03d}", requests[k]
        head = {"scene": name, "location": places[k][1], "target_veh_per_km": req.target}
        if name in kept:  # --resume: generated in the same batch as now, so the same scene
            with open(os.path.join(o.out, name, "rollout.json")) as f:
                results.append({**head, **_counts(net, req.window, json.load(f))})
            continue
        info = {"scene": name, "location": places[k][1], "window_index": k,
                "target_veh_per_km": req.target, "model": gen.config.record(gen),
                "sumo_options": session.cfg.options()}
        row = session.realise(scenes[k], req.tokens, req.sources, req.existing, o.out, name, info,
                              o.rollout, seed=o.seed, p_mask=req.p_mask, force=o.force,
                              replay=o.replay_future)
        _warn_lost(o, name, row)
        results.append({**head, **_counts(net, req.window, row)})
    return results


def run(o) -> dict:
    t = time.perf_counter()
    scen, judged = _scenario(o)
    from .data.demand import demand_files
    from .map.network import Network, NoCarLane
    from .sim.sumo import settings
    from .tokens.file import load_tokens
    progress = sys.stderr.isatty() or o.verbose
    try:
        sumo_settings = settings(o, scen)     # the scenario's step length and options, the flags over them
        net = Network.load(scen.net)
    except NoCarLane as e:
        _verdict(judged)
        if not o.config:     # a bare -n: the user chose a network the model cannot use
            raise
        return _nothing_to_generate(o, scen, f"no car lane: {e}")
    except Exception:
        _verdict(judged)
        raise
    _verdict(judged)
    demand = demand_files(scen.routes, scen.additional)
    times = _demand_times(o, scen, net, demand)   # the demand's problems before the model is loaded
    edge_data = _edge_data(o, net)
    spec = load_tokens(o.tokens, net=net) if o.tokens else None
    kept = _check_output(o)
    from .core.threads import GENERATION_THREADS, share_cpu
    threads = share_cpu(default=GENERATION_THREADS)   # before torch is imported (core/threads.py: why one)
    from .generation.generator import GenerationConfig, ScenarioGenerator
    from .sim.density import default_density, host_has_traffic
    from .sim.request import counted_as_asked
    gen = ScenarioGenerator.load(o.checkpoint, counted_as_asked(GenerationConfig.from_options(o), o.vehicles))
    session, prepare = _session(o, scen, net, gen, sumo_settings, times, progress, demand)
    timing = {}
    try:
        prepare()
        places = _windows(o, net, session.sim, session.cosim())
        _check_kept(o, kept, [w for w, _ in places])
        host = bool(demand)
        level = _level(o, default_density(o.density, o.vehicles, host and host_has_traffic(session.sim),
                                          gen.has_density))
        requests = _requests(o, net, session, [w for w, _ in places], spec, gen, edge_data, host)
        timing["load"] = time.perf_counter() - t
        scenes = _generate(o, net, gen, requests, progress, timing)
        results = _realise(o, net, gen, session, places, requests, scenes, kept, progress)
        timing.update(session.timing)
    finally:
        session.close()
    summary = {"network": scen.net, "configuration": scen.config, "output_dir": os.path.abspath(o.out),
               "model_sha256": gen.sha256, "seed": o.seed, "threads": threads,
               "fleet": "model" if o.model_fleet else "scenario",
               "density": level, "scenes": results, "timing_s": {k: round(v, 3) for k, v in timing.items()}}
    return _write_summary(o, summary)


def _write_summary(o, summary: dict) -> dict:
    from .core.outputs import partial_path
    tmp = partial_path(os.path.join(o.out, "run.json"))
    with open(tmp, "w") as f:
        json.dump(summary, f, indent=1)
    os.replace(tmp, os.path.join(o.out, "run.json"))
    return summary


def _nothing_to_generate(o, scen, why: str) -> dict:
    """A scenario stock SUMO runs on which the model has nowhere to draw a vehicle (a railway): no
    window can be placed, so no scene folder; run.json says why (README: bad input)."""
    _check_output(o)
    return _write_summary(o, {"network": scen.net, "configuration": scen.config,
                              "output_dir": os.path.abspath(o.out), "seed": o.seed, "scenes": [],
                              "nothing_to_generate": why, "timing_s": {}})


def _warn_lost(o, name: str, row: dict) -> None:
    """One warning line per token of the user's that gives no vehicle (README: every token is placed
    or named)."""
    for k, why in row.get("user_tokens_lost", {}).items():
        print(f"{PROG}: warning: {name}: {o.tokens}: token {k}: no vehicle: {why}", file=sys.stderr)


def print_summary(summary: dict) -> None:
    from .sim.seeding import STATUSES
    rows = summary["scenes"]
    rolled = any(r.get("seconds", 0) > 0 for r in rows)
    wide = max([11] + [len(str(r["location"])) for r in rows])
    print(f"{'scene':10} {'where':{wide}} {'kept':>5} {'generated':>9} {'placed':>6} {'misplaced':>9} "
          f"{'refused':>7} {'dropped':>7} {'veh/km':>6} {'collisions':>10} {'teleports':>9} {'e-brakes':>8} {'speed':>6}")
    for r in rows:
        density = "–" if r.get("density_veh_per_km") is None else f"{r['density_veh_per_km']:.0f}"
        speed = f"{r['mean_speed']:6.1f}" if rolled else f"{'–':>6}"
        print(f"{r['scene']:10} {r['location']:{wide}} {r['existing_vehicles']:5d} {r['generated']:9d} "
              f"{r['placed']:6d} {r['misplaced']:9d} {r['refused']:7d} {r.get('dropped', 0):7d} {density:>6} "
              f"{r['collisions']:10d} {r['teleports']:9d} {r['emergency_brakes']:8d} {speed}")
    gen = sum(r["generated"] for r in rows)
    n = {s: sum(r.get(s, 0) for r in rows) for s in STATUSES}
    copies = sum(r.get("copies_of_existing", 0) for r in rows)
    new = gen - copies          # the model's copies of the vehicles kept are theirs, not new traffic
    print(f"of {gen} generated agents: placed {n['placed']} ({100.0 * n['placed'] / max(new, 1):.1f} % of the "
          f"{new} new) at their pose, misplaced {n['misplaced']}, refused by SUMO {n['refused']}, dropped "
          f"{n['dropped']}" + (f" ({copies} the model's copies of vehicles already there)" if copies else "") + "; "
          f"beside {sum(r['existing_vehicles'] for r in rows)} vehicles kept from the simulation; "
          f"timing (s): " + ", ".join(f"{k} {v:.2f}" for k, v in summary["timing_s"].items()))
    print(f"wrote {len(rows)} scenario folders and run.json to {summary['output_dir']} "
          f"(open one with: sumo-gui -c {os.path.join(summary['output_dir'], rows[0]['scene'], 'scenario.sumocfg')})")


def _interrupt(signum, frame):
    raise KeyboardInterrupt  # SIGTERM ends a run as Ctrl-C does: complete scenes are kept


def _user_errors() -> tuple[type, ...]:
    """The errors that are the user's input, one line and exit 2; imported only when one is raised,
    so that a bad input is answered before torch is loaded."""
    from .core.outputs import OutputError
    from .export.opendrive import ExportError
    from .map.locations import LocationError
    from .map.network import NetworkError
    from .model.checkpoint import CheckpointError
    from .sim.sumo import SimError
    from .sim.warmup import WarmUpError
    from .tokens.file import TokenFileError
    return (RunError, NetworkError, CheckpointError, SimError, TokenFileError, LocationError,
            FileExistsError, OutputError, ExportError, WarmUpError)


def main(o) -> int:
    from .core.outputs import claim
    on_sigterm = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with claim(o.out):   # first of all: a second run into -o stops here, before any work
            summary = run(o)
            if o.export and summary["scenes"]:
                from .export.batch import export_after
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


if __name__ == "__main__":
    sys.exit(main(get_options()))
