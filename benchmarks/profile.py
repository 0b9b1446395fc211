"""Benchmark: where the time goes, per phase, in ``run`` of one window and in a batch of generation.

    python benchmarks/profile.py [-n NET] [--batch 32] [--scenes 64] [--repeats 2] [-o results/speed_profile.json]
    python benchmarks/profile.py --before /tmp/base     # another checkout beside this one, in turns

Each measurement runs in a fresh Python process of its own (``--child``), the functions of every
phase wrapped by a timer that counts a call's time to its phase minus the time of the phases it
calls (so the phases add up to the whole). ``run``: ``python -m sumo_scendiff.run -n NET --scenes 1
--rollout R -o TMP`` as a user starts it; its wall time end to end is taken from outside the process
(interpreter start and exit included), the time before the first line of this script is "python
startup", the time after ``run`` returns "exit". Imports are a phase of their own wherever they happen
(``builtins.__import__``). The generation profile loads the network, renders the maps of ``--scenes``
random road windows, warms the generator up on one batch and times ``generate`` at ``--batch``.

``--before DIR``: the same measurements of the package in DIR (e.g. ``git archive`` of an earlier
commit) in the same invocation, taking turns with this checkout, so that a machine shared with other
jobs slows both alike; the table puts them side by side. Phases a checkout does not have are empty.
CPU seconds (this process and its threads) are given beside wall seconds: they depend less on
what else runs on the machine; the CPU of the processes ``run`` starts and waits for (stock SUMO
judging the inputs) is a row of its own.
"""
from __future__ import annotations

import argparse
import builtins
import importlib
import inspect
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
BIG = os.path.normpath(os.path.join(ROOT, "..", "shared", "nets", "resco_ingolstadt21", "ingolstadt21.net.xml"))
G = "sumo_scendiff.generation.generator"
P = "sumo_scendiff.generation.scene_passes"   # the passes after the model (in G before)
SUBPROCESSES = "subprocesses (the preflight's sumo), CPU"
# (phase, [module:attribute ...]) in table order; an attribute a checkout lacks is skipped
PHASES = [
    ("imports", []),
    ("preflight (stock SUMO loads the inputs)", ["sumo_scendiff.sim.preflight:preflight"]),
    ("network load", ["sumo_scendiff.map.network:Network.load"]),
    ("model load", [f"{G}:ScenarioGenerator.load"]),
    ("SUMO start / close", ["sumo_scendiff.sim.session:start", "sumo_scendiff.sim.session:close"]),
    ("windows", ["sumo_scendiff.map.locations:auto_windows"]),
    ("vehicles already there", ["sumo_scendiff.sim.session:Session.existing"]),
    ("rasters", ["sumo_scendiff.map.raster:render_map", f"{G}:render_map"]),
    ("map encoder", ["sumo_scendiff.model.diffusion:ScenarioDiffusion.encode_map"]),
    ("UNet (sampler)", ["sumo_scendiff.model.diffusion:ScenarioDiffusion.sample"]),
    ("pinned latent", [f"{G}:pinned_latent"]),
    ("decoder", [f"{G}:ScenarioGenerator.decode"]),
    ("lane headings", [f"{G}:junction_yaw"]),
    ("box decoding", [f"{G}:decode_boxes", f"{G}:_decode"]),
    ("batch assembly (tokens, noise)", [f"{G}:ScenarioGenerator._batch"]),
    ("box selection", [f"{G}:select_boxes", f"{G}:_select", f"{P}:select_boxes"]),
    ("overlap removal", [f"{G}:remove_overlaps", f"{P}:remove_overlaps"]),
    ("pinned tokens (turn, pace)", [f"{G}:turn_to_pins", f"{G}:pace_to_pins", f"{G}:match_pins",
                                    f"{G}:_turn_pins", f"{P}:turn_to_pins", f"{P}:pace_to_pins",
                                    f"{P}:match_pins", f"{P}:_turn_pins"]),
    ("delivered tokens (match, apply, pace)", [f"{G}:delivered_rows", f"{G}:match_rows", f"{G}:apply_rows",
                                               f"{G}:pace_rows", f"{G}:missing_pins", f"{G}:_deliver",
                                               f"{P}:delivered_rows", f"{P}:match_rows", f"{P}:apply_rows",
                                               f"{P}:pace_rows", f"{P}:missing_pins", f"{P}:_deliver"]),
    ("lane snap", [f"{G}:snap_to_lanes", f"{G}:_snap", f"{P}:snap_to_lanes", f"{P}:_snap"]),
    ("count (trim to the density)", [f"{G}:trim_to_count", f"{G}:area_mask", f"{G}:_trim",
                                     f"{G}:ScenarioGenerator._count", f"{G}:ScenarioGenerator._condition",
                                     f"{P}:trim_to_count", f"{P}:area_mask", f"{P}:_trim"]),
    ("placing unmatched tokens", [f"{G}:place_rows", f"{G}:_place", f"{P}:place_rows", f"{P}:_place"]),
    ("infill passes", [f"{G}:ScenarioGenerator._infill", f"{G}:add_new_agents", f"{G}:in_area",
                       f"{G}:scene_tokens"]),
    ("red queues", [f"{G}:stand_at_red"]),
    ("scene assembly", [f"{G}:ScenarioGenerator._scene", f"{G}:_finish", f"{P}:build_scene"]),
    ("generate's own loop", [f"{G}:ScenarioGenerator.generate"]),
    ("SUMO seeding", ["sumo_scendiff.sim.cosim:CoSimulation.place", "sumo_scendiff.sim.cosim:CoSimulation.verify"]),
    ("writing the scene", ["sumo_scendiff.sim.export:ScenarioWriter.after_seeding",
                           "sumo_scendiff.sim.export:ScenarioWriter.finish",
                           "sumo_scendiff.run:_write_summary", "sumo_scendiff.run:print_summary"]),
    ("rollout", ["sumo_scendiff.sim.session:rollout"]),
]


