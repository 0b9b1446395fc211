"""Evaluate scene generators against SUMO's own traffic on networks the model never trained on.

    python -m sumo_scendiff.evaluate                         # held-out generated nets + real cities
    python -m sumo_scendiff.evaluate -n ../shared/nets/resco_cologne8/cologne8.net.xml --scenes 300
    python -m sumo_scendiff.evaluate --json results.json     # everything, for machines

For every network, ground-truth scenes are recorded from SUMO (with the network's own demand when a
matching ``*.rou.xml`` lies beside it, otherwise random trips), each window turned by a random angle
and recorded again whole at the same instant (:mod:`sumo_scendiff.data.rerecord`), and every method
generates a scene for the same windows: Random Log Selection (agents of a random *training* scene,
map ignored), Lane-uniform with its own count rule and told the true count, and the shipped Scenario
Diffusion model (with ``--checkpoint``/the default weights when present). A reference row, "SUMO
2 min later", scores the same windows :data:`LATER` s later in the same traffic: an independent draw
of what SUMO puts there, so what a perfect generator would score. The table gives the paper's
metrics per network (see :mod:`sumo_scendiff.evaluate.metrics`).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import sys
from dataclasses import replace

import numpy as np

from ..core.geometry import Window, wrap_angle
from ..core.scene import per_km
from ..data.demand import DemandError, find_demand
from ..data.shards import SceneStore
from ..generation.config import GenerationConfig, SettingError
from ..map.network import Network, NetworkError
from .baselines import LaneUniform, RandomLogSelection
from .delivered import scenario_fleet, with_fleet
from .jsd import FEATURES, evaluate_jsd, vehicle_features
from .metrics import evaluate_scenes

PROG = "python -m sumo_scendiff.evaluate"
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHARED_NETS = os.path.join(ROOT, "..", "shared", "nets")
REAL_CITIES = ("resco_cologne1/cologne1.net.xml", "resco_cologne3/cologne3.net.xml",
               "resco_cologne8/cologne8.net.xml", "resco_ingolstadt1/ingolstadt1.net.xml",
               "resco_ingolstadt7/ingolstadt7.net.xml", "resco_ingolstadt21/ingolstadt21.net.xml",
               "berlin_doerpfeldstr/net.net.xml.gz", "wildau/net.net.xml.gz",
               "ingolstadt_cutmap/Forschungskreuzung_cutmap.net.xml.gz")
LATER = 120.0   # s: the reference row's delay (longer than a signal cycle: other vehicles, same traffic)
REFERENCE = "SUMO 2 min later"
FLOOR = "SUMO, other windows"
FLEET = ", the scenario's fleet"   # a JSD row of a model's scenes with the vTypes run seeds them as   # the JSD set's floor: SUMO's traffic in the other half of the windows
JSD_COLUMNS = tuple((f"jsd_{k}", f"JSD {k.replace('_', ' ')}") for k in FEATURES) + (("collision", "collision"),)
COLUMNS = (("mmd2_position", "MMD² pos"), ("mmd2_heading", "MMD² head"),
           ("mmd2_velocity", "MMD² vel"), ("mmd2_joint", "MMD² joint"),
           ("traj_on_drivable", "traj on drivable"), ("lane_heading_difference", "lane head. diff"),
           ("agents_emd", "agents/scene EMD"), ("agents_per_scene", "agents/scene"),
           ("standing_red", "standing at red"), ("standing_green", "standing at green"))


def get_options(args=None):
    from ..core.cli import HelpFormatter, description
    p = argparse.ArgumentParser(prog=PROG, description=description(__doc__), formatter_class=HelpFormatter)
    p.add_argument("-n", "--net-file", "--net", dest="nets", action="append", default=None,
                   metavar="NET", help="network to evaluate on (repeat); default: held-out + real cities")
    p.add_argument("--scenes", type=int, default=200, help="ground-truth scenes per network")
    p.add_argument("--train-data", default=os.path.join(ROOT, "data", "train"),
                   help="training scenes for Random Log (recorded from networks/ if missing)")
    p.add_argument("--cache", default=os.path.join(ROOT, ".cache", "eval"),
                   help="where recorded ground truth is kept between runs")
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("--no-model", action="store_true", help="baselines only")
    p.add_argument("--no-map-checkpoint", default=None, help="the no-map ablation model (a row)")
    p.add_argument("--tokens", action="store_true", help="also the token tables (2, 3, E.2)")
    p.add_argument("--token-scenes", type=int, default=100, help="scenes per net for --tokens")
    p.add_argument("--json", default=None, metavar="PATH", help="also write all results as JSON")
    p.add_argument("--pictures", default=None, metavar="DIR",
                   help="write DIR/<net>.png: three windows, ground truth beside every method")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-v", "--verbose", action="store_true")
    GenerationConfig.add_arguments(p)
    o = p.parse_args(args)
    try:
        GenerationConfig.from_options(o)
    except SettingError as e:
        p.error(str(e))
    if o.tokens and o.no_model:
        p.error("--tokens measures the model: it cannot go with --no-model")
    o.parser = p
    return o


def default_nets() -> list[str]:
    with open(os.path.join(ROOT, "networks", "splits.json")) as f:
        nets = [os.path.join(ROOT, "networks", n) for n in json.load(f)["heldout"]]
    return nets + [os.path.join(SHARED_NETS, r) for r in REAL_CITIES
                   if os.path.exists(os.path.join(SHARED_NETS, r))]


def record_cached(nets: list[str], routes: list[str | None], scenes: int, seed: int, cache: str,
                  tag: str) -> str:
    """Record (once) scenes into the cache (continuing an interrupted recording there); returns the
    data directory. Exits as the data CLI does (2 for bad input, 130 when interrupted)."""
    from ..core.outputs import OutputError
    from ..data.record import RECORDER_VERSION
    from ..data.recording import RecordingError, RecordingInterrupted, record_dataset
    key = json.dumps([[os.path.abspath(n) for n in nets], routes, scenes, seed, RECORDER_VERSION])
    out = os.path.join(cache, f"{tag}-{hashlib.sha1(key.encode()).hexdigest()[:12]}")
    if not os.path.exists(os.path.join(out, "manifest.json")):
        try:
            with contextlib.redirect_stdout(sys.stderr):  # keep stdout for the table
                m = record_dataset(nets, out, scenes, seed, routes=routes,
                                   per_episode=100, resume=os.path.exists(out + ".partial"))
                print(f"{out}: {m['scenes']} scenes, {m['agents']} agents from "
                      f"{len(m['nets'])} network(s) in {len(m['episodes'])} episode(s)")
        except (RecordingError, OutputError) as e:
            print(f"{PROG}: error: {e}", file=sys.stderr)
            raise SystemExit(2) from None
        except RecordingInterrupted as e:
            print(f"{PROG}: interrupted: {e}", file=sys.stderr)
            raise SystemExit(130) from None
    return out


def training_pool(o) -> SceneStore:
    if os.path.exists(os.path.join(o.train_data, "manifest.json")):
        return SceneStore(o.train_data)
    with open(os.path.join(ROOT, "networks", "splits.json")) as f:
        train = [os.path.join(ROOT, "networks", n) for n in json.load(f)["train"]]
    return SceneStore(record_cached(train, [None] * len(train), 1200, 12345, o.cache, "train-pool"))


def methods_for(net: Network, pool: SceneStore, models: dict, seed: int):
    """(name, fn(ground-truth scenes) -> generated scenes) for every method compared on this net."""
    rlog = RandomLogSelection(pool, seed=seed)
    lane = LaneUniform(net, seed=seed)
    out = [("Random Log", lambda gts: [rlog.generate(g.window, index=i) for i, g in enumerate(gts)]),
           ("Lane-uniform", lambda gts: [lane.generate(g.window, index=i) for i, g in enumerate(gts)]),
           ("Lane-uniform (true count)",
            lambda gts: [lane.generate(g.window, n=len(g), index=i) for i, g in enumerate(gts)])]
    # map-only generation (no agent tokens, p_mask = 1) with the traffic lights of the recorded moment,
    # as a host simulation gives them
    for name, gen in models.items():
        out.append((name, lambda gts, gen=gen: gen.generate(net, [g.window for g in gts], seed=seed,
                                                            signals=lights_of(gts))))
    for name, gen in models.items():  # told each window's true count, as `run --vehicles N` is
        if gen.has_density:
            out.append((f"{name} (true count)", lambda gts, gen=gen: gen.generate(
                net, [g.window for g in gts], seed=seed, density=[true_density(net, g) for g in gts],
                signals=lights_of(gts))))
    return out


def lights_of(scenes) -> list[dict | None]:
    """The traffic lights' states each recorded scene holds (None where its recording has none)."""
    return [s.meta.get("signals") or None for s in scenes]


