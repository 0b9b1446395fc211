"""What ``python -m sumo_scendiff.run`` does once its flags are parsed (:mod:`.cli`): the user's
scenario read and judged by stock SUMO (its preflight), the network and model loaded, SUMO started
and the demand run up to the seeding time (or until the ego has driven in), the windows placed, each
window's request to the generator, the scenes generated, and each one seeded, exported and rolled
out (sim/session.py); ``run.json`` sums the run up. A problem with the user's input is a
:class:`RunError` (the CLI's one line, exit 2).
"""
from __future__ import annotations

import json
import os
import sys
import time

PROG = "python -m sumo_scendiff.run"
EGO_AHEAD_M = 25.0   # the ego window's centre ahead of the ego: it sees its own lane 75 m ahead


class RunError(Exception):
    """A problem with the user's input that stops the run (exit code 2, one line)."""


def _check_output(o) -> set[str]:
    """Called as the owner of -o (main claims it). Returns the scenes kept from an earlier run
    (--resume: those complete, i.e. under their final name); removes what dead runs left half-written."""
    from ..core.outputs import clean_stale
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
    from ..core.scene import per_km
    km = net.car_lane_km(window)
    total = row["existing_vehicles"] + row["placed"]
    density = per_km(total, km)
    return {**row, "vehicles_in_window": total, "car_lane_km": round(km, 4),
            "density_veh_per_km": None if density is None else round(density, 2)}


def _edge_data(o, net):
    from ..map.edgedata import EdgeData, EdgeDataError
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
    from ..map.edgedata import EdgeDataError
    from ..sim.fleet import Fleet
    from ..sim.request import DensityUnsupported, window_request
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
    from ..map.locations import auto_windows, parse_center, window_at
    from ..sim.density import host_positions
    if o.ego:
        w = cosim.ego_window(o.ego, ahead_m=EGO_AHEAD_M)
        return [(w, "ego")] * o.scenes
    if o.center:
        x, y = parse_center(o.center)
        return [(window_at(net, x, y, yaw=o.yaw), "center")] * o.scenes
    # with a demand, where its vehicles are at the seeding time (front bumpers; none: the layout alone)
    return [(loc.window, loc.kind) for loc in auto_windows(net, o.scenes, seed=o.seed, traffic=host_positions(sim))]


def _scenario(o):
    """The user's inputs as SUMO reads them, and SUMO judging them (its preflight, a Future: the
    network loads meanwhile; :func:`_verdict` takes it before the model is even imported)."""
    from concurrent.futures import ThreadPoolExecutor

    from ..sim.preflight import preflight
    from ..sim.scenario import ScenarioError, meso_notice, scenario_from_files
    try:
        scen = scenario_from_files(o.config, o.net, _files(o.routes), _files(o.additional))
    except ScenarioError as e:
        raise RunError(str(e)) from None
    if meso_notice(o.config):
        if o.replay_future > 0:    # the agents' futures are poses, which the mesoscopic model has not
            raise RunError(f"--replay-future: {o.config}: mesosim: SUMO's mesoscopic model holds no vehicle "
                           "at a pose (moveToXY does nothing there); leave --replay-future out")
        print(f"{PROG}: warning: {meso_notice(o.config)}", file=sys.stderr)
    pool = ThreadPoolExecutor(max_workers=1)   # its thread mostly waits for SUMO's process
    judged = pool.submit(preflight, scen)
    pool.shutdown(wait=False)
    return scen, judged


def _verdict(judged) -> None:
    """SUMO's refusal of the inputs as the run's error (it comes first, whatever else failed)."""
    from ..sim.scenario import ScenarioError
    try:
        judged.result()
    except ScenarioError as e:
        raise RunError(str(e)) from None


def _demand_times(o, scen, net, demand: list[str]) -> tuple[float | None, float | None]:
    """(the time SUMO starts at, the seeding time it runs the demand up to; None: the ego decides,
    or there is no demand), as :func:`_session` says. ``demand``: the files holding it
    (``data.demand.demand_files``: route files, and additional files with vehicles in them)."""
    from ..data.demand import DemandError, start_times
    if not demand:
        return (o.begin if o.begin is not None else scen.begin), None
    try:  # the route files as the set SUMO loads, against this network
        start, at, span = start_times(scen, {ln.edge for ln in net.lanes}, o.begin, demand, seed=not o.ego)
    except DemandError as e:
        raise RunError(str(e)) from None
    if span.cut is not None:
        _check_cut(o, span.cut, at)
    return start, at


def _check_cut(o, cut, at: float | None) -> None:
    """A route file cut short: SUMO runs it up to the cut (a warning, once); a run whose rollout
    ends after SUMO quits is refused (``at``: the seeding time; None: the ego decides)."""
    from ..core.cli import clock
    print(f"{PROG}: warning: {cut.warning()}", file=sys.stderr)
    if at is not None and at + o.rollout > cut.stop:
        end = at + o.rollout
        raise RunError(f"--rollout {o.rollout:g}: the run ends at {end:g} s ({clock(end)}), after SUMO quits on "
                       f"{cut.path} at about {cut.stop:g} s; give an earlier --begin or a shorter --rollout")


def _session(o, scen, net, gen, sumo_settings: dict, times: tuple, progress: bool, demand: list[str]):
    """The simulation of the scenario and the warm-up that runs its demand up to the seeding time
    (sim/session.py); with demand SUMO starts at the configuration's begin, else the demand's first
    departure (before it the network is empty), and without demand at --begin."""
    from ..sim.scenario import own_random
    from ..sim.session import Session
    from ..sim.sumo import SimConfig
    begin, at = times
    # a demand runs to the seeding time as the user's own sumo runs it: their SUMO seed, not -s (the
    # model's); each scene's rollout goes on under it (Session._realise)
    seed, rng = own_random(scen) if demand else (o.seed, ())
    cfg = SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional, gui=o.gui, traci=o.traci,
                    seed=seed, begin=begin, extra=rng, **sumo_settings)
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

    from ..map.raster import render_map
    from ..sim.request import generation_inputs
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
    from ..data.demand import demand_files
    from ..map.network import Network, NoCarLane
    from ..sim.sumo import settings
    from ..tokens.file import load_tokens
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
    from ..core.threads import GENERATION_THREADS, share_cpu
    threads = share_cpu(default=GENERATION_THREADS)   # before torch is imported (core/threads.py: why one)
    from ..generation.generator import GenerationConfig, ScenarioGenerator
    from ..sim.density import default_density, host_has_traffic
    from ..sim.request import counted_as_asked
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
    from ..core.outputs import partial_path
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