# ---- the timer (in the child) --------------------------------------------------------------------
class Profile:
    """Exclusive wall and CPU seconds per phase: a call's time minus that of the timed calls inside it."""

    def __init__(self):
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.stack: list[list] = []      # [phase, wall at entry, cpu at entry, wall of children, cpu of children]

    def enter(self, phase):
        self.stack.append([phase, time.perf_counter(), time.process_time(), 0.0, 0.0])

    def leave(self):
        phase, w0, c0, cw, cc = self.stack.pop()
        w, c = time.perf_counter() - w0, time.process_time() - c0
        self.wall[phase] = self.wall.get(phase, 0.0) + w - cw
        self.cpu[phase] = self.cpu.get(phase, 0.0) + c - cc
        if self.stack:
            self.stack[-1][3] += w
            self.stack[-1][4] += c

    def timed(self, phase, fn):
        def wrapper(*args, **kwargs):
            self.enter(phase)
            try:
                return fn(*args, **kwargs)
            finally:
                self.leave()
        wrapper.__wrapped__ = fn
        return wrapper


def _patch(prof: Profile, target: str, phase: str) -> bool:
    """Wrap ``module:attr`` (or ``module:Class.attr``) in the timer; False if the checkout lacks it."""
    mod_name, attr = target.split(":")
    owner = sys.modules[mod_name]
    *path, name = attr.split(".")
    for p in path:
        owner = getattr(owner, p, None)
    if owner is None or not hasattr(owner, name):
        return False
    orig = inspect.getattr_static(owner, name)
    if isinstance(orig, classmethod):
        setattr(owner, name, classmethod(prof.timed(phase, orig.__func__)))
    elif isinstance(orig, staticmethod):
        setattr(owner, name, staticmethod(prof.timed(phase, orig.__func__)))
    else:
        setattr(owner, name, prof.timed(phase, orig))
    return True


def install(prof: Profile) -> None:
    """Time every import, and wrap each phase's functions as soon as their module has been imported
    (a module that binds a function by ``from x import f`` is patched where it binds it)."""
    pending = {}
    for phase, targets in PHASES:
        for t in targets:
            pending.setdefault(t.split(":")[0], []).append((t, phase))
    original = builtins.__import__
    depth = [0]

    def timed_import(*args, **kwargs):
        prof.enter("imports")
        depth[0] += 1
        try:
            return original(*args, **kwargs)
        finally:
            depth[0] -= 1
            prof.leave()
            if depth[0] == 0:
                for mod in [m for m in pending if m in sys.modules]:
                    for t, phase in pending.pop(mod):
                        _patch(prof, t, phase)

    builtins.__import__ = timed_import


# ---- the children ------------------------------------------------------------------------------
def child_run(o, prof: Profile) -> dict:
    from sumo_scendiff import run as run_mod
    with tempfile.TemporaryDirectory(prefix="profile-run-") as tmp:
        args = ["-n", o.net, "--scenes", "1", "--rollout", f"{o.rollout:g}", "-s", str(o.seed),
                "-o", os.path.join(tmp, "out")]
        code = run_mod.main(run_mod.get_options(args))
    return {"exit_code": code}