def true_density(net: Network, scene) -> float:
    """The ground truth's vehicles per km of car lane in its window (what --vehicles N asks for)."""
    d = per_km(len(scene), net.car_lane_km(scene.window))
    return float("nan") if d is None else d   # NaN: the generator's "no target"


def ground_truth(net: Network, o) -> tuple[str | None, list, list]:
    """The network's demand file, its recorded scenes with each window turned by a random angle
    (recorded again whole, at the same instant), and the same windows :data:`LATER` s later."""
    from ..data.rerecord import rerecorded
    routes = find_demand(net)
    data = record_cached([net.path], [routes], o.scenes, o.seed, o.cache, f"gt-{net.name}")
    store = SceneStore(data)
    rng = np.random.default_rng([o.seed, 7])
    windows = []
    for i in range(len(store)):
        w = store.scene(i).window
        windows.append(Window(w.cx, w.cy, float(wrap_angle(w.yaw + rng.uniform(-np.pi, np.pi))), w.size))
    again = rerecorded(data, windows, (0.0, LATER), progress=True)
    return routes, again[0.0], again[LATER]


def evaluate_net(net: Network, o, pool: SceneStore, models: dict) -> dict:
    import time
    routes, gts, later = ground_truth(net, o)
    result = {"net": net.name, "path": net.path, "demand": routes and os.path.basename(routes),
              "scenes": len(gts), "methods": {}, "seconds": {}}
    first = None
    # the JSD set compares pooled vehicles: every method's on the even windows against SUMO's on the
    # odd ones, and SUMO's own on the even ones is the floor at the same sample size
    half, other = gts[0::2], gts[1::2]
    reference = vehicle_features(other, net)
    jsd = {FLOOR: evaluate_jsd(half, other, net, reference)}
    shown = [i for i, g in enumerate(gts) if len(g)][:3]
    tiles = {"Ground truth": [gts[i] for i in shown]}
    from tqdm import tqdm
    methods = [(REFERENCE, lambda gts: later)] + methods_for(net, pool, models, o.seed)
    fleet = scenario_fleet(net, routes) if models else None
    bar = tqdm(methods, desc=f"evaluating {net.name}", unit="method")
    for name, fn in bar:
        bar.set_postfix_str(name)
        t = time.perf_counter()
        gen = fn(gts)
        tiles[name] = [gen[i] for i in shown]
        result["seconds"][name] = time.perf_counter() - t
        res = evaluate_scenes(gen, gts, net)
        first = first or res
        result["methods"][name] = _row(res)
        jsd[name] = evaluate_jsd(gen[0::2], other, net, reference)
        if fleet is not None and name.split(" (")[0] in models:   # the sizes SUMO gets, as run seeds them
            jsd[f"{name}{FLEET}"] = evaluate_jsd(with_fleet(gen[0::2], fleet, net, o.seed), other, net, reference)
        if o.verbose:
            print(f"{net.name}: {name} in {result['seconds'][name]:.1f} s", file=sys.stderr)
    gt = first["gt_only"]
    result["methods"] = {"Ground truth": {"traj_on_drivable": gt["traj_on_drivable"],
                                          "lane_heading_difference": gt["lane_heading_diff"],
                                          "agents_per_scene": first["agents_per_scene_gt"],
                                          **{k: gt[k] for k in ("standing_red", "standing_green",
                                                                "at_red", "at_green") if k in gt}},
                         **result["methods"]}
    result["jsd"] = jsd
    if o.pictures:
        save_pictures(net, tiles, os.path.join(o.pictures, f"{net.name}.png"))
    return result


