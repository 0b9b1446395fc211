"""Soak: a long co-simulation through the public API (sumo_scendiff.CoSimulation), as a CARLA bridge or
an RL loop runs it for hours: resident memory, seeding latency and what the project keeps per vehicle.

    python benchmarks/soak.py                                   # 3 600 s on ingolstadt21, 3 egos
    python benchmarks/soak.py --duration 600 --egos 2 -o /tmp/soak.json
    python benchmarks/soak.py -c networks/x.sumocfg --duration 120     # any scenario

The scenario (default: the largest real city of ../shared/nets that ships a configuration,
resco_ingolstadt21, with its demand) runs in libsumo from the configuration's begin at its own step.
``--egos`` caller vehicles drive long routes (drawn with ``--seed`` between car edges, ``--route-m``
to twice that long); each one is re-seeded with ``reseed_ahead(ego, every_m, ahead_m)`` called every
step, then stepped and ``verify``-ed as the README's snippet does. An ego that arrives is replaced by a
new one under a new id (a bridge's next episode). Every ``--period`` simulated seconds one line: the
process's resident memory (/proc/self/statm; libsumo runs in this process, so SUMO's memory is in it),
the seeding latency (``reseed_ahead`` + ``verify``, wall clock) median and p95 of the period's
seedings, SUMO's vehicle count, the project's vehicles alive, the vTypes and routes SUMO holds, and
the sizes of the containers in the co-simulation object (:func:`state_sizes`).

At the end, the leave-nothing-behind check (:func:`leftovers`): of the vehicles the project added and
SUMO removed since, which are still named anywhere in the co-simulation object's state (its dicts,
lists and sets, recursively; the network and the model left out), which still have their vType or
route in SUMO, and the egos gone that the object still keeps an entry for. Targets (issue 62): RSS
after the first period grows <= 10 % to the end; p95 seeding latency of the last 10 simulated
minutes <= 1.5x the first 10's. docs/benchmarks.md ("Soak and memory") has the figures.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
import warnings

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

DEFAULT_CONFIG = os.path.join(ROOT, "..", "shared", "nets", "resco_ingolstadt21", "ingolstadt21.sumocfg")
MEMORY_GROWTH = 0.10     # target: RSS after the first period grows at most this much to the end
LATENCY_RATIO = 1.5      # target: p95 latency of the last window <= this x the first window's
LATENCY_WINDOW = 600.0   # s of simulated time the latency target compares at both ends
PENDING_S = 120.0        # s an ego may wait for its insertion before it is replaced
SEEDED = re.compile(r"^(sd\.\d+\.\d+)")   # a seeded vehicle's id (CoSimulation prefix "sd") and its _route
# the seeded vehicle a SUMO vType or route is of: its own type (SUMO's "{type}@{id}"), its route
# (SUMO's "!{id}!var#1", the seeder's staging "{id}_route")
OF_SEEDED = re.compile(r"(?:^|[@!])(sd\.\d+\.\d+)(?:$|[!_])")


def get_options(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-c", "--config", default=DEFAULT_CONFIG, help="SUMO scenario (.sumocfg)")
    p.add_argument("--duration", type=float, default=3600.0, help="simulated seconds")
    p.add_argument("--egos", type=int, default=3, help="caller vehicles re-seeded as they drive")
    p.add_argument("--every-m", type=float, default=150.0, help="reseed_ahead's every_m")
    p.add_argument("--ahead-m", type=float, default=100.0, help="reseed_ahead's ahead_m")
    p.add_argument("--density", type=float, default=None,
                   help="veh/km asked of each window (default: the host's own level, as the README's API)")
    p.add_argument("--route-m", type=float, default=1500.0, help="an ego's route is this to twice this long (m)")
    p.add_argument("--period", type=float, default=300.0, help="simulated seconds per printed line")
    p.add_argument("--steps", type=int, default=None, help="ODE solver steps (default: the generator's)")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--out", default=None, help="results JSON (e.g. results/soak.json)")
    o = p.parse_args(argv)
    if not o.duration > 0 or o.egos < 1 or not o.period > 0:
        p.error("--duration and --period must be > 0, --egos >= 1")
    if not os.path.isfile(o.config):
        p.error(f"-c: {o.config}: no such file")
    return o


def rss_mib() -> float:
    """This process's resident memory (MiB)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


