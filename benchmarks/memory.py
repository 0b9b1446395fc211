"""Peak memory of the two long batch commands: a sweep of 2 000 scenarios and a fill of the largest
network. Each runs as the user runs it (``python -m sumo_scendiff.sweep`` / ``.fill``) in a session of
its own; the resident memory of every process of that session (the command, its workers; libsumo runs
inside them) is sampled every ``--interval`` s (psutil if installed, else /proc: benchmarks/sweep_procs.py)
and summed: the peak of that sum is the tree's peak. Beside it the largest single process, and the
kernel's own ``ru_maxrss`` of the waited-for children (the largest one process ever held, between
samples too).

    python benchmarks/memory.py -o results/memory.json                  # both, at their defaults
    python benchmarks/memory.py --only sweep --scenarios 200 -o /tmp/m.json

The sweep (benchmarks/sweep_data.py's spec writer): networks/city.net.xml, 10 auto locations x p_mask
0.1 ... 1.0 x seeds, no tokens, ``--steps`` solver steps, ``--rollout`` s of SUMO after each seeding,
``--workers`` processes, no pictures. The fill: ``--fill-net`` (default the largest network of
../shared/nets, ingolstadt_cutmap, 1 632 car lanes) at ``--density`` veh/km with ``--steps``.
docs/benchmarks.md ("Soak and memory") has the figures.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from sweep_data import write_spec                      # noqa: E402
from sweep_procs import BACKEND, count_done, rss, session_members  # noqa: E402

MIB = 2**20
PARTIAL_S = 60.0     # s between the running figures written to -o (a long run's file kept current)
LARGEST = os.path.join(ROOT, "..", "shared", "nets", "ingolstadt_cutmap", "Forschungskreuzung_cutmap.net.xml.gz")


def get_options(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", choices=("sweep", "fill"), default=None, help="one of the two")
    p.add_argument("--scenarios", type=int, default=2000)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--steps", type=int, default=2, help="ODE solver steps (both commands)")
    p.add_argument("--rollout", type=float, default=0.0, help="sweep: s of SUMO after each seeding")
    p.add_argument("--fill-net", default=LARGEST)
    p.add_argument("--density", type=float, default=25.0, help="fill: veh per km of car lane")
    p.add_argument("--interval", type=float, default=0.5, help="RSS sample period (s)")
    p.add_argument("--timeout", type=float, default=4 * 3600.0, help="s before a command is given up")
    p.add_argument("--workdir", default=None, help="outputs here (default: a temporary folder, removed)")
    p.add_argument("-s", "--seed", type=int, default=0)
    p.add_argument("-o", "--out", default=None, help="results JSON (e.g. results/memory.json)")
    o = p.parse_args(argv)
    if o.scenarios < 1 or o.workers < 1 or o.steps < 1 or not o.interval > 0:
        p.error("--scenarios, --workers, --steps must be >= 1, --interval > 0")
    return o


def watch(cmd: list[str], log: str, interval: float, timeout: float, partial=None) -> dict:
    """Run ``cmd`` in a new session, sampling its processes' RSS; its exit, wall time and peaks (MiB).
    ``partial(wall_s, peak_tree_mib, peak_process_mib)``: called every PARTIAL_S s meanwhile."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0, peak_tree, peak_one, samples = time.perf_counter(), 0, 0, 0
    told = t0
    with open(log, "w") as f:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT,
                                start_new_session=True)
        try:
            while proc.poll() is None:
                mem = [r for p in session_members(proc.pid) if (r := rss(p))]
                if mem:
                    peak_tree, peak_one, samples = max(peak_tree, sum(mem)), max(peak_one, max(mem)), samples + 1
                if partial is not None and time.perf_counter() - told > PARTIAL_S:
                    told = time.perf_counter()
                    partial(round(told - t0, 1), round(peak_tree / MIB, 1), round(peak_one / MIB, 1))
                if time.perf_counter() - t0 > timeout:
                    raise TimeoutError(f"{cmd[2]}: no exit after {timeout:.0f} s (log: {log})")
                time.sleep(interval)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, 9)
                proc.wait()
    after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss     # KiB on Linux
    with open(log, errors="replace") as f:
        tail = f.read().strip().splitlines()[-3:]
    return {"command": " ".join(cmd[1:]), "exit": proc.returncode, "wall_s": round(time.perf_counter() - t0, 1),
            "samples": samples, "peak_tree_mib": round(peak_tree / MIB, 1),
            "peak_process_mib": round(peak_one / MIB, 1),
            "ru_maxrss_children_mib": round(max(after, before) / 1024, 1) if after > before else None,
            "log_tail": tail}