def child_generate(o, prof: Profile) -> dict:
    import numpy as np
    import torch

    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.map.raster import render_map
    torch.set_num_threads(o.threads)
    net = Network.load(o.net)
    xy, yaw = net.random_road_points(o.scenes, np.random.default_rng(o.seed))
    wins = [Window(float(x), float(y), float(h)) for (x, y), h in zip(xy, yaw)]
    maps = np.stack([render_map(net, w) for w in wins])
    gen = ScenarioGenerator.load(None, GenerationConfig(batch_size=o.batch))
    gen.generate(net, wins[: o.batch], seed=o.seed, maps=maps[: o.batch])    # warm-up
    prof.wall.clear(), prof.cpu.clear()
    t, c = time.perf_counter(), time.process_time()
    scenes = gen.generate(net, wins, seed=o.seed, maps=maps)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    return {"scenes": len(scenes), "scenes_per_s": len(scenes) / wall, "scenes_per_cpu_s": len(scenes) / cpu,
            "generate_wall_s": wall, "agents": int(sum(len(s) for s in scenes))}


def child(o) -> None:
    start_wall, start_cpu = time.monotonic(), time.process_time()
    prof = Profile()
    install(prof)
    prof.enter("other (the command's own code)")
    extra = (child_run if o.child == "run" else child_generate)(o, prof)
    prof.leave()
    kids = os.times()
    doc = {"wall": prof.wall, "cpu": prof.cpu, "start_monotonic": start_wall, "startup_cpu": start_cpu,
           "end_monotonic": time.monotonic(), "children_cpu": kids.children_user + kids.children_system, **extra}
    with open(o.result, "w") as f:
        json.dump(doc, f)


# ---- the parent ------------------------------------------------------------------------------------
def measure(kind: str, o, tree: str) -> dict:
    """One child process of ``kind`` with the package of ``tree`` first on its path."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        result = f.name
    cmd = [sys.executable, os.path.abspath(__file__), "--child", kind, "--result", result, "-n", o.net,
           "--batch", str(o.batch), "--scenes", str(o.scenes), "-s", str(o.seed), "--rollout", f"{o.rollout:g}",
           "--threads", str(o.threads)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([tree, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    with tempfile.TemporaryDirectory(prefix="profile-cache-") as cold:
        if o.cold:     # a first run: nothing read before (the network cache empty)
            env["XDG_CACHE_HOME"] = cold
        t0, c0 = time.monotonic(), os.times()
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tempfile.gettempdir())
        t1, c1 = time.monotonic(), os.times()
    if proc.returncode != 0:
        sys.exit(f"profile: {kind} in {tree} failed:\n{proc.stderr[-2000:]}")
    with open(result) as f:
        doc = json.load(f)
    os.remove(result)
    doc["total_wall"] = t1 - t0
    doc["total_cpu"] = (c1.children_user - c0.children_user) + (c1.children_system - c0.children_system)
    if kind == "run":
        doc["wall"]["python startup"] = doc["start_monotonic"] - t0
        doc["cpu"]["python startup"] = doc["startup_cpu"]
        doc["wall"]["exit"] = t1 - doc["end_monotonic"]
        doc["cpu"][SUBPROCESSES] = doc["children_cpu"]     # their wall time is their caller's phase's
        doc["cpu"]["exit"] = max(doc["total_cpu"] - sum(doc["cpu"].values()), 0.0)
    return doc


def order(kind: str) -> list[str]:
    head = ["python startup"] if kind == "run" else []
    tail = ["other (the command's own code)"] + ([SUBPROCESSES, "exit"] if kind == "run" else [])
    return head + [p for p, _ in PHASES] + tail


def best(runs: list[dict]) -> dict:
    """The least disturbed run: least total wall time (``run``), most scenes per CPU second (generate)."""
    return min(runs, key=lambda d: d["total_wall"] if "scenes_per_s" not in d else -d["scenes_per_cpu_s"])


def table(kind: str, results: dict[str, list[dict]]) -> list[str]:
    labels = list(results)
    docs = {k: best(v) for k, v in results.items()}
    lines = ["| phase | " + " | ".join(f"{k}: wall s | {k}: CPU s" for k in labels) + " |",
             "|---|" + "---|---|" * len(labels)]
    for p in order(kind):
        cells = [(d["wall"].get(p), d["cpu"].get(p)) for d in docs.values()]
        if all((w or 0.0) < 5e-4 and (c or 0.0) < 5e-4 for w, c in cells):
            continue
        lines.append(f"| {p} | " + " | ".join(f"{w or 0:.3f} | {c or 0:.3f}" for w, c in cells) + " |")
    lines.append("| **sum of phases** | " + " | ".join(
        f"**{sum(d['wall'].values()):.2f}** | **{sum(d['cpu'].values()):.2f}**" for d in docs.values()) + " |")
    if kind == "run":
        lines.append("| **wall end to end (outside)** | " + " | ".join(
            f"**{d['total_wall']:.2f}** | {d['total_cpu']:.2f}" for d in docs.values()) + " |")
        lines.append("| all runs, wall end to end | " + " | ".join(
            ", ".join(f"{r['total_wall']:.2f}" for r in v) + " | " for v in results.values()) + "|")
    else:
        lines.append("| **scenes per wall s / per CPU s** | " + " | ".join(
            f"**{d['scenes_per_s']:.1f}** | **{d['scenes_per_cpu_s']:.1f}**" for d in docs.values()) + " |")
        lines.append("| all runs, scenes per CPU s | " + " | ".join(
            ", ".join(f"{r['scenes_per_cpu_s']:.1f}" for r in v) + " | " for v in results.values()) + "|")
    return lines


def rows(results: dict) -> list[dict]:
    """One object per profile and phase, a wall and a CPU column per checkout (the best run's),
    for benchmarks/report.py's table."""
    out = []
    for kind, by_label in results.items():
        docs = {label: best(v) for label, v in by_label.items()}
        for p in order(kind) + ["total"]:
            row = {"profile": kind, "phase": p}
            for label, d in docs.items():
                w = sum(d["wall"].values()) if p == "total" else d["wall"].get(p, 0.0)
                c = sum(d["cpu"].values()) if p == "total" else d["cpu"].get(p, 0.0)
                row[f"{label}: wall s"], row[f"{label}: CPU s"] = round(w, 3), round(c, 3)
            if p == "total" or any(v >= 5e-4 for k, v in row.items() if k.endswith(" s")):
                out.append(row)
        if kind == "generate":
            out.append({"profile": kind, "phase": "scenes per CPU s",
                        **{f"{label}: CPU s": round(d["scenes_per_cpu_s"], 2) for label, d in docs.items()}})
    return out


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("-n", "--net-file", dest="net", default=BIG, help="network (default: ingolstadt21, 84 km)")
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--scenes", type=int, default=64, help="windows of the generation profile")
    p.add_argument("--threads", type=int, default=1, help="torch threads of the generation profile "
                   "(run uses its own: core.threads)")
    p.add_argument("--rollout", type=float, default=60.0, help="run's --rollout")
    p.add_argument("--repeats", type=int, default=2, help="runs of each measurement, in turns")
    p.add_argument("--only", choices=("run", "generate"), default=None)
    p.add_argument("--cold", action="store_true", help="every process with an empty cache directory "
                   "(XDG_CACHE_HOME): a first run on the network; else the user's cache, warm after one run")
    p.add_argument("--before", metavar="DIR", default=None,
                   help="a checkout of the package (its root) measured beside this one")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="write the results as JSON")
    p.add_argument("--child", choices=("run", "generate"), default=None, help=argparse.SUPPRESS)
    p.add_argument("--result", default=None, help=argparse.SUPPRESS)
    return p.parse_args(args)