# ---- the co-simulation object's state ------------------------------------------------------------

def _owned(x) -> bool:
    return type(x).__module__.startswith("sumo_scendiff") and hasattr(x, "__dict__")


def walk_state(cosim):
    """(path, value) for every attribute of ``cosim`` and the project's objects it holds, recursively,
    and every item of their containers; the network, the generator and the simulation are left out
    (static, or not the project's state)."""
    skip = {id(cosim.net), id(cosim.generator), id(cosim.sim)}
    seen: set[int] = set()
    stack = [("cosim", cosim)]
    while stack:
        path, x = stack.pop()
        if id(x) in skip or id(x) in seen:
            continue
        seen.add(id(x))
        yield path, x
        if _owned(x):
            stack += [(f"{path}.{k}", v) for k, v in vars(x).items()]
        elif isinstance(x, dict):
            stack += [(f"{path}[k]", k) for k in x] + [(f"{path}[]", v) for v in x.values()]
        elif isinstance(x, (list, tuple, set, frozenset)):
            stack += [(f"{path}[]", v) for v in x]


def state_sizes(cosim) -> dict[str, int]:
    """Size of each container reached from ``cosim`` by attributes (path -> len; dicts, lists, sets,
    arrays), the containers inside them summed under their parent's path with ``[]``."""
    out: dict[str, int] = {}
    for path, x in walk_state(cosim):
        if isinstance(x, (dict, list, set, frozenset, tuple, np.ndarray)) and not isinstance(x, str):
            out[path] = out.get(path, 0) + len(x)
    return out


def named_vehicles(cosim) -> set[str]:
    """The seeded vehicle ids any string in ``cosim``'s state names (an id, its _type, its _route)."""
    return {m.group(1) for _, x in walk_state(cosim) if isinstance(x, str) and (m := SEEDED.match(x))}


def leftovers(cosim, sim, added: set[str], egos_gone: set[str]) -> dict:
    """What stays of the project's vehicles SUMO removed: named in the co-simulation object's state,
    their vType or route still in SUMO; and the object's entries for egos gone."""
    live = set(sim.vehicle.getIDList())
    removed = added - live
    kept_types = {m.group(1) for t in sim.vehicletype.getIDList() if (m := OF_SEEDED.search(t))}
    kept_routes = {m.group(1) for r in sim.route.getIDList() if (m := OF_SEEDED.search(r))}
    in_state = named_vehicles(cosim) & removed
    ego_entries = sorted(set(cosim._last_seed_xy) & egos_gone)
    return {"added": len(added), "removed_by_sumo": len(removed), "alive": len(added & live),
            "removed_named_in_state": len(in_state), "examples_in_state": sorted(in_state)[:5],
            "removed_vtypes_left_in_sumo": len(kept_types & removed),
            "removed_routes_left_in_sumo": len(kept_routes & removed),
            "gone_egos_with_state": len(ego_entries), "examples_gone_egos": ego_entries[:5]}


# ---- egos ----------------------------------------------------------------------------------------

