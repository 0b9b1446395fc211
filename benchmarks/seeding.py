"""Benchmark: seeding generated traffic into SUMO -- placement rate, and 60-s rollouts of the model's
agents and Lane-uniform's beside SUMO's own traffic in the same windows and the same traffic state.

    python benchmarks/seeding.py [-n NET ...] [--windows 10] [--rollout 60] [-s 0] [-o runs/bench_seeding.md]
    python benchmarks/seeding.py -n networks/city.net.xml \\
        -n ../shared/nets/resco_cologne8/cologne8.net.xml \\
        -n ../shared/nets/resco_ingolstadt21/ingolstadt21.net.xml --windows 8 -o runs/bench_seeding.md

Per network: its own demand (a real city: the route file beside the net, from its first departure,
as the data recorder runs it; otherwise random trips with the recorder's vehicle mix) is warmed up
for ``--warmup`` s and the state saved at that time T. For each window (``auto_windows``):

* **SUMO**: load the state; the vehicles whose centre is inside the window are the agents.
* **Scenario Diffusion**: load the state, remove the vehicles inside the window, generate the window
  map-only (no tokens, p_mask = 1) and seed it with ``CoSimulation.place`` (the vehicles around the
  window are the existing ones, so nothing is seeded on top of them); step; ``verify``.
* **Lane-uniform**: the same with the baseline's scene (its own Poisson count rule).

Every rollout runs in a freshly started SUMO that loads the state (as ``run``'s ``Session`` does), so
each method starts from the same state and random streams. Every method gets one step (the seeding
step for the generated ones) and ``rollout`` of ``--rollout`` s. Placement = agents within 0.5 m /
0.1 rad of their generated pose after that step, over the agents generated (refused, misplaced and
dropped-on-existing ones count against it); "dropped (junction foe)" are agents not seeded because
another agent was already in the area their junction links share (``sim.junctions``; off with
``--no-junction-rule``) or because an agent waiting inside a junction on red found its place at the
stop line taken (``sim.stop_lines``; "moved from a red junction" counts those moved there, off with
``--no-red-stop-line``), and the second placement rate leaves both kinds of drop out. "Slowed" counts
agents that departed below their generated speed, capped at the Krauss safe speed behind the vehicle
or red light ahead (``Seeder.seed`` / ``settle``), or a foe already inside the junction ahead
(``junction_leaders``, off with ``--no-junction-leaders``), or standing to wait for a junction foe.
Rollout rates are per 100 agents; "x SUMO" columns are the method's rate over SUMO's. Collision events
are split per net by where and with whom (on a junction, with a host vehicle, a host vehicle ran into
the agent, in the first 10 s), beside the teleports.

Beside them, every collision of the whole simulation per 100 vehicles present (the host's own
junction collisions too), per net and method: the yardstick for a window's few agents. ``--events
FILE`` writes every collision, teleport and early hard braking of SUMO's and the model's rollouts
in detail (both parties, their links' signal and right of way, their last steps, how the agents
were seeded; ``sim.events``), and the host-only collisions, as a pickle.

``--scenes FILE`` keeps the generated scenes (per net, windows and generation options) in a pickle:
a later run with the same options reads them instead of generating, so a change to the seeder is
measured on the very same scenes (and no model needs to load).

Determinism: with libsumo 1.28 the steps after a ``loadState`` depend on where SUMO's objects lie
in memory (measured on city.net.xml: the same state file loaded into a fresh SUMO gives other
vehicle positions one step later from run to run, even within one process; warm-ups from scratch
repeat exactly). So the model's scenes are generated here, and SUMO runs in a fresh interpreter
per net (``--worker``: benchmarks/seeding_sim.py) that is given only that net's inputs and has
nothing that varies between runs: no address space randomisation (``personality``, as
``setarch -R``), no torch, one BLAS thread, a fixed hash seed, a fixed environment (only ``WORKER_ENV``: its size moves the stack),
fixed file names (``$TMPDIR/scendiff-bench-seeding-UID/work``, locked),
stdout / stderr to a pipe / file, windows and methods in a fixed order, the begin time on the step
grid. Then the same seed gives the same numbers, whatever other nets the command has (checked by
repeating runs on this machine; another SUMO build or machine may give other numbers), for the same
checkpoint: the three methods' rollouts share the net's worker, so another model's vehicles can move
Lane-uniform's numbers by an event or two (measured: 7 against 8 collisions in 781 agents). Every
rollout starts a fresh SUMO because SUMO's random streams are not part of a saved state
(``--save-state.rng`` crashes libsumo 1.28 on the second ``loadState``). Prints markdown tables
(and writes them with ``-o``).
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import re
import sys
import time
from collections import Counter

from seeding_sim import sim_config, worker
from seeding_tables import tables

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
SHARED = os.path.join(ROOT, "..", "shared", "nets")
CITY = os.path.join(ROOT, "networks", "city.net.xml")
REAL = ("resco_cologne1/cologne1.net.xml", "resco_cologne3/cologne3.net.xml",
        "resco_cologne8/cologne8.net.xml", "resco_ingolstadt1/ingolstadt1.net.xml",
        "resco_ingolstadt7/ingolstadt7.net.xml", "resco_ingolstadt21/ingolstadt21.net.xml",
        "berlin_doerpfeldstr/net.net.xml.gz")
WORKER_ENV = ("PATH", "HOME", "TMPDIR", "SUMO_HOME", "PYTHONPATH", "LD_LIBRARY_PATH", "VIRTUAL_ENV")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("-n", "--net-file", "--net", dest="nets", action="append", default=None, metavar="NET",
                   help="network (repeat); default: networks/city.net.xml + the real cities with demand")
    p.add_argument("--windows", type=int, default=10, help="windows per network (auto_windows)")
    p.add_argument("--rollout", type=float, default=60.0, help="seconds SUMO drives after hand-off")
    p.add_argument("--warmup", type=float, default=600.0, help="seconds of demand before the state T")
    p.add_argument("--density", type=float, default=100.0,
                   help="random trips (nets without demand): vehicles / h / km of lane")
    p.add_argument("--step-length", type=float, default=0.5)
    p.add_argument("--checkpoint", default=None, help="model checkpoint (default: the shipped one)")
    p.add_argument("--scene-guidance", type=float, default=None,
                   help="the global token's guidance weight (default: the checkpoint's)")
    p.add_argument("--scene-guidance-sigma", type=float, default=None, metavar="SIGMA",
                   help="... applied only above this noise level (default: the checkpoint's)")
    p.add_argument("--no-lane-snap", dest="lane_snap", action="store_false",
                   help="seed the decoded poses, not snapped onto lane centre lines (generate's lane_snap)")
    p.add_argument("--scenes", default=None, metavar="FILE",
                   help="generated scenes cache (pickle): read if it has this net's windows, else generate "
                        "and write; lets a change to the seeder be measured on the very same scenes")
    p.add_argument("--no-junction-rule", dest="junction_rule", action="store_false",
                   help="seed agents on conflicting junction links as generated (sim.junctions off)")
    p.add_argument("--no-junction-leaders", dest="junction_leaders", action="store_false",
                   help="settle without the foes already inside a junction as leaders (Seeder.junction_leaders off)")
    p.add_argument("--no-red-stop-line", dest="red_stop_line", action="store_false",
                   help="seed agents waiting inside a junction on red where generated, not at their stop line "
                        "(Seeder.red_to_stop_line off)")
    p.add_argument("--no-width-cap", dest="width_cap", action="store_false",
                   help="seed the generated widths, also those wider than the network's junctions assume "
                        "(Seeder.width_cap off)")
    p.add_argument("--signals", action="store_true",
                   help="generate with the traffic lights' states at T (run's --signals)")
    p.add_argument("--signal-guidance", type=float, default=None,
                   help="with --signals: the lights' guidance weight (default: generate's)")
    p.add_argument("--no-red-queues", dest="red_queues", action="store_false",
                   help="with --signals: the model's own speeds in a red light's queue (run's --no-red-queues)")
    p.add_argument("--scene-density", default="auto", metavar="D|auto|model|window",
                   help="the level each window is generated at: veh / km of car lane; 'auto' (default, as run "
                        "seeds with demand): the host's own level around the window at T; 'model': the model's "
                        "own; 'window': the count SUMO's own traffic has in the window at T (told the count)")
    p.add_argument("--events", default=None, metavar="FILE",
                   help="write every collision / teleport of SUMO's and the model's rollouts in detail "
                        "(pickle; sim.events)")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="also write the tables here")
    return p.parse_args(args)


def default_nets() -> list[str]:
    return [CITY] + [os.path.normpath(os.path.join(SHARED, r)) for r in REAL
                     if os.path.exists(os.path.join(SHARED, r))]


# ---- one network ---------------------------------------------------------------------------------
def demand(net, o, tmp: str):
    """(route file, begin, extra SUMO args, label): the net's own demand, else random trips."""
    from sumo_scendiff.data.demand import (
        RandomDemand,
        check_routes,
        find_demand,
        random_trips,
        write_vtypes,
    )
    routes = find_demand(net)
    if routes:
        first = check_routes(routes, {ln.edge for ln in net.lanes})  # first departure (data CLI -> record)
        begin = math.floor(first / o.step_length) * o.step_length   # on the step grid, see the docstring
        return routes, begin, [], f"own demand {os.path.basename(routes)}, from t = {begin:g} s"
    vtypes = write_vtypes(os.path.join(tmp, "vtypes.add.xml"))
    trips = random_trips(net.path, os.path.join(tmp, "trips.rou.xml"),
                         RandomDemand(o.density, o.warmup + o.rollout + 60.0, o.seed))
    with open(trips) as f:   # without randomTrips' header comment (its time stamp): the same bytes every run
        text = re.sub(r"<!--.*?-->\s*", "", f.read(), count=1, flags=re.S)
    with open(trips, "w") as f:
        f.write(text)
    return trips, 0.0, ["--additional-files", vtypes], f"random trips {o.density:g} veh/h/km"