def save_pictures(net: Network, tiles: dict, path: str) -> None:
    """One row per shown window, one column per method (ground truth first)."""
    from ..core.files import write_png
    from ..core.outputs import partial_path
    from ..map.picture import contact_sheet, draw_scene
    rows = [[draw_scene(net, scenes[r], 320, title=name) for name, scenes in tiles.items()]
            for r in range(len(next(iter(tiles.values()))))]
    if rows:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        tmp = partial_path(path)   # complete or absent, never a half-written picture
        write_png(tmp, contact_sheet(rows))
        os.replace(tmp, path)


def _row(res: dict) -> dict:
    return {"mmd2_position": res["mmd2_position"], "mmd2_heading": res["mmd2_heading"],
            "mmd2_velocity": res["mmd2_velocity"], "mmd2_joint": res["mmd2_joint"],
            "traj_on_drivable": res["traj_on_drivable"],
            "lane_heading_difference": res["lane_heading_diff"],
            "agents_emd": res["agents_per_scene_emd"], "agents_per_scene": res["agents_per_scene_gen"],
            "mmd_scenes": res["mmd_scenes"],
            **{k: res[k] for k in ("standing_red", "standing_green", "at_red", "at_green") if k in res}}


def markdown(results: list[dict]) -> str:
    head = "| network | method | " + " | ".join(c[1] for c in COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 2)]
    for r in results:
        label = f"{r['net']} ({r['scenes']} scenes{', own demand' if r['demand'] else ', random trips'})"
        for k, (name, row) in enumerate(r["methods"].items()):
            cells = [_fmt(row.get(key)) for key, _ in COLUMNS]
            lines.append(f"| {label if k == 0 else ''} | {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary(results: list[dict]) -> str:
    """Means over the held-out generated networks and over the real cities, with the MMD²s as a
    ratio to Random Log's (the paper's targets are stated that way)."""
    ours = os.path.join(ROOT, "networks") + os.sep
    mine = [os.path.abspath(r["path"]).startswith(ours) for r in results]
    groups = {"held-out generated": [r for r, m in zip(results, mine) if m],
              "real cities": [r for r, m in zip(results, mine) if not m]}
    keys = [k for k, _ in COLUMNS]
    mmds = [k for k in keys if k.startswith("mmd2_")]
    head = ("| networks | method | " + " | ".join(c[1] for c in COLUMNS)
            + " | MMD² / Random Log (pos / head / vel / joint) |")
    lines = [head, "|" + "---|" * (len(COLUMNS) + 3)]
    for group, rs in groups.items():
        if not rs:
            continue
        methods = list(rs[0]["methods"])
        ref = {key: np.nanmean([r["methods"]["Random Log"][key] for r in rs]) for key in mmds}
        for k, name in enumerate(methods):
            mean = {key: float(np.nanmean([r["methods"][name].get(key, np.nan) for r in rs]))
                    if any(key in r["methods"][name] for r in rs) else None for key in keys}
            ratio = (" / ".join(f"{mean[key] / ref[key]:.2f}" for key in mmds)
                     if mean.get("mmd2_joint") is not None else "–")
            label = f"{group} ({len(rs)})" if k == 0 else ""
            lines.append(f"| {label} | {name} | " + " | ".join(_fmt(mean[key]) for key in keys)
                         + f" | {ratio} |")
    return "\n".join(lines)


def jsd_markdown(results: list[dict]) -> str:
    """Scenario Dreamer's JSD set per network and method (:mod:`.jsd`), the floor row first."""
    lines = ["| network | method | " + " | ".join(c[1] for c in JSD_COLUMNS) + " |",
             "|" + "---|" * (len(JSD_COLUMNS) + 2)]
    for r in results:
        for k, (name, row) in enumerate(r.get("jsd", {}).items()):
            cells = [_fmt(row.get(key)) for key, _ in JSD_COLUMNS]
            lines.append(f"| {r['net'] if k == 0 else ''} | {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return "–"
    return f"{v:.3f}" if abs(v) < 100 else f"{v:.0f}"


def load_models(o) -> dict:
    """name -> ScenarioGenerator for the model rows (none with --no-model)."""
    if o.no_model:
        return {}
    from ..generation.generator import DEFAULT_CHECKPOINT, ScenarioGenerator
    cfg = GenerationConfig.from_options(o)
    path = o.checkpoint or DEFAULT_CHECKPOINT
    if o.checkpoint is None and not os.path.exists(path):
        print(f"{PROG}: no shipped checkpoint at {path}: baselines only", file=sys.stderr)
        return {}
    models = {"Scenario Diffusion": ScenarioGenerator.load(path, cfg)}
    if o.no_map_checkpoint:
        # the ablation sees no map at all: no lane headings or snapping from the network either
        models["Scenario Diffusion (no map)"] = ScenarioGenerator.load(
            o.no_map_checkpoint, replace(cfg, lane_headings=False, lane_snap=False))
    return models


def main(o) -> int:
    from ..core.outputs import OutputError, claim
    from ..core.threads import share_cpu
    share_cpu()
    try:  # --pictures DIR is this evaluation's until it ends: a second one stops before any work
        with claim(o.pictures) if o.pictures else contextlib.nullcontext():
            return _evaluate(o)
    except OutputError as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")


def _evaluate(o) -> int:
    from ..model.checkpoint import CheckpointError
    try:
        nets = [Network.load(p) for p in (o.nets or default_nets())]  # bad input first, before work
        models = load_models(o)
        pool = training_pool(o)
        results = [evaluate_net(net, o, pool, models) for net in nets]
        tokens = {}
        if o.tokens and models:
            from . import tokens as token_eval
            gen = models["Scenario Diffusion"]
            for net in nets:
                _, gts, _ = ground_truth(net, o)
                gts = gts[: o.token_scenes]
                tokens[net.name] = token_eval.token_tables(gen, net, gts, o.seed, progress=True)
    except (NetworkError, DemandError, CheckpointError) as e:
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    print(summary(results))
    print()
    # Random Log's agents come from this pool, and the MMD² ratios depend on it (docs/evaluation.md)
    roots = sorted({os.path.relpath(r) for r, _ in pool.sources})
    print(f"Random Log pool: {', '.join(roots)} ({len(pool)} scenes)")
    print()
    print(markdown(results))
    print()
    print(f"Scenario Dreamer's JSD set (even windows against SUMO's in the odd ones; {FLOOR}: the floor)")
    print(jsd_markdown(results))
    if tokens:
        from .tokens import markdown_tables
        print()
        print(markdown_tables(tokens))
    if o.json:
        with open(o.json, "w") as f:
            json.dump({"distribution": results, "tokens": tokens}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