class Egos:
    """The caller's vehicles: ``n`` at a time on long routes; one that arrives (or never gets in)
    is replaced by a new one with a new id."""

    def __init__(self, sim, net, n: int, route_m: float, rng):
        self.sim, self.rng, self.route_m = sim, rng, route_m
        self.edges = [e.getID() for e in net.sumo_net.getEdges(withInternal=False) if e.allows("passenger")]
        self.slots: list[tuple[str, float, bool]] = []     # (id, time added, seen in SUMO)
        self.made, self.gone = 0, set()
        for _ in range(n):
            self.slots.append(self._spawn())

    def _route(self) -> list[str]:
        for _ in range(200):
            a, b = self.rng.choice(self.edges, 2, replace=False)
            stage = self.sim.simulation.findRoute(str(a), str(b))
            if stage.edges and self.route_m <= stage.length <= 2 * self.route_m:
                return list(stage.edges)
        raise RuntimeError(f"no route of {self.route_m:g} to {2 * self.route_m:g} m found between car edges")

    def _spawn(self) -> tuple[str, float, bool]:
        vid = f"ego{self.made}"
        self.made += 1
        self.sim.route.add(f"{vid}_route", self._route())
        self.sim.vehicle.add(vid, f"{vid}_route", depart="now", departLane="best", departSpeed="max")
        return vid, self.sim.simulation.getTime(), False

    def update(self, live: set[str]) -> list[str]:
        """The egos driving now, replacing those gone."""
        now = self.sim.simulation.getTime()
        for k, (vid, t0, seen) in enumerate(self.slots):
            if vid in live:
                self.slots[k] = (vid, t0, True)
            elif seen or now - t0 > PENDING_S:
                if not seen:
                    self.sim.vehicle.remove(vid)
                self.gone.add(vid)
                self.slots[k] = self._spawn()
        return [vid for vid, _, seen in self.slots if seen and vid in live]


# ---- the run -------------------------------------------------------------------------------------

def start_scenario(config: str, seed: int):
    """libsumo on the scenario as the product starts a user's (its step, its options, its begin)."""
    from sumo_scendiff.sim.scenario import scenario_from_files
    from sumo_scendiff.sim.sumo import SimConfig, start, step_length_for
    scen = scenario_from_files(config=config)
    sim = start(SimConfig(net=scen.net, routes=scen.routes, additional=scen.additional,
                          step_length=step_length_for(scen), begin=scen.begin, seed=seed,
                          scenario_options=scen.options))
    return sim, scen


def period_line(rec: dict) -> str:
    return (f"t={rec['t']:6.0f} s  wall {rec['wall_s']:7.1f} s  rss {rec['rss_mib']:7.1f} MiB  "
            f"seedings {rec['seedings']:3d}  latency median {rec['latency_median_s']:.3f} s "
            f"p95 {rec['latency_p95_s']:.3f} s  vehicles {rec['vehicles']:4d}  ours {rec['ours_alive']:3d}  "
            f"vtypes {rec['sumo_vtypes']:5d}  routes {rec['sumo_routes']:5d}  state {rec['state_items']:6d}")


def snapshot(sim, cosim, t: float, wall: float, lat: list[float], added: set[str]) -> dict:
    """One period's record (see the module docstring)."""
    live = set(sim.vehicle.getIDList())
    sizes = state_sizes(cosim)
    return {"t": t, "wall_s": round(wall, 1), "rss_mib": round(rss_mib(), 1), "seedings": len(lat),
            "latency_median_s": round(float(np.median(lat)), 4) if lat else float("nan"),
            "latency_p95_s": round(float(np.percentile(lat, 95)), 4) if lat else float("nan"),
            "vehicles": len(live), "ours_alive": len(live & added),
            "sumo_vtypes": sim.vehicletype.getIDCount(), "sumo_routes": sim.route.getIDCount(),
            "state_items": sum(sizes.values()), "state_sizes": sizes}


def seed_egos(sim, cosim, egos: list[str], o, added: set[str]) -> list[float]:
    """One step of the caller: ``reseed_ahead`` for each ego, the step, ``verify`` of what was seeded
    (the README's snippet); the latency of each seeding that happened (s)."""
    done, lat = [], []
    for ego in egos:
        t0 = time.perf_counter()
        s = cosim.reseed_ahead(ego, every_m=o.every_m, ahead_m=o.ahead_m, density=o.density)
        if s is not None:
            done.append((s, time.perf_counter() - t0))
            added.update(s.agent_ids)
    sim.simulationStep()
    for s, dt in done:
        t0 = time.perf_counter()
        cosim.verify(s, warn=False)
        lat.append(dt + time.perf_counter() - t0)
    return lat