@contextlib.contextmanager
def no_aslr():
    """Programs started inside run without address space randomisation (Linux ``personality``,
    what ``setarch -R`` does); yields whether that worked."""
    import ctypes
    ADDR_NO_RANDOMIZE = 0x0040000
    old = -1
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        old = libc.personality(0xFFFFFFFF)
        if old != -1 and libc.personality(old | ADDR_NO_RANDOMIZE) == -1:
            old = -1
    except (OSError, AttributeError):
        pass
    if old == -1:
        print("could not turn off address space randomisation: rollout numbers may vary between runs",
              file=sys.stderr)
    try:
        yield old != -1
    finally:
        if old != -1:
            libc.personality(old)


def cached_scenes(path: str | None, name: str, windows: list, o, scenes: list | None = None) -> list | None:
    """Read (``scenes`` None) or add a net's scenes in the cache ``path``, keyed by the net, every
    window's pose and the generation options (another checkpoint or seed must not reuse them)."""
    import pickle
    if not path:
        return None
    key = (name, o.checkpoint, o.seed, getattr(o, "signals", False), getattr(o, "signal_guidance", None), getattr(o, "scene_density", None), o.scene_guidance, o.scene_guidance_sigma, o.lane_snap, tuple((round(w.cx, 3), round(w.cy, 3), round(w.yaw, 4), w.size) for w in windows))
    if getattr(o, "signals", False):     # the lights' queue rule (keys of runs without lights stay as they were)
        key += (("red_queues", getattr(o, "red_queues", True)),)
    cache = {}
    if os.path.exists(path):
        with open(path, "rb") as f:
            cache = pickle.load(f)
    if scenes is None:
        return cache.get(key)
    cache[key] = scenes
    with open(path, "wb") as f:
        pickle.dump(cache, f)
    return scenes