def sweep(o, work: str, partial=None) -> dict:
    spec = write_spec(os.path.join(work, "memory_sweep.json"), "bench_memory", o.scenarios, o.seed, locations=10,
                      p_masks=[round(0.1 * k, 1) for k in range(1, 11)], seeds=max(1, o.scenarios // 100),
                      token_sets=None, rollout=o.rollout, steps=o.steps)
    out = os.path.join(work, "sweep")
    cmd = [sys.executable, "-m", "sumo_scendiff.sweep", "--spec", spec, "--out", out, "--workers",
           str(o.workers), "--no-pictures"]
    res = watch(cmd, out + ".log", o.interval, o.timeout,
                partial and (lambda *a: partial(*a, done=sum(count_done(out)))))
    with open(os.path.join(out, "index.jsonl")) as f:
        rows = [json.loads(line) for line in f if line.strip()]
    res["scenarios"] = {"planned": o.scenarios, "in_index": len(rows),
                        "ok": sum(r.get("status") == "ok" for r in rows)}
    return res


def fill(o, work: str, partial=None) -> dict:
    out = os.path.join(work, "fill")
    cmd = [sys.executable, "-m", "sumo_scendiff.fill", "-n", os.path.abspath(o.fill_net), "--density",
           f"{o.density:g}", "--steps", str(o.steps), "-s", str(o.seed), "-o", out]
    res = watch(cmd, out + ".log", o.interval, o.timeout, partial)
    path = os.path.join(out, "fill.json")
    if os.path.exists(path):
        with open(path) as f:
            info = json.load(f)
        res["fill"] = {"tiles": len(info.get("tiles", ())), "agents": len(info.get("agents", ())),
                       **{k: v for k, v in info.get("summary", {}).items() if isinstance(v, (int, float))}}
    return res


def main(argv=None) -> int:
    o = get_options(argv)
    res = {"command": "python benchmarks/memory.py " + " ".join(sys.argv[1:] if argv is None else argv),
           "backend": BACKEND, "options": vars(o)}
    def write() -> None:
        if o.out:
            os.makedirs(os.path.dirname(os.path.abspath(o.out)), exist_ok=True)
            with open(o.out + ".tmp", "w") as f:
                json.dump(res, f, indent=1)
            os.replace(o.out + ".tmp", o.out)
    with tempfile.TemporaryDirectory(prefix="scendiff-memory-") as tmp:
        work = o.workdir or tmp
        os.makedirs(work, exist_ok=True)
        for name, run in (("fill", fill), ("sweep", sweep)):
            if o.only not in (None, name):
                continue
            print(f"memory: {name} ...", flush=True)

            def running(wall, tree, one, name=name, **more):
                res[name] = {"running": True, "wall_s": wall, "peak_tree_mib": tree, "peak_process_mib": one, **more}
                print(f"memory: {name}: {wall:.0f} s, peak so far {tree:.0f} MiB {more or ''}", flush=True)
                write()
            res[name] = r = run(o, work, running)
            print(f"memory: {name}: exit {r['exit']}, {r['wall_s']:.0f} s, peak of the process tree "
                  f"{r['peak_tree_mib']:.0f} MiB, largest process {r['peak_process_mib']:.0f} MiB "
                  f"(ru_maxrss {r['ru_maxrss_children_mib']} MiB)", flush=True)
            write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
