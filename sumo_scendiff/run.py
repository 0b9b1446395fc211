"""Generate scenes on a SUMO network, seed them as real SUMO vehicles, let SUMO drive, export.

    python -m sumo_scendiff.run -n networks/city.net.xml                      # 4 busy places, 60 s each
    python -m sumo_scendiff.run -n city.net.xml --center 1020,980 --tokens tokens.toml --scenes 8
    python -m sumo_scendiff.run -n city.net.xml -r demand.rou.xml --ego veh42 --gui
    python -m sumo_scendiff.run -n city.net.xml --rollout 0 -o out/       # seed and export only

Without ``--center`` or ``--ego`` the windows are busy, varied places of the network (junctions,
roundabouts, merges; :mod:`~sumo_scendiff.map.locations`). With ``-r`` SUMO first runs that demand
(until the ego appears, or ``--begin`` seconds) and the vehicles already in a window become agent
tokens: the model fills in around them. Each scene is written to ``OUT/scene_NNN/`` (see the
README, "Scenario files"): scene.json, scenario.rou.xml, scenario.sumocfg, state.xml.gz,
rollout.json, scene.png; ``OUT/run.json`` sums the run up.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

PROG = "python -m sumo_scendiff.run"


def get_options(args=None):
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("-n", "--net-file", "--net", dest="net", required=True, help="SUMO network (.net.xml)")
    p.add_argument("-r", "--route-files", "--routes", dest="routes", default=None,
                   help="demand to run first (comma-separated route files); its vehicles become tokens")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--center", metavar="X,Y", help="window centre in network coordinates")
    where.add_argument("--ego", metavar="ID", help="seed around this vehicle of --route-files")
    p.add_argument("--begin", type=float, default=None,
                   help="with -r and no --ego: seconds of demand to run (from its first departure) "
                        "before seeding (default 600)")
    p.add_argument("--tokens", metavar="FILE", help="agent tokens and global token (TOML/JSON, docs/tokens.md)")
    p.add_argument("--p-mask", type=float, default=None, help="global scene token (overrides the token file)")
    p.add_argument("--scenes", type=int, default=4, help="number of scenes (default 4)")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=10, help="sampler steps (default 10, DPM-Solver++(2M))")
    p.add_argument("--threshold", type=float, default=0.8, help="box probability threshold")
    p.add_argument("--guidance", type=float, default=3.0,
                   help="classifier-free guidance weight of the agent tokens (default 3; 1 = off)")
    p.add_argument("--scene-guidance", type=float, default=None,
                   help="classifier-free guidance weight of the global token for windows without agent "
                        "tokens: more agents above 1 (default: the model's calibrated value; 1 = off)")
    p.add_argument("--no-pin-tokens", dest="pin_tokens", action="store_false",
                   help="tokens are conditions only (default: a token giving pose, size and speed -- "
                        "every vehicle already in the window -- is pinned where it is)")
    p.add_argument("--no-pin-speeds", dest="pin_speeds", action="store_false",
                   help="a pinned token's vehicle keeps the speeds the model draws (default: it moves at "
                        "the token's speed and final speed along the path the model draws)")
    p.add_argument("--no-lane-headings", dest="lane_headings", action="store_false",
                   help="vehicles on a junction keep the decoder's own heading (default: the heading of the "
                        "network's lane through them that the decoder finds most probable)")
    p.add_argument("--no-lane-snap", dest="lane_snap", action="store_false",
                   help="vehicles keep their decoded pose (default: a pose within 3 m of an agreeing car "
                        "lane moves onto its centre line and takes its heading, as SUMO's traffic drives)")
    p.add_argument("--rollout", type=float, default=60.0, help="seconds SUMO drives after seeding (0: none)")
    p.add_argument("--replay-future", type=float, default=0.0, metavar="SECONDS",
                   help="hold the agents on their generated 0..+2 s future before SUMO takes over (max 2)")
    p.add_argument("--step-length", type=float, default=0.5)
    p.add_argument("--gui", action="store_true", help="watch in sumo-gui (traci)")
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("-o", "--output-dir", dest="out", default="scendiff-out")
    p.add_argument("--force", action="store_true", help="replace scene folders of an earlier run in -o")
    p.add_argument("-v", "--verbose", action="store_true")
    o = p.parse_args(args)
    if o.ego and not o.routes:
        p.error("--ego needs --route-files (the demand the ego drives in)")
    if o.scenes < 1:
        p.error("--scenes must be >= 1")
    if o.rollout < 0 or o.step_length <= 0 or o.steps < 1 or not o.guidance >= 0 \
            or not (o.scene_guidance is None or o.scene_guidance >= 0):
        p.error("--rollout must be >= 0, --step-length > 0, --steps >= 1, "
                "--guidance and --scene-guidance >= 0")
    if not 0.0 <= o.replay_future <= 2.0:
        p.error(f"--replay-future must be in [0, 2] seconds, got {o.replay_future}")
    if o.p_mask is not None and not 0.0 <= o.p_mask <= 1.0:
        p.error(f"--p-mask must be in [0, 1], got {o.p_mask}")
    o.parser = p
    return o


class RunError(Exception):
    """A problem with the user's input that stops the run (exit code 2, one line)."""


