"""Benchmark: training steps per second of each stage, one process with two threads against two
DistributedDataParallel processes with one thread each (the same global batch).

    python benchmarks/train_speed.py [--data data/fast/train] [--steps 10 60] [-o runs/bench_train_speed.md]

Runs the real CLI (``python -m sumo_scendiff.train``, or ``python -m torch.distributed.run
--standalone --nproc_per_node 2 -m sumo_scendiff.train`` with half the batch per process) for each
training stage of ``configs/scendiff.json``: the autoencoder from scratch, its decoder alone reading
the tokens (from the shipped model, encoder frozen), and the diffusion model (in the shipped
model's latent space), each with that stage's settings. Each setting runs twice from scratch, for the two ``--steps`` counts; the
difference of the wall times over the difference of the steps is the time per step with start-up,
data indexing and process spawning cancelled out. No validation runs.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from report import emit  # noqa: E402

SHIPPED = os.path.join(ROOT, "sumo_scendiff", "weights", "scendiff.pt")
AE_CONFIG = {"latent_noise": 1.0, "loss": {"category_weights": [1.0, 1.0, 40.0]}}
# (label, global batch, stage arguments) as in configs/scendiff.json
STAGES = [
    ("autoencoder from scratch", 16, ["autoencoder", "--p-keep-all-tokens", "0", "--p-map-only", "1",
                                      "--model-config", json.dumps(AE_CONFIG)]),
    ("decoder alone (encoder frozen)", 16, ["autoencoder", "--init-from", SHIPPED, "--freeze-encoder"]),
    ("diffusion", 32, ["diffusion", "--autoencoder", SHIPPED]),
]
LAUNCHES = [("1 process x 2 threads", 1, 2), ("2 processes x 1 thread (DDP)", 2, 1)]


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default=os.path.join(ROOT, "runs", "scendiff", "data", "train"),
                   help="a recording (python -m sumo_scendiff.data; default: configs/scendiff.json's in runs/scendiff)")
    p.add_argument("--steps", type=int, nargs=2, default=[10, 60], metavar=("SHORT", "LONG"))
    p.add_argument("-o", "--output", default=None, help="also write the table to this markdown file")
    o = p.parse_args(args)
    if not os.path.isfile(os.path.join(o.data, "manifest.json")):
        p.error(f"{o.data}: not a recording (no manifest.json); record one with python -m sumo_scendiff.data")
    if not 0 < o.steps[0] < o.steps[1]:
        p.error("--steps: SHORT must be positive and below LONG")
    return o


def run_seconds(stage_args: list[str], batch: int, procs: int, threads: int, steps: int, data: str) -> float:
    """Wall time of one training run of ``steps`` steps from scratch."""
    launcher = ([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
                 str(procs), "-m", "sumo_scendiff.train"] if procs > 1
                else [sys.executable, "-m", "sumo_scendiff.train"])
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    with tempfile.TemporaryDirectory() as out:
        cmd = launcher + stage_args + ["--data", data, "-o", out, "--steps", str(steps),
                                       "--batch-size", str(batch // procs), "--val-every", "1000000",
                                       "--ckpt-every", "1000000"]
        t = time.perf_counter()
        res = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
        seconds = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(f"train_speed: {' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    return seconds


def main(o) -> None:
    from tqdm import tqdm
    short, long = o.steps
    rows = []
    with tqdm(total=len(STAGES) * len(LAUNCHES) * 2, desc="runs") as bar:
        for label, batch, args in STAGES:
            per_step = []
            for _, procs, threads in LAUNCHES:
                times = []
                for steps in (short, long):
                    times.append(run_seconds(args, batch, procs, threads, steps, o.data))
                    bar.update()
                per_step.append((times[1] - times[0]) / (long - short))
            rows.append((label, batch, *per_step))
    lines = [f"training steps on {os.cpu_count()} cores, s/step from runs of {short} and {long} steps "
             f"({o.data})", "",
             "| stage | global batch | " + " | ".join(f"{name} (s/step)" for name, _, _ in LAUNCHES)
             + " | speed-up |", "|---|---|---|---|---|"]
    for label, batch, one, two in rows:
        lines.append(f"| {label} | {batch} | {one:.3f} | {two:.3f} | {one / two:.2f}x |")
    emit("\n".join(lines) + "\n", o.output, "Training speed")


if __name__ == "__main__":
    main(get_options())
