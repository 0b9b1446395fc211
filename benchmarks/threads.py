"""Benchmark: how much a busy CPU slows `run`'s generate phase: a thread per core spinning
(``OMP_WAIT_POLICY=ACTIVE``, torch's own behaviour), a thread per core sleeping, and the default
(``core.threads``: one thread, ``GENERATION_THREADS``).

    python benchmarks/threads.py [--repeats 3] [--neighbours 2]

Each setting runs ``python -m sumo_scendiff.run -n networks/city.net.xml --rollout 0`` alone and
beside ``--neighbours`` torch processes (matrix products on 2 threads each, as another training or
generation job would be) and reads the generate phase from run.json. With two neighbours on a
2-core machine a fair share is about a third of the CPU, so a ratio near 3 is what sharing costs;
far above it is threads waiting for a descheduled partner. The table gives the median of ``--repeats`` runs.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from sumo_scendiff.core.threads import available_cores  # noqa: E402

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
NEIGHBOUR = ("import torch\ntorch.set_num_threads(2)\na = torch.randn(384, 384)\n"
             "while True:\n    for _ in range(50):\n        a = torch.tanh(a @ a / 20)\n")


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--neighbours", type=int, default=2)
    p.add_argument("--scenes", type=int, default=4)
    return p.parse_args(args)


def generate_seconds(setting: dict, scenes: int) -> float:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
    env.update(setting)
    with tempfile.TemporaryDirectory() as out:
        res = subprocess.run([sys.executable, "-m", "sumo_scendiff.run", "-n", os.path.join(ROOT, "networks",
                             "city.net.xml"), "--rollout", "0", "--scenes", str(scenes), "-o", out],
                             capture_output=True, text=True, env=env, cwd=ROOT)
        if res.returncode:
            sys.exit(f"run failed: {(res.stderr.strip().splitlines() or ['?'])[-1]}")
        with open(os.path.join(out, "run.json")) as f:
            return json.load(f)["timing_s"]["generate"]


def main(o) -> None:
    cores = str(available_cores())
    settings = [(f"{cores} threads spinning (torch's own default)", {"OMP_WAIT_POLICY": "ACTIVE",
                                                                     "OMP_NUM_THREADS": cores}),
                (f"{cores} threads sleeping (OMP_WAIT_POLICY=PASSIVE)", {"OMP_NUM_THREADS": cores}),
                ("one thread (default)", {})]
    idle = {name: [] for name, _ in settings}
    busy = {name: [] for name, _ in settings}
    for _ in range(o.repeats):              # settings take turns: the machine drifts within minutes
        for name, policy in settings:
            idle[name].append(generate_seconds(policy, o.scenes))
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OMP_NUM_THREADS")}
    procs = [subprocess.Popen([sys.executable, "-c", NEIGHBOUR], env=env) for _ in range(o.neighbours)]
    try:
        time.sleep(3.0)
        for _ in range(o.repeats):
            for name, policy in settings:
                busy[name].append(generate_seconds(policy, o.scenes))
    finally:
        for p in procs:
            p.kill()
    print(f"| `run` generate phase ({o.scenes} scenes) | idle (s) | beside {o.neighbours} torch "
          f"neighbours (s) | ratio |")
    print("|---|---|---|---|")
    for name, _ in settings:
        a, b = statistics.median(idle[name]), statistics.median(busy[name])
        print(f"| {name} | {a:.2f} | {b:.2f} | {b / a:.1f}x |")
    print(f"\nall runs (s): idle {idle}, busy {busy}")


if __name__ == "__main__":
    main(get_options())