def bench_net(path: str, gen, o, explicit: bool) -> dict | None:
    """Windows and the model's scenes here; everything SUMO does in a fresh child process."""
    import pickle
    import shutil
    import tempfile

    from sumo_scendiff.data.demand import find_demand
    from sumo_scendiff.map.locations import auto_windows
    from sumo_scendiff.map.network import Network

    t_start = time.perf_counter()
    net = Network.load(path)
    if find_demand(net) is None and not explicit and os.path.abspath(path) != os.path.abspath(CITY):
        print(f"{net.name}: no demand beside the net, skipped", file=sys.stderr)
        return None
    locs = auto_windows(net, o.windows, seed=o.seed)
    windows = [loc.window for loc in locs]
    # SUMO's steps after a loadState depend on where its objects lie in memory (see the module
    # docstring): a fresh interpreter without torch or BLAS threads, with a fixed hash seed, without
    # address space randomisation, fixed file names and stdout / stderr, given only this net's inputs,
    # runs the same way whatever else the command does.
    import fcntl
    opts = {k: getattr(o, k) for k in ("warmup", "rollout", "density", "step_length", "seed", "junction_rule",
                                          "width_cap", "junction_leaders", "red_stop_line")}
    opts["events"] = bool(getattr(o, "events", None))
    top = os.path.join(tempfile.gettempdir(), f"scendiff-bench-seeding-{os.getuid()}")
    os.makedirs(top, exist_ok=True)
    with open(os.path.join(top, "lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)                 # one benchmark at a time uses these names
        io = os.path.join(top, "work")
        shutil.rmtree(io, ignore_errors=True)
        os.makedirs(io)
        src, dst, log = (os.path.join(io, n) for n in ("in.pkl", "out.pkl", "err.txt"))
        dem = demand(net, o, io)
        t = time.perf_counter()
        scenes = cached_scenes(o.scenes, net.name, windows, o)
        if scenes is None:   # map-only (no tokens, p_mask = 1), with the lights as they are at T
            lights, density = host_at_t(path, dem, o, net, windows)
            scenes = gen().generate(net, windows, seed=o.seed, signals=lights, density=density)
            cached_scenes(o.scenes, net.name, windows, o, scenes)
        t_gen = time.perf_counter() - t
        with open(src, "wb") as f:
            pickle.dump({"path": os.path.abspath(path), "windows": windows, "scenes": scenes, "opts": opts,
                         "demand": dem, "dir": io}, f)
        fixed = run_worker(net.name, len(windows), src, dst, log)
        with open(dst, "rb") as f:
            r = pickle.load(f)
        shutil.rmtree(io, ignore_errors=True)
    r["repeatable"] = fixed
    r.update(net=net.name, windows=len(windows), kinds=dict(Counter(loc.kind for loc in locs)))
    r["seconds"].update(generate=t_gen, total=time.perf_counter() - t_start)
    return r


def run_worker(name: str, windows: int, src: str, dst: str, log: str) -> bool:
    """``seeding.py --worker SRC DST`` (seeding_sim.py) in a fresh interpreter, its progress shown;
    exits naming the net if it fails. Returns whether address space randomisation was off."""
    import subprocess

    from tqdm import tqdm

    # only the variables a worker needs: without address space randomisation the environment's
    # size moves the stack and with it SUMO's memory layout (measured: one more variable of 3 kB
    # changed Lane-uniform's teleports on cologne1)
    env = {k: os.environ[k] for k in WORKER_ENV if k in os.environ}
    env.update(PYTHONHASHSEED="0", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    with no_aslr() as fixed, open(log, "w") as err, \
            tqdm(total=windows, desc=name, unit="window", leave=False) as bar:
        proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), "--worker", src, dst],
                                env=env, stdout=subprocess.PIPE, stderr=err, text=True)
        for _ in proc.stdout:                         # one line per window done
            bar.update(1)
        if proc.wait() != 0:
            with open(log) as f:
                sys.exit(f"{name}: the SUMO worker failed:\n{f.read()[-3000:]}")
    return fixed


