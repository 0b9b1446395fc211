"""The recording's part of benchmarks/train_profile.py: ``python -m sumo_scendiff.data`` timed by phase
in the profiler's child process (SUMO's steps apart before an episode's first window and after,
the vehicles' states, cutting the windows, random trips and their child processes, writing the
shard), and its table scaled to the recipe's recordings."""
from __future__ import annotations

import json
import os
import resource
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
RECIPE = os.path.join(ROOT, "configs", "scendiff.json")
REC = "sumo_scendiff.data.record"
RECORD_PHASES = [
    ("network load", ["sumo_scendiff.map.network:Network.load"]),
    ("SUMO start / close", ["libsumo:start", "libsumo:close"]),
    ("vehicle states: libsumo subscriptions", ["libsumo:vehicle.getAllSubscriptionResults",
                                               "libsumo:vehicle.subscribe"]),
    ("vehicle states: poses (tracker)", [f"{REC}:_Tracker.step"]),
    ("windows: cut the scenes", [f"{REC}:_Tracker.scene", f"{REC}:_sample_windows"]),
    ("random trips (waiting for randomTrips.py)", [f"{REC}:random_trips"]),
    ("writing the shard", [f"{REC}:write_shard"]),
]
CHILDREN = "random trips: child processes' CPU (randomTrips.py, duarouter)"
WARM, SAMPLING = "SUMO steps: warm-up", "SUMO steps: while cutting windows"
PER_EPISODE = ("network load", "SUMO start / close", "random trips (waiting for randomTrips.py)", WARM, CHILDREN)


def train_networks() -> list[str]:
    from sumo_scendiff.train import recipe as rc
    with open(rc.SPLITS) as f:
        return [os.path.join(rc.NETWORKS, n) for n in json.load(f)[rc.stage(rc.load(RECIPE), "record-train")["split"]]]


def time_sumo_steps(prof) -> None:
    """libsumo's steps timed apart before an episode's first window (its warm-up) and after."""
    import libsumo

    from sumo_scendiff.data import record
    episode, step, spec = record.record_episode, libsumo.simulationStep, {}

    def record_episode(net, s, progress=None):
        spec["now"] = s
        return episode(net, s, progress)

    def simulation_step(*a, **kw):
        s = spec["now"]
        prof.enter(WARM if libsumo.simulation.getTime() + 1 < s.begin + s.warmup else SAMPLING)
        try:
            return step(*a, **kw)
        finally:
            prof.leave()
    record.record_episode, libsumo.simulationStep = record_episode, simulation_step


def child_record(o, prof, patch) -> dict:
    """The recording of ``o.record_scenes`` windows on ``o.record_net`` in this process, ``prof`` (a
    benchmarks/profile.py Profile) timing the phases ``patch`` wraps."""
    import libsumo  # noqa: F401
    import sumo_scendiff.data.record  # noqa: F401
    import sumo_scendiff.map.network  # noqa: F401
    from sumo_scendiff.data.recording import record_dataset
    from sumo_scendiff.train import recipe as rc
    for phase, targets in RECORD_PHASES:
        for t in targets:
            patch(prof, t, phase)
    time_sumo_steps(prof)
    density = tuple(rc.stage(rc.load(RECIPE), "record-train")["density"])
    kids0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu0 = time.process_time()
    prof.enter("other (the recorder's own)")
    manifest = record_dataset(o.record_net, os.path.join(o.work, "rec"), o.record_scenes, 0,
                              per_episode=o.record_per_episode, density=density, disc=True, workers=1)
    prof.leave()
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = dict(prof.cpu, **{CHILDREN: kids.ru_utime + kids.ru_stime - kids0.ru_utime - kids0.ru_stime})
    episodes = len(manifest["episodes"])
    rows = [{"phase": p, "cpu_s": c, "per": "episode" if p in PER_EPISODE else "window",
             "cpu_s_per_unit": c / (episodes if p in PER_EPISODE else manifest["scenes"])}
            for p, c in sorted(cpu.items(), key=lambda kv: -kv[1])]
    return {"nets": [os.path.basename(n) for n in o.record_net], "scenes": manifest["scenes"],
            "agents": manifest["agents"], "episodes": [{k: e[k] for k in ("density", "warmup", "sample_every", "scenes")}
                                                       for e in manifest["episodes"]],
            "cpu_s": time.process_time() - cpu0 + cpu[CHILDREN], "rows": rows}


def recipe_recording() -> tuple[int, int]:
    """(windows, episodes) of the recipe's recordings: the data CLI's episodes of its default length."""
    from sumo_scendiff.data.__main__ import get_options as data_options
    from sumo_scendiff.train import recipe as rc
    r = rc.load(RECIPE)
    per = data_options(["-n", "x", "-o", "x", "--scenes", "1"]).scenes_per_episode
    nets = len(train_networks())
    stages = [s for s in r["stages"] if s["run"] == "data"]
    return sum(s["scenes"] for s in stages), sum(nets * -(-(s["scenes"] // nets) // per) for s in stages)


def record_table(rec: dict) -> list[str]:
    windows, episodes = recipe_recording()
    lines = [f"recording {rec['scenes']} windows of {len(rec['nets'])} networks in {len(rec['episodes'])} episodes "
             f"(densities {min(e['density'] for e in rec['episodes']):.0f}-{max(e['density'] for e in rec['episodes']):.0f} "
             f"veh/h/km of lane), CPU s, and the recipe's {windows:,} windows in {episodes} episodes at these rates", "",
             "| phase | CPU s per | here | the recipe (CPU h) | share |", "|---|---|---|---|---|"]
    recipe = {r["phase"]: r["cpu_s_per_unit"] * (episodes if r["per"] == "episode" else windows) / 3600
              for r in rec["rows"]}
    total = sum(recipe.values())
    for r in rec["rows"]:
        lines.append(f"| {r['phase']} | {r['per']} | {r['cpu_s_per_unit']:.4f} | {recipe[r['phase']]:.3f} | "
                     f"{100 * recipe[r['phase']] / total:.0f} % |")
    lines += [f"| **total** | | | **{total:.2f}** | |", "",
              f"the recipe's recordings at these rates: {60 * total / 2:.0f} min on two workers"]
    return lines
