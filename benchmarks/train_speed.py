"""Benchmark: training steps per second of each stage, one process with two threads against two
DistributedDataParallel processes with one thread each (the same global batch).

    python benchmarks/train_speed.py [--data data/fast/train] [--steps 10 60] [-o runs/bench_train_speed.md]
    python benchmarks/train_speed.py --ab=--compile --vs=--no-compile --pairs 3 --stages diffusion decoder \
        --results results/train_speed_compile.json     # two settings side by side, DDP as the recipe runs

With ``--ab FLAGS --vs FLAGS`` the two settings of the same stage run in turn (A B A B ...; each
pair a short and a long run of each) as the recipe's two one-thread DDP processes, so that a
machine whose speed drifts moves both sides of a pair alike: each pair gives A's and B's s/step
and their ratio (the medians over the pairs are reported), and A's extra start-up (its wall time
at the short count beyond B's, less the steps' difference): a compile's cost, from inductor's
cache (``TORCHINDUCTOR_CACHE_DIR``, one per stage, filled by an unpaired first run of A whose
extra start-up is the first compile's, as on a machine that never compiled).

``--optimizer`` times one AdamW step of the diffusion model's weights in this process (one thread,
CPU seconds, medians of 15), the loop's form against the fused one the stages use, A B in turn.

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
import shlex
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
BENCH = os.path.dirname(os.path.abspath(__file__))
# this directory last: its profile.py is not the standard library's, which torch._dynamo imports
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != BENCH] + [BENCH]
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
KEYS = {"autoencoder": 0, "decoder": 1, "diffusion": 2}   # --stages: STAGES by a short name
LAUNCHES = [("1 process x 2 threads", 1, 2), ("2 processes x 1 thread (DDP)", 2, 1)]


def get_options(args=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default=os.path.join(ROOT, "runs", "scendiff", "data", "train"),
                   help="a recording (python -m sumo_scendiff.data; default: configs/scendiff.json's in runs/scendiff)")
    p.add_argument("--steps", type=int, nargs=2, default=[10, 60], metavar=("SHORT", "LONG"))
    p.add_argument("-o", "--output", default=None, help="also write the table to this markdown file")
    p.add_argument("--stages", nargs="+", choices=list(KEYS), default=list(KEYS))
    p.add_argument("--ab", default=None, metavar="FLAGS", help="A: these stage flags (one string)")
    p.add_argument("--vs", default="", metavar="FLAGS", help="B: these stage flags (with --ab)")
    p.add_argument("--pairs", type=int, default=3, help="A B pairs per stage (with --ab)")
    p.add_argument("--results", default=None, help="with --ab: write the pairs and medians here (JSON)")
    p.add_argument("--optimizer", action="store_true", help="time the optimiser step, plain and fused")
    o = p.parse_args(args)
    if not o.optimizer and not os.path.isfile(os.path.join(o.data, "manifest.json")):
        p.error(f"{o.data}: not a recording (no manifest.json); record one with python -m sumo_scendiff.data")
    if not 0 < o.steps[0] < o.steps[1]:
        p.error("--steps: SHORT must be positive and below LONG")
    return o


def run_seconds(stage_args: list[str], batch: int, procs: int, threads: int, steps: int, data: str,
                cache: str | None = None) -> float:
    """Wall time of one training run of ``steps`` steps from scratch (inductor's cache in ``cache``,
    else a fresh one: a first compile)."""
    launcher = ([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
                 str(procs), "-m", "sumo_scendiff.train"] if procs > 1
                else [sys.executable, "-m", "sumo_scendiff.train"])
    with tempfile.TemporaryDirectory() as out, tempfile.TemporaryDirectory() as fresh:
        env = {**os.environ, "OMP_NUM_THREADS": str(threads), "TORCHINDUCTOR_CACHE_DIR": cache or fresh}
        cmd = launcher + stage_args + ["--data", data, "-o", out, "--steps", str(steps),
                                       "--batch-size", str(batch // procs), "--val-every", "1000000",
                                       "--ckpt-every", "1000000"]
        t = time.perf_counter()
        res = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True)
        seconds = time.perf_counter() - t
    if res.returncode != 0:
        raise SystemExit(f"train_speed: {' '.join(cmd)} failed:\n{res.stderr[-2000:]}")
    return seconds


def ab_pair(args: list[str], batch: int, o, cache: str) -> dict:
    """One pair: A's and B's short and long runs in turn (DDP, 2 x 1 thread), A's compiles from
    ``cache`` (warm: a first compile's time varies by minutes on a shared machine, more than the
    steps between the two counts take)."""
    short, long = o.steps
    t = {}
    for steps in (short, long):
        for side, flags in (("a", o.ab), ("b", o.vs)):
            t[side, steps] = run_seconds(args + shlex.split(flags), batch, 2, 1, steps, o.data, cache)
    a, b = ((t[s, long] - t[s, short]) / (long - short) for s in ("a", "b"))
    return {"a_s_per_step": a, "b_s_per_step": b, "ratio": a / b, "a_short_s": t["a", short],
            "b_short_s": t["b", short], "a_extra_startup_s": t["a", short] - t["b", short] - short * (a - b)}


def main_ab(o) -> None:
    from tqdm import tqdm
    out = {"command": ["python", "benchmarks/train_speed.py"] + sys.argv[1:], "a": o.ab, "b": o.vs,
           "steps": o.steps, "data": o.data, "stages": {}}
    lines = [f"A `{o.ab}` against B `{o.vs}`: 2 DDP processes x 1 thread, s/step from runs of "
             f"{o.steps[0]} and {o.steps[1]} steps, medians of {o.pairs} A B pairs", "",
             "| stage | global batch | A s/step | B s/step | A / B (pairs) | A's extra start-up, cached / first (s) |",
             "|---|---|---|---|---|---|"]
    with tqdm(total=len(o.stages) * o.pairs, desc="pairs") as bar:
        for key in o.stages:
            label, batch, args = STAGES[KEYS[key]]
            with tempfile.TemporaryDirectory() as cache:
                # A's first run, into an empty cache: what a first compile costs
                first = run_seconds(args + shlex.split(o.ab), batch, 2, 1, o.steps[0], o.data, cache)
                pairs = []
                for _ in range(o.pairs):
                    pairs.append(ab_pair(args, batch, o, cache))
                    bar.update()
            med = {k: statistics.median(p[k] for p in pairs) for k in pairs[0]}
            med["a_first_compile_extra_s"] = first - med["a_short_s"] + med["a_extra_startup_s"]
            out["stages"][key] = {"pairs": pairs, "median": med, "a_first_short_s": first}
            ratios = ", ".join(f"{p['ratio']:.3f}" for p in pairs)
            lines.append(f"| {label} | {batch} | {med['a_s_per_step']:.3f} | {med['b_s_per_step']:.3f} | "
                         f"**{med['ratio']:.3f}** ({ratios}) | {med['a_extra_startup_s']:.0f} / "
                         f"{med['a_first_compile_extra_s']:.0f} |")
    out["table"] = "\n".join(lines) + "\n"
    if o.results:
        with open(o.results, "w") as f:
            json.dump(out, f, indent=1)
    emit(out["table"], o.output, "Training speed, A against B")


def main_optimizer() -> None:
    import copy

    import torch
    from sumo_scendiff.model.diffusion import DiffusionConfig, ScenarioDiffusion
    torch.set_num_threads(1)
    models = {"loop": ScenarioDiffusion(DiffusionConfig())}
    models["fused"] = copy.deepcopy(models["loop"])
    for p, q in zip(models["loop"].parameters(), models["fused"].parameters()):
        p.grad = torch.randn_like(p) * 1e-3
        q.grad = p.grad.clone()
    opts = {k: torch.optim.AdamW(m.parameters(), lr=6e-4, weight_decay=1e-5, **({"fused": True} if k == "fused" else {}))
            for k, m in models.items()}
    times = {k: [] for k in opts}
    for _ in range(16):
        for k, opt in opts.items():
            t = time.process_time()
            opt.step()
            times[k].append(time.process_time() - t)
    ms = {k: 1000 * statistics.median(v[1:]) for k, v in times.items()}
    diff = max(float((p - q).detach().abs().max()) for p, q in zip(models["loop"].parameters(), models["fused"].parameters()))
    n = sum(p.numel() for p in models["loop"].parameters())
    print(f"AdamW step of {n:,} weights: {ms['loop']:.1f} ms, fused {ms['fused']:.1f} ms; "
          f"largest weight difference after 16 steps {diff:.1e}")


def main(o) -> None:
    if o.optimizer:
        return main_optimizer()
    if o.ab is not None:
        return main_ab(o)
    from tqdm import tqdm
    short, long = o.steps
    rows = []
    with tqdm(total=len(o.stages) * len(LAUNCHES) * 2, desc="runs") as bar:
        for label, batch, args in (STAGES[KEYS[k]] for k in o.stages):
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