def host_at_t(path: str, dem: tuple, o, net, windows: list) -> tuple[list | None, list | None]:
    """Each window's traffic-light states (``--signals``) and host density (``--scene-density
    auto``) at T: the warm-up run here once more (warm-ups from scratch repeat exactly, see the
    docstring), so the model sees the state the rollouts start with."""
    sd = getattr(o, "scene_density", None)
    density = None if sd in (None, "model", "auto", "window") else float(sd)
    if not o.signals and sd not in ("auto", "window"):
        return None, density
    from sumo_scendiff.sim.density import host_density
    from sumo_scendiff.sim.lights import light_states
    from sumo_scendiff.sim.sumo import close, start
    sim = start(sim_config(path, dem, o))
    try:
        sim.simulationStep(dem[1] + o.warmup)
        lights = [light_states(sim, net.lights_in(w)) for w in windows] if o.signals else None
        if sd == "auto":
            density = [host_density(sim, net, w) for w in windows]
            density = [math.nan if d is None else d for d in density]
        elif sd == "window":                 # the vehicles the SUMO row of the tables counts
            from sumo_scendiff.sim.cosim import CoSimulation
            cosim = CoSimulation(sim, net, None, seed=o.seed)
            density = [len(cosim.existing(w).token_ids()) / max(net.car_lane_km(w), 1e-9) for w in windows]
        return lights, density
    finally:
        close(sim)


def main(o) -> int:
    import torch

    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    torch.manual_seed(o.seed)
    command = "python benchmarks/seeding.py " + " ".join(sys.argv[1:]) if sys.argv[0].endswith(
        "seeding.py") else "benchmarks/seeding.py (in-process)"
    t = time.perf_counter()
    loaded = []

    def gen():          # loaded only when a net's scenes are not in the --scenes cache
        if not loaded:
            loaded.append(ScenarioGenerator.load(o.checkpoint, GenerationConfig(
                scene_guidance=o.scene_guidance, scene_guidance_sigma=o.scene_guidance_sigma,
                lane_snap=o.lane_snap, signals=o.signals, red_queues=o.red_queues,
                **({} if o.signal_guidance is None else {"signal_guidance": o.signal_guidance}))))
        return loaded[0]
    results = []
    for path in (o.nets or default_nets()):
        r = bench_net(path, gen, o, explicit=o.nets is not None)
        if r is not None:
            results.append(r)
            print(f"{r['net']}: {r['seconds']['total']:.0f} s", file=sys.stderr)
    if getattr(o, "events", None):
        import pickle
        with open(o.events, "wb") as f:
            pickle.dump([e for r in results for e in r.get("events", [])], f)
    text = tables(results, o, command) + f"\n\nTotal wall time {time.perf_counter() - t:.0f} s.\n"
    from report import emit
    emit(text, o.output, "Seeding benchmark")
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        sys.exit(worker(*sys.argv[2:4]))
    sys.exit(main(get_options()))