def soak(o, echo=print, partial=None) -> dict:
    """Run the soak of options ``o`` (:func:`get_options`); the records and the end's check.
    ``partial``: called with the records so far after each period (a long run's file kept current)."""
    from sumo_scendiff import CoSimulation, Network, ScenarioGenerator
    from sumo_scendiff.generation.generator import GenerationConfig
    warnings.simplefilter("ignore")          # the seeding's per-window notes are not the soak's subject
    sim, scen = start_scenario(o.config, o.seed)
    try:
        net = Network.load(scen.net)
        cfg = GenerationConfig() if o.steps is None else GenerationConfig(steps=o.steps)
        cosim = CoSimulation(sim, net, ScenarioGenerator.load(config=cfg), seed=o.seed)
        egos = Egos(sim, net, o.egos, o.route_m, np.random.default_rng(o.seed))
        t_begin, wall0 = sim.simulation.getTime(), time.perf_counter()
        added: set[str] = set()
        periods, seedings, lat = [], [], []
        while sim.simulation.getTime() - t_begin < o.duration:
            live = set(sim.vehicle.getIDList())
            now = seed_egos(sim, cosim, egos.update(live), o, added)
            t = sim.simulation.getTime() - t_begin
            seedings += [(t, x) for x in now]
            lat += now
            if t >= o.period * (len(periods) + 1) - 1e-9:
                periods.append(snapshot(sim, cosim, t, time.perf_counter() - wall0, lat, added))
                echo(period_line(periods[-1]))
                lat = []
                if partial is not None:
                    partial({"periods": periods, "seedings": seedings, "partial": True})
        left = leftovers(cosim, sim, added, egos.gone)
        return {"periods": periods, "seedings": seedings,
                "leftovers": left, "egos_used": egos.made, "scenario": scen.config or scen.net,
                "begin": t_begin, "step_length": sim.simulation.getDeltaT()}
    finally:
        sim.close()


def targets(res: dict, duration: float) -> dict:
    """The issue's two targets, measured."""
    p = res["periods"]
    first, last = p[0]["rss_mib"], p[-1]["rss_mib"]
    lat = np.array([x for _, x in res["seedings"]])
    t = np.array([t for t, _ in res["seedings"]])
    head, tail = lat[t <= LATENCY_WINDOW], lat[t > duration - LATENCY_WINDOW]
    p_head = float(np.percentile(head, 95)) if len(head) else float("nan")
    p_tail = float(np.percentile(tail, 95)) if len(tail) else float("nan")
    return {"rss_after_first_period_mib": first, "rss_end_mib": last, "rss_growth": round(last / first - 1, 4),
            "rss_growth_ok": bool(last / first - 1 <= MEMORY_GROWTH),
            "p95_first_window_s": round(p_head, 4), "p95_last_window_s": round(p_tail, 4),
            "p95_ratio": round(p_tail / p_head, 3) if p_head > 0 else None,
            "p95_ratio_ok": bool(p_tail <= LATENCY_RATIO * p_head),
            "window_s": LATENCY_WINDOW, "seedings_first_window": len(head), "seedings_last_window": len(tail)}


def main(argv=None) -> int:
    o = get_options(argv)
    print(f"soak: {o.config}, {o.duration:g} s, {o.egos} egos re-seeded every {o.every_m:g} m", flush=True)
    command = "python benchmarks/soak.py " + " ".join(sys.argv[1:] if argv is None else argv)

    def write(res: dict) -> None:
        if o.out:
            os.makedirs(os.path.dirname(os.path.abspath(o.out)), exist_ok=True)
            with open(o.out + ".tmp", "w") as f:
                json.dump({**res, "options": vars(o), "command": command}, f, indent=1)
            os.replace(o.out + ".tmp", o.out)
    res = soak(o, echo=lambda line: print(line, flush=True), partial=write)
    res["seedings"] = [[round(t, 1), round(x, 4)] for t, x in res["seedings"]]
    res["targets"] = targets(res, o.duration) if res["periods"] else {}
    print(json.dumps({"targets": res["targets"], "leftovers": res["leftovers"]}, indent=1), flush=True)
    write(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
