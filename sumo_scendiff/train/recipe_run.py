"""Run a training recipe (configs/*.json, :mod:`.recipe`) stage by stage into one output directory.

    python -m sumo_scendiff.train recipe configs/scendiff.json OUT [--scale toy] [--data-dir DIR]

Every stage is a program of its own (``python -m sumo_scendiff.data`` or a ``train`` subcommand; a
training stage of a recipe with ``procs`` > 1 as that many one-thread DistributedDataParallel
processes, ``torch.distributed.run``). ``OUT/recipe.json`` records the recipe, the commit, each
stage's command line and wall time, and the model's SHA-256 at the end. Resumable: run the same
command again and a finished stage with the same command line is skipped, a recording continues in
``DIR.partial``, a training stage from its ``last.pt``; the wall times add up over the runs.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

from . import recipe as rc

ROOT = os.path.dirname(rc.NETWORKS)
LOG = "recipe.json"


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
            start = time.time()
            try:
                status = subprocess.run(cmd, env=env, cwd=ROOT).returncode
            except KeyboardInterrupt:
                status = 130
            entry["seconds"] = round(entry["seconds"] + time.time() - start, 1)
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
    print(f"recipe: done in {log['seconds'] / 60:.1f} min of stages; {log_path}")
    return 0
