"""The training scripts stay runnable: every command of scripts/train_fast.sh parses with today's CLIs.

The script runs with a ``python`` on PATH that checks each ``python -m sumo_scendiff.…`` and
``benchmarks/….py`` command line with that program's own ``get_options`` (an unknown or renamed
flag fails as it would two hours into a real run) and records it instead of running it. A stage
launched through ``python -m torch.distributed.run … -m sumo_scendiff.train`` has the launcher's own
arguments checked by the launcher's parser and is recorded with its process count.
"""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

SHIM = r'''
import importlib, json, os, runpy, sys
args = sys.argv[1:]
procs = 1
if args[:2] == ["-m", "torch.distributed.run"]:
    from torch.distributed.run import get_args_parser
    cut = args.index("-m", 2)
    launcher = get_args_parser().parse_args(args[2:cut] + ["-m", args[cut + 1]])
    procs = int(launcher.nproc_per_node)
    args = args[cut:]
if args[0] == "-c":
    sys.argv = ["-c"] + args[2:]
    exec(args[1])
    sys.exit(0)
if args[0] == "-m":
    prog, rest = args[1], args[2:]
    mod = importlib.import_module(prog)
    get_options = (importlib.import_module(prog + ".__main__") if hasattr(mod, "__path__") else mod).get_options
else:
    prog, rest = args[0], args[1:]
    sys.path.insert(0, os.path.dirname(os.path.abspath(prog)))
    get_options = runpy.run_path(prog)["get_options"]
get_options(rest)  # argparse exits 2 with the reason on a bad flag
with open(os.environ["SHIM_LOG"], "a") as f:
    f.write(json.dumps([prog] + rest + ["--procs", str(procs)]) + "\n")
if prog.endswith("scene_guidance.py"):
    print("agents per window equal to the ground truth's at w = 1.42 (interpolated)")
'''


def _flag(call: list[str], name: str) -> str:
    return call[call.index(name) + 1]


def test_the_two_hour_recipe_parses_with_todays_clis(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (tmp_path / "shim.py").write_text(SHIM)
    python = bin_dir / "python"
    python.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{tmp_path / "shim.py"}" "$@"\n')
    python.chmod(python.stat().st_mode | stat.S_IEXEC)
    log = tmp_path / "calls.jsonl"
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "SHIM_LOG": str(log),
           "FAST_DATA": str(tmp_path / "data"), "PYTHONPATH": REPO}
    res = subprocess.run(["bash", os.path.join(REPO, "scripts", "train_fast.sh"), str(tmp_path / "run")],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    progs = [c[0] for c in calls]
    assert progs == ["sumo_scendiff.data"] * 2 + ["sumo_scendiff.train"] * 4 + [
        "benchmarks/scene_guidance.py", "sumo_scendiff.train"]
    stages = [c[1] for c in calls if c[0] == "sumo_scendiff.train"]
    assert stages == ["autoencoder", "autoencoder", "diffusion", "export", "export"]
    trains = [c for c in calls if c[1] in ("autoencoder", "diffusion")]
    # the run measured in README "Training": its steps and learning-rate drops
    assert [(_flag(c, "--steps"), _flag(c, "--lr-drop-at")) for c in trains] == [
        ("5500", "4600"), ("2500", "2100"), ("3600", "3000")]
    # two DDP processes, each on half of the global batches of 16 / 16 / 32
    assert [(_flag(c, "--procs"), _flag(c, "--batch-size")) for c in trains] == [
        ("2", "8"), ("2", "8"), ("2", "16")]
    assert _flag(calls[-1], "--scene-guidance") == "1.4"   # the calibrated weight
    nets = [c for c in calls[0] if c.endswith(".net.xml")]
    with open(os.path.join(REPO, "networks", "splits.json")) as f:
        train = json.load(f)["train"]
    assert nets == [f"networks/{n}" for n in train]   # the project's own training networks only