def main(o) -> int:
    if o.child:
        child(o)
        return 0
    trees = {"this checkout": ROOT}
    if o.before:
        trees = {"before": os.path.abspath(o.before), "after": ROOT}
    kinds = [o.only] if o.only else ["run", "generate"]
    results = {k: {label: [] for label in trees} for k in kinds}
    for _ in range(o.repeats):
        for kind in kinds:
            for label, tree in trees.items():
                results[kind][label].append(measure(kind, o, tree))
                print(f"{kind} {label}: {results[kind][label][-1]['total_wall']:.1f} s", file=sys.stderr)
    command = "python benchmarks/profile.py " + " ".join(sys.argv[1:])
    out = [f"Command: `{command.strip()}`", "",
           f"Network {os.path.relpath(o.net, ROOT)}; load average before {os.getloadavg()[0]:.2f} on "
           f"{os.cpu_count()} cores; best of {o.repeats} runs each, taking turns; "
           f"{'an empty cache in every process' if o.cold else 'the cache as left by the runs before'}.", ""]
    if "run" in kinds:
        out += [f"`python -m sumo_scendiff.run -n NET --scenes 1 --rollout {o.rollout:g}` (one window):", ""]
        out += table("run", results["run"]) + [""]
    if "generate" in kinds:
        out += [f"`generate` of {o.scenes} windows at batch {o.batch}, {o.threads} torch thread(s), "
                f"maps rendered beforehand:", ""]
        out += table("generate", results["generate"])
    print("\n".join(out))
    if o.output:
        os.makedirs(os.path.dirname(os.path.abspath(o.output)), exist_ok=True)
        with open(o.output, "w") as f:
            json.dump({"command": ["python", "benchmarks/profile.py", *sys.argv[1:]], "rows": rows(results),
                       "table": out, "results": results}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