def _check_output(o) -> None:
    try:
        os.makedirs(o.out, exist_ok=True)
        probe = os.path.join(o.out, f".write-test-{os.getpid()}")
        open(probe, "w").close()
        os.remove(probe)
    except OSError as e:
        raise RunError(f"{o.out}: output directory not writable ({e.strerror or e})") from None
    names = [f"scene_{k:03d}" for k in range(o.scenes)] + ["run.json"]
    taken = [n for n in names if os.path.exists(os.path.join(o.out, n))]
    if taken and not o.force:
        raise RunError(f"{os.path.join(o.out, taken[0])}: exists (choose another --output-dir or add --force)")


def _warm_up(sim, o, progress: bool) -> None:
    """Run the demand until the ego is on the road, or for --begin seconds."""
    from tqdm import tqdm
    if o.ego:
        bar = tqdm(desc=f"waiting for {o.ego}", unit=" s", disable=not progress, leave=False)
        while o.ego not in sim.vehicle.getIDList():
            if sim.simulation.getMinExpectedNumber() == 0:
                raise RunError(f"{o.routes}: vehicle {o.ego!r} never appears (the demand ended at "
                               f"t = {sim.simulation.getTime():.0f} s)")
            sim.simulationStep()
            bar.update(sim.simulation.getDeltaT())
        bar.close()
        return
    begin = 600.0 if o.begin is None else o.begin
    steps = int(round(begin / sim.simulation.getDeltaT()))
    for _ in tqdm(range(steps), desc="warming up the demand", disable=not progress, leave=False):
        sim.simulationStep()


def _windows(o, net, sim, cosim):
    from .map.locations import auto_windows, parse_center, window_at
    if o.ego:
        w = cosim.ego_window(o.ego)
        return [(w, "ego")] * o.scenes
    if o.center:
        x, y = parse_center(o.center)
        return [(window_at(net, x, y), "center")] * o.scenes
    return [(loc.window, loc.kind) for loc in auto_windows(net, o.scenes, seed=o.seed)]


