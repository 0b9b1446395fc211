"""Benchmark: the three targets of the sweep issue -- parallel speed-up, resume after SIGKILL, and
flat worker memory over a long sweep.

    python benchmarks/sweep.py speedup [--scenarios 40] [--workers 1 2] [--rollout 30]
    python benchmarks/sweep.py kill [--scenarios 40] [--kills 5] [--kill-at time|count] [--rollout 30]
    python benchmarks/sweep.py memory [--scenarios 500] [--rollout 5] [--interval 1]
    python benchmarks/sweep.py all -o runs/bench_sweep.md      # the three at their defaults
    python benchmarks/sweep.py speedup --scenarios 8 -o runs/bench_sweep_small.md   # a quick check

Every sweep runs the real CLI as a subprocess (``python -m sumo_scendiff.sweep --spec SPEC --out DIR
--workers N --no-pictures``, in a new session) on a spec written into the work directory (a temp
dir, removed at the end unless ``--keep``; or ``--workdir DIR``):

* **speedup** -- ``networks/city.net.xml``, 4 auto locations x a truck token set with 2 variants
  (final speed 0 / 8 m/s, as ``scenarios/truck_stopping.toml``) x p_mask 0.2 ... 1.0 (5 values), seed
  0 = 40 scenarios, 30-s rollouts; once per ``--workers`` value into a fresh directory, wall clock
  from the start of the process to its exit. Prints the times, the speed-up over the first value
  (target >= 1.8x), the bound that the task granularity (tasks of up to 8 scenarios) puts on it,
  and whether the index.jsonl files are identical (same seeds -> same scenes).
* **kill** -- the same sweep with ``--workers 2``: once uninterrupted (the reference), then started,
  SIGKILLed (the sweep's main process only: its workers must die with it) and started again with
  ``--resume``, ``--kills`` times (resumed runs are killed too), then left to finish. ``--kill-at
  time``: after a delay drawn uniformly between ``--min-delay`` and the reference's duration scaled
  to the scenarios still to run (start-up included), so every kill lands in a running sweep;
  ``--kill-at count``: when a random number of further scenarios has finished. The draws come from
  ``--seed`` only. After each kill: every process of the sweep's session (and any process whose
  command line names the output directory) must be gone within ``--orphan-wait`` s; each resumed
  run must report "K done before" with K = the scenario folders left by the kill. At the end:
  scenarios lost (planned, neither folder nor failure), duplicated (folders not in the plan, ids
  twice in the index), ``*.partial`` left anywhere, and whether index.jsonl equals the reference's.
* **memory** -- a long sweep (500 scenarios: 5 auto locations x 10 p_mask values x 10 seeds, no
  tokens, 5-s rollouts) with ``--workers 2``; the RSS of every worker process (the sweep's
  ``multiprocessing`` children; the main process too) is sampled every ``--interval`` s (psutil if
  installed, else /proc). Per process: RSS once the first task is done (the first sample with
  8 x workers scenarios finished), at the end, the peak, and the least-squares slope of RSS against
  scenarios finished over the second half of the sweep, in MiB per 100 scenarios (of the sweep);
  "flat" = |slope| < ``--flat`` (5 MiB / 100). ``--samples FILE`` writes the raw samples (CSV).

``--scenarios N`` other than the full product: the product is extended with more seeds if needed
and N scenarios are drawn from it with ``--seed`` (written as the spec's explicit list, plan order).
Everything except the timings is deterministic for a seed. Prints markdown tables with the command
(and writes them with ``-o``). Timing numbers are only meaningful on an otherwise idle machine: the
header shows the load average at the start.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time


def _common(p: argparse.ArgumentParser, scenarios: int | None, rollout: float | None) -> None:
    if scenarios is not None:
        p.add_argument("--scenarios", type=int, default=scenarios, help=f"sweep size (default {scenarios})")
        p.add_argument("--rollout", type=float, default=rollout, help=f"rollout seconds (default {rollout:g})")
        p.add_argument("--steps", type=int, default=10, help="sampler steps (default 10, the sweep's)")
        p.add_argument("--pictures", action="store_true", help="let the sweep draw its pictures (timed too)")
    p.add_argument("-s", "--seed", type=int, default=0, help="subsample and kill draws (default 0)")
    p.add_argument("-o", "--output", default=None, metavar="FILE", help="also write the tables here")
    p.add_argument("--workdir", default=None, help="specs and sweep outputs (default: a temp dir)")
    p.add_argument("--keep", action="store_true", help="keep the work directory")
    p.add_argument("--timeout", type=float, default=4 * 3600.0, help="per sweep process (s)")
    p.add_argument("--hash-seed", default=None, metavar="N",
                   help="diagnostic: PYTHONHASHSEED for the sweep processes (default: Python's random one)")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    sub = p.add_subparsers(dest="what", required=True, metavar="speedup|kill|memory|all")
    sp = sub.add_parser("speedup", help="the same sweep with --workers 1 and 2")
    _common(sp, 40, 30.0)
    sp.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="values to compare (default 1 2)")
    sp.add_argument("--target", type=float, default=1.8, help="speed-up target (default 1.8)")
    kp = sub.add_parser("kill", help="SIGKILL + --resume, repeated; compared with an uninterrupted sweep")
    _common(kp, 40, 30.0)
    kp.add_argument("--workers", type=int, default=2)
    kp.add_argument("--kills", type=int, default=5)
    kp.add_argument("--kill-at", choices=("time", "count"), default="time")
    kp.add_argument("--min-delay", type=float, default=2.0, help="earliest kill after a start (s)")
    kp.add_argument("--orphan-wait", type=float, default=10.0, help="grace for the workers to die (s)")
    mp = sub.add_parser("memory", help="worker RSS over a long sweep")
    _common(mp, 500, 5.0)
    mp.add_argument("--workers", type=int, default=2)
    mp.add_argument("--interval", type=float, default=1.0, help="RSS sample period (s)")
    mp.add_argument("--flat", type=float, default=5.0, help="|slope| below this (MiB / 100 scenarios) is flat")
    mp.add_argument("--samples", default=None, metavar="FILE", help="write the raw samples (CSV)")
    ap = sub.add_parser("all", help="speedup, kill (its reference: speedup's --workers 2 run), memory; defaults")
    _common(ap, None, None)
    ap.add_argument("--quick", action="store_true", help="a self-check of this script, not a measurement: "
                    "8 scenarios and 2 kills, memory 40 scenarios with 1-s rollouts")
    o = p.parse_args(args)
    if getattr(o, "scenarios", 1) < 1:
        p.error("--scenarios must be >= 1")
    return o


def main(o) -> int:
    import tempfile

    from sweep_checks import (  # the measurements; processes: sweep_procs, specs: sweep_data
        kill,
        memory,
        speedup,
    )
    command = ("python benchmarks/sweep.py " + " ".join(sys.argv[1:])).strip() \
        if sys.argv[0].endswith("sweep.py") else f"benchmarks/sweep.py {o.what} (in-process)"
    if o.workdir:
        os.makedirs(o.workdir, exist_ok=True)
        workdir = os.path.abspath(o.workdir)
    else:
        workdir = tempfile.mkdtemp(prefix="bench-sweep-")
    print(f"work directory {workdir}", file=sys.stderr)
    t0 = time.perf_counter()
    parts = []
    try:
        if o.what == "all":
            common = ["-s", str(o.seed), "--timeout", str(o.timeout)] + \
                (["--hash-seed", o.hash_seed] if o.hash_seed is not None else [])
            small = ["--scenarios", "8"] if o.quick else []
            so = get_options(["speedup"] + common + small)
            text, res = speedup(so, workdir, command)
            parts.append(("speedup", text))
            ko = get_options(["kill"] + common + small + (["--kills", "2"] if o.quick else []))
            ref = res.get(ko.workers)
            parts.append(("kill", kill(ko, workdir, command, ref)))
            mo = get_options(["memory"] + common + (["--scenarios", "40", "--rollout", "1"] if o.quick else []))
            parts.append(("memory", memory(mo, workdir, command)))
        elif o.what == "speedup":
            parts.append(("speedup", speedup(o, workdir, command)[0]))
        elif o.what == "kill":
            parts.append(("kill", kill(o, workdir, command)))
        else:
            parts.append(("memory", memory(o, workdir, command)))
    finally:
        if not o.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    text = "\n\n".join(f"## {name}\n\n{body}" for name, body in parts) + \
        f"\n\nTotal wall time {time.perf_counter() - t0:.0f} s.\n"
    from report import emit
    emit(text, o.output, "sweep benchmark")
    return 0


if __name__ == "__main__":
    sys.exit(main(get_options()))
