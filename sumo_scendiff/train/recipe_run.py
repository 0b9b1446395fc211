"""Run a training recipe (configs/*.json, :mod:`.recipe`) stage by stage into one output directory.

    python -m sumo_scendiff.train recipe configs/scendiff.json OUT [--scale toy] [--data-dir DIR]

Every stage is a program of its own (``python -m sumo_scendiff.data`` or a ``train`` subcommand; a
training stage of a recipe with ``procs`` > 1 as that many one-thread DistributedDataParallel
processes, ``torch.distributed.run``). ``OUT/recipe.json`` records the recipe, the commit, each
stage's command line and wall time, and the model's SHA-256 at the end; ``OUT/card.md`` is the
model's weights card (:mod:`.card`). Resumable: run the same command again and a finished stage with
the same command line is skipped, a recording continues in ``DIR.partial``, a training stage from its
``last.pt``; the wall times add up over the runs (a running stage's is written every minute, so a
runner killed with its stage loses at most that).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from . import recipe as rc

ROOT = os.path.dirname(rc.NETWORKS)
LOG = rc.LOG
TICK = 60.0   # s between the log's updates of a running stage's wall time


def commit() -> str | None:
    """The repository's commit (with ``+dirty`` when files differ from it); None outside git."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def command(args: list[str], procs: int) -> tuple[list[str], dict]:
    """The process to start for a stage's arguments (:func:`recipe.stage_args`) and its environment."""
    env = dict(os.environ)
    if args[0] == "data":
        return [sys.executable, "-m", "sumo_scendiff.data", *args[1:]], env
    if args[0] in rc.TRAINING:
        # one process gains little from a second thread on two cores; two one-thread processes do
        env.setdefault("OMP_NUM_THREADS", "1" if procs > 1 else "2")
        if procs > 1:
            return [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node",
                    str(procs), "-m", "sumo_scendiff.train", *args], env
    return [sys.executable, "-m", "sumo_scendiff.train", *args], env


def run_timed(cmd: list[str], env: dict, tick, every: float = TICK) -> int:
    """Run ``cmd`` to its end; ``tick(seconds so far)`` every ``every`` s and once at the end. A runner
    killed with its stage (a session ending, a machine going down) leaves the time up to the last tick."""
    start = time.time()
    proc = subprocess.Popen(cmd, env=env, cwd=ROOT)
    try:
        while True:
            try:
                status = proc.wait(timeout=every)
                break
            except subprocess.TimeoutExpired:
                tick(time.time() - start)
    except KeyboardInterrupt:   # the stage got the same SIGINT: it saves and exits; wait for it
        proc.wait()
        status = 130
    tick(time.time() - start)
    return status


def _write(path: str, log: dict) -> None:
    tmp = path + ".partial"
    with open(tmp, "w") as f:
        json.dump(log, f, indent=1)
    os.replace(tmp, path)


def _read(path: str) -> dict:
    if not os.path.exists(path):
        return {}
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise rc.RecipeError(f"{path}: not a recipe log ({e})") from None


def run(path: str, recipe: dict, out: str, data: str, procs: int, steps: dict, scale: str | None,
        stage_lines: dict[str, list[str]]) -> int:
    """Run the (checked) stages' command lines ``stage_lines`` in order; returns the exit status."""
    log_path = os.path.join(out, LOG)
    log = _read(log_path)
    log.update({"recipe": os.path.relpath(os.path.abspath(path), ROOT), "scale": scale, "procs": procs,
                "steps": steps, "data": data, "commit": commit()})
    stages = log.setdefault("stages", {})
    for name, args in stage_lines.items():
        entry = stages.setdefault(name, {"seconds": 0.0})
        if entry.get("done") and entry.get("args") == args:
            continue
        todo = rc.pending(args)
        entry.update({"args": args, "done": False})
        if todo:
            cmd, env = command(todo, procs)
            print(f"recipe: stage {name}: {' '.join(cmd[1:])}", flush=True)
            _write(log_path, log)
            spent = entry["seconds"]

            def tick(seconds: float) -> None:   # the log holds the stage's time even if this runner is killed
                entry["seconds"] = round(spent + seconds, 1)
                _write(log_path, log)

            status = run_timed(cmd, env, tick)
            if status != 0:
                _write(log_path, log)
                print(f"recipe: stage {name} stopped (exit {status}); run the same command again to continue",
                      file=sys.stderr)
                return status
        entry["done"] = True
        _write(log_path, log)
    model = os.path.join(out, "scendiff.pt")
    if os.path.exists(model):
        from ..core.files import file_sha256
        log["model"] = {"path": os.path.relpath(model, out), "sha256": file_sha256(model)}
    log["seconds"] = round(sum(e["seconds"] for e in stages.values()), 1)
    _write(log_path, log)
    if "model" in log:
        from .card import CARD, card
        with open(os.path.join(out, CARD), "w") as f:
            f.write(card(out))
    print(f"recipe: done in {log['seconds'] / 60:.1f} min of stages; {log_path}")
    return 0