def run(o) -> dict:
    import numpy as np

    from .data.demand import DemandError, check_routes
    from .generation.generator import GenerationConfig, ScenarioGenerator
    from .map.network import Network
    from .map.raster import render_map
    from .sim.session import Session
    from .sim.sumo import SimConfig
    from .tokens.file import load_tokens

    progress = sys.stderr.isatty() or o.verbose
    timing = {}
    t = time.perf_counter()
    net = Network.load(o.net)
    spec = load_tokens(o.tokens) if o.tokens else None
    _check_output(o)
    gen = ScenarioGenerator.load(o.checkpoint, GenerationConfig(
        steps=o.steps, threshold=o.threshold, guidance=o.guidance, scene_guidance=o.scene_guidance,
        pin_tokens=o.pin_tokens, pin_speeds=o.pin_speeds, lane_headings=o.lane_headings,
        lane_snap=o.lane_snap))
    routes = tuple(r for r in (o.routes or "").split(",") if r)
    edges = {ln.edge for ln in net.lanes}
    try:  # matches the network; the simulation starts at the first departure
        first = min(check_routes(r, edges) for r in routes) if routes else None
    except DemandError as e:
        raise RunError(str(e)) from None
    cfg = SimConfig(net=o.net, routes=routes, step_length=o.step_length, gui=o.gui, seed=o.seed,
                    begin=first)
    session = Session(cfg, net, gen, quiet=not o.verbose)
    try:
        session.prepare((lambda sim: _warm_up(sim, o, progress)) if routes else None)
        places = _windows(o, net, session.sim, session.cosim())
        windows = [w for w, _ in places]
        existing = [session.existing(w) for w in windows]
        timing["load"] = time.perf_counter() - t

        t = time.perf_counter()
        maps = np.stack([render_map(net, w, gen.raster) for w in windows])
        timing["raster"] = time.perf_counter() - t

        t = time.perf_counter()
        user = [spec.for_window(w) if spec else [] for w in windows]
        tokens = [u + e.tokens() for u, e in zip(user, existing)]
        sources = [["user"] * len(u) + e.token_ids() for u, e in zip(user, existing)]
        p_mask = [o.p_mask if o.p_mask is not None else spec.p_mask if spec else 0.5 if tk else 1.0
                  for tk in tokens]
        scenes = gen.generate(net, windows, tokens=tokens, p_mask=p_mask, seed=o.seed, maps=maps,
                              progress=progress)
        timing["generate"] = time.perf_counter() - t

        results = []
        from tqdm import tqdm
        for k in tqdm(range(len(scenes)), desc="seeding and rolling out", disable=not progress):
            name = f"scene_{k:03d}"
            info = {"scene": name, "location": places[k][1], "window_index": k,
                    "model": {"sha256": gen.sha256, "sampler": gen.config.sampler.__name__, "steps": o.steps,
                              "threshold": o.threshold, "pin_tokens": o.pin_tokens, "pin_speeds": o.pin_speeds,
                              "lane_headings": o.lane_headings, "lane_snap": o.lane_snap,
                              "guidance": o.guidance, "scene_guidance": gen.scene_guidance_for(gen.config),
                              "scene_guidance_sigma": gen.scene_guidance_sigma_for(gen.config)},
                    "sumo_options": cfg.options()}
            row = session.realise(scenes[k], tokens[k], sources[k], existing[k], o.out, name, info,
                                  o.rollout, seed=o.seed, p_mask=p_mask[k], force=o.force,
                                  replay=o.replay_future)
            results.append({"scene": name, "location": places[k][1], **row})
        timing.update(session.timing)
    finally:
        session.close()
    summary = {"network": os.path.abspath(o.net), "model_sha256": gen.sha256, "seed": o.seed,
               "scenes": results, "timing_s": {k: round(v, 3) for k, v in timing.items()}}
    tmp = os.path.join(o.out, "run.json.partial")
    with open(tmp, "w") as f:
        json.dump(summary, f, indent=1)
    os.replace(tmp, os.path.join(o.out, "run.json"))
    return summary


def print_summary(summary: dict) -> None:
    rows = summary["scenes"]
    print(f"{'scene':10} {'where':11} {'agents':>6} {'placed':>6} {'refused':>7} {'misplaced':>9} "
          f"{'collisions':>10} {'teleports':>9} {'e-brakes':>8} {'speed':>6}")
    for r in rows:
        print(f"{r['scene']:10} {r['location']:11} {r['generated']:6d} {r['placed']:6d} {r['refused']:7d} "
              f"{r['misplaced']:9d} {r['collisions']:10d} {r['teleports']:9d} {r['emergency_brakes']:8d} "
              f"{r['mean_speed']:6.1f}")
    gen = sum(r["generated"] for r in rows)
    placed = sum(r["placed"] for r in rows)
    print(f"placed {placed} of {gen} generated agents ({100.0 * placed / max(gen, 1):.1f} %) at their pose; "
          f"timing (s): " + ", ".join(f"{k} {v:.2f}" for k, v in summary["timing_s"].items()))


def main(o) -> int:
    from .map.locations import LocationError
    from .map.network import NetworkError
    from .model.checkpoint import CheckpointError
    from .sim.sumo import SimError
    from .tokens.file import TokenFileError
    try:
        summary = run(o)
    except (RunError, NetworkError, CheckpointError, SimError, TokenFileError, LocationError,
            FileExistsError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    print_summary(summary)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
