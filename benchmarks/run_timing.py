"""Benchmark: where the time of a ``run`` goes on a real city with its own traffic, and the seeding
overhead relative to SUMO driving (target: raster + generate + seed + export <= 10 % of rollout).

    python benchmarks/run_timing.py [-n NET] [-r ROUTES] [--scenes 8] [--rollout 60] [--begin SECONDS ...]
    python benchmarks/run_timing.py -o runs/bench_run_timing.md
    python benchmarks/run_timing.py -n NET --no-demand --scenes 1    # a window on a network alone

Runs ``python -m sumo_scendiff.run -n NET -r ROUTES --scenes 8 --rollout 60 -o TMP`` in-process
(``sumo_scendiff.run.get_options`` / ``run``; windows auto-chosen) once per ``--begin`` value
(``default``: run's own, 600 s of demand from its first departure; a number is passed as run's
``--begin``) and reads ``TMP/run.json``'s ``timing_s``: the warm-up to ``--begin`` is its ``warm_up``
(a part of "load"), beside SUMO's own vehicles kept in the windows. Prints a markdown table, configurations side by side
(and writes it with ``-o``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from sumo_scendiff.sim.seed_report import SEEDED, STATUSES

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
COLOGNE8 = os.path.normpath(os.path.join(ROOT, "..", "shared", "nets", "resco_cologne8", "cologne8.net.xml"))
PHASES = ("load", "raster", "generate", "seed", "rollout", "export")
OVERHEAD = ("raster", "generate", "seed", "export")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    p.add_argument("-n", "--net-file", "--net", dest="net", default=COLOGNE8)
    p.add_argument("-r", "--route-files", "--routes", dest="routes", default=None,
                   help="default: the route file beside the net (evaluate.find_demand)")
    p.add_argument("--no-demand", action="store_true", help="run on the network alone (no -r): the "
                   "warm-up rows stay empty; benchmarks/profile.py splits such a run finer")
    p.add_argument("--scenes", type=int, default=8)
    p.add_argument("--rollout", type=float, default=60.0)
    p.add_argument("--begin", action="append", default=None, metavar="default|SECONDS",
                   help="run's --begin (seconds of demand before seeding), one run per value (default: default)")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="also write the table here")
    return p.parse_args(args)


def one_run(o, routes: str, begin: float | None, tmp: str) -> dict:
    """Run the CLI in-process; its summary (run.json's, with ``timing_s``) and wall time."""
    from sumo_scendiff import run as run_mod
    args = ["-n", o.net, *(["-r", routes] if routes else []), "--scenes", str(o.scenes),
            "--rollout", f"{o.rollout:g}", "-s", str(o.seed), "-o", tmp]
    if begin is not None:
        args += ["--begin", f"{begin:g}"]
    t = time.perf_counter()
    summary = run_mod.run(run_mod.get_options(args))
    return {"args": args, "summary": summary, "wall": time.perf_counter() - t}


def table(results: list[tuple[str, dict]], o, routes: str, command: str) -> str:
    labels = [label for label, _ in results]
    lines = [f"Command: `{command}`", "",
             f"`python -m sumo_scendiff.run -n {os.path.relpath(o.net, ROOT)}"
             f"{f' -r {os.path.relpath(routes, ROOT)}' if routes else ''} "
             f"--scenes {o.scenes} --rollout {o.rollout:g} -s {o.seed} -o TMP [--begin B]` in-process, "
             f"windows auto-chosen, 1 process; load average before the run {o.load_before:.2f} "
             f"on {os.cpu_count()} cores (other jobs on the machine slow every phase)", "",
             "| | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]

    def row(name, cells):
        lines.append(f"| {name} | " + " | ".join(cells) + " |")

    S = [r["summary"] for _, r in results]
    T = [s["timing_s"] for s in S]
    n = [max(len(s["scenes"]), 1) for s in S]
    row("`--begin` passed", [" ".join(r["args"][r["args"].index("--begin"):][:2]) if "--begin" in r["args"]
                             else "none (no demand)" if o.no_demand else "none (600 s of demand)" for _, r in results])
    row("vehicles kept in the windows (SUMO's own when seeding)",
        [str(sum(sc.get("existing_vehicles", 0) for sc in s["scenes"])) for s in S])
    for ph in PHASES:
        row(f"{ph} (s): total / per scene",
            [f"{t.get(ph, 0.0):.2f} / {t.get(ph, 0.0) / k:.2f}" for t, k in zip(T, n)])
        if ph == "load":
            row("  of which warm-up inside run (s)", [f"{t.get('warm_up', 0.0):.2f}" for t in T])
            row("  load without warm-up (s)", [f"{t.get('load', 0.0) - t.get('warm_up', 0.0):.2f}" for t in T])
    row("sum of phases / wall of run() (s)",   # the warm-up is inside load
        [f"{sum(v for k, v in t.items() if k != 'warm_up'):.1f} / {r['wall']:.1f}" for t, (_, r) in zip(T, results)])
    over = [sum(t.get(k, 0.0) for k in OVERHEAD) for t in T]
    row("seeding overhead (raster + generate + seed + export) (s)", [f"{v:.2f}" for v in over])
    row("**overhead / rollout** (target ≤ 10 %)",
        [f"**{100.0 * v / t['rollout']:.1f} %**" if t.get("rollout") else "–" for v, t in zip(over, T)])
    sim_s = [len(s["scenes"]) * o.rollout for s in S]
    row("simulated rollout time (s); simulated s per wall s",
        [f"{v:g}; {v / t['rollout']:.0f}x" if t.get("rollout") else f"{v:g}; –" for v, t in zip(sim_s, T)])
    row("overhead / simulated rollout time", [f"{100.0 * v / x:.1f} %" if x else "–" for v, x in zip(over, sim_s)])
    for key, name in (("generated", f"agents generated (each {', '.join(STATUSES[:-1])} or {STATUSES[-1]})"),
                      ("existing_vehicles", "existing vehicles in the windows (tokens)"),
                      ("existing", "existing: the model's copies of those vehicles (kept, the copies not added)"),
                      ("dropped", "dropped (the seeder's rules and the vehicles already there)"),
                      ("dropped_on_existing", "of the dropped: on or too close ahead of a vehicle already there"),
                      ("refused", "refused"), ("misplaced", "misplaced")):
        row(name, [str(sum(sc.get(key, 0) for sc in s["scenes"])) for s in S])
    placed = [sum(sc["placed"] for sc in s["scenes"]) for s in S]
    gen = [sum(sc["generated"] for sc in s["scenes"]) for s in S]
    seeded = [sum(sc[k] for sc in s["scenes"] for k in SEEDED) for s in S]   # neither existing nor dropped
    row("**placement** (placed / seeded: placed + misplaced + refused)",
        [f"**{100.0 * p / t:.1f} %** ({p}/{t})" if t else "–" for p, t in zip(placed, seeded)])
    row("placed / generated", [f"{100.0 * p / g:.1f} %" if g else "–" for p, g in zip(placed, gen)])
    for key, name in (("collisions", "collisions"), ("teleports", "teleports"),
                      ("emergency_brakes", "e-brake agents (first 10 s)")):
        row(f"{name} / 100 agents",
            [f"{100.0 * sum(sc[key] for sc in s['scenes']) / max(sum(sc['agents'] for sc in s['scenes']), 1):.1f}"
             for s in S])
    return "\n".join(lines)


def main(o) -> int:
    import tempfile

    o.load_before = os.getloadavg()[0]

    from sumo_scendiff.data.demand import find_demand
    from sumo_scendiff.map.network import Network
    routes = None if o.no_demand else o.routes or find_demand(Network.load(o.net))
    if routes is None and not o.no_demand:
        sys.exit(f"{o.net}: no route file beside the net; give -r")
    command = ("python benchmarks/run_timing.py " + " ".join(sys.argv[1:])).strip() \
        if sys.argv[0].endswith("run_timing.py") else "benchmarks/run_timing.py (in-process)"
    results = []
    t0 = time.perf_counter()
    for b in (o.begin or ["default"]) if not o.no_demand else ["default"]:
        begin = None if b == "default" else float(b)
        label = ("no demand" if o.no_demand else "run's default warm-up (600 s of demand)") if begin is None \
            else f"--begin {begin:g}"
        with tempfile.TemporaryDirectory(prefix="bench-run-") as tmp:
            r = one_run(o, routes, begin, tmp)
        print(f"{label}: {r['wall']:.0f} s", file=sys.stderr)
        results.append((label, r))
    text = table(results, o, routes, command) + f"\n\nTotal wall time {time.perf_counter() - t0:.0f} s.\n"
    from report import emit
    emit(text, o.output, "run timing benchmark")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
