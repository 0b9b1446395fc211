"""The training recipes stay runnable and true to the shipped model.

scripts/train_fast.sh (and train_nomap.sh) run with a ``python`` on PATH that checks each
``python -m sumo_scendiff.…`` command line with that program's own ``get_options`` (an unknown or
renamed flag fails as it would two hours into a real run) and records it instead of running it;
``train recipe``, which reads configs/*.json, runs for real. A stage launched through
``python -m torch.distributed.run … -m sumo_scendiff.train`` has the launcher's own arguments checked
by the launcher's parser and is recorded with its process count. configs/fast.json's values are
compared with what the shipped checkpoint records of its own training.
"""
from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest

from sumo_scendiff.model import checkpoint as ckpt
from sumo_scendiff.train import recipe as rc
from sumo_scendiff.train.stages import _merge

pytestmark = pytest.mark.slow   # real runs of the CLIs: the fast tier is -m "not slow"

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FAST = os.path.join(REPO, "configs", "fast.json")

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
if args[:3] == ["-m", "sumo_scendiff.train", "recipe"]:   # reads the recipe: runs for real
    sys.argv = ["sumo_scendiff.train"] + args[2:]
    runpy.run_module("sumo_scendiff.train", run_name="__main__")
if args[0] != "-m":
    sys.exit(f"shim: not a module: {args}")
prog, rest = args[1], args[2:]
mod = importlib.import_module(prog)
get_options = (importlib.import_module(prog + ".__main__") if hasattr(mod, "__path__") else mod).get_options
get_options(rest)  # argparse exits 2 with the reason on a bad flag
with open(os.environ["SHIM_LOG"], "a") as f:
    f.write(json.dumps([prog] + rest + ["--procs", str(procs)]) + "\n")
'''


def _flag(call: list[str], name: str) -> str:
    return call[call.index(name) + 1]


def run_script(tmp_path, script: str, *args: str, **env) -> list[list[str]]:
    """Run scripts/SCRIPT with the checking shim as ``python``; the command lines it ran."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    (tmp_path / "shim.py").write_text(SHIM)
    python = bin_dir / "python"
    python.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{tmp_path / "shim.py"}" "$@"\n')
    python.chmod(python.stat().st_mode | stat.S_IEXEC)
    log = tmp_path / "calls.jsonl"
    env = {**os.environ, "PATH": f"{bin_dir}:{os.environ['PATH']}", "SHIM_LOG": str(log),
           "PYTHONPATH": REPO, **env}
    res = subprocess.run(["bash", os.path.join(REPO, "scripts", script), *args],
                         capture_output=True, text=True, env=env, cwd=tmp_path, check=False)
    assert res.returncode == 0, res.stderr
    return [json.loads(line) for line in log.read_text().splitlines()]


def test_the_fast_recipe_parses_with_todays_clis(tmp_path):
    data, run = str(tmp_path / "data"), str(tmp_path / "run")
    calls = run_script(tmp_path, "train_fast.sh", run, FAST_DATA=data)
    assert [c[0] for c in calls] == ["sumo_scendiff.data"] * 2 + ["sumo_scendiff.train"] * 5
    stages = [c[1] for c in calls if c[0] == "sumo_scendiff.train"]
    assert stages == ["autoencoder", "autoencoder", "diffusion", "export", "calibrate"]
    trains = [c for c in calls if c[1] in ("autoencoder", "diffusion")]
    # the run measured in docs/training.md: its steps and learning-rate drops
    assert [(_flag(c, "--steps"), _flag(c, "--lr-drop-at")) for c in trains] == [
        ("5500", "4600"), ("2500", "2100"), ("3600", "3000")]
    # two DDP processes, each on half of the global batches of 16 / 16 / 32
    assert [(_flag(c, "--procs"), _flag(c, "--batch-size")) for c in trains] == [
        ("2", "8"), ("2", "8"), ("2", "16")]
    export, calibrate = calls[-2], calls[-1]
    assert _flag(export, "--output") == f"{run}/scendiff.pt"
    # the calibration rewrites the exported model, on turned windows of the validation recording
    assert _flag(calibrate, "--model") == f"{run}/scendiff.pt" and "--turned" in calibrate
    assert _flag(calibrate, "--data") == f"{data}/val"
    nets = [c for c in calls[0] if c.endswith(".net.xml")]
    with open(os.path.join(REPO, "networks", "splits.json")) as f:
        train = json.load(f)["train"]
    assert nets == [f"networks/{n}" for n in train]   # the project's own training networks only


def test_other_step_budgets_one_process_and_a_finished_recording(tmp_path):
    data = tmp_path / "data"
    (data / "train").mkdir(parents=True)
    (data / "train" / "manifest.json").write_text("{}")   # complete: not recorded again
    (data / "val.partial").mkdir()                         # interrupted: continued
    calls = run_script(tmp_path, "train_fast.sh", str(tmp_path / "run"), FAST_DATA=str(data),
                       AE_STEPS="3500", DECODER_STEPS="600", PROCS="1")
    assert [c[0] for c in calls][:1] == ["sumo_scendiff.data"] and "--resume" in calls[0]
    trains = [c for c in calls if c[1] in ("autoencoder", "diffusion")]
    assert [(_flag(c, "--steps"), _flag(c, "--lr-drop-at")) for c in trains] == [
        ("3500", "2900"), ("600", "500"), ("3600", "3000")]
    assert [(_flag(c, "--procs"), _flag(c, "--batch-size")) for c in trains] == [
        ("1", "16"), ("1", "16"), ("1", "32")]


def test_the_nomap_recipe_parses_with_todays_clis(tmp_path):
    calls = run_script(tmp_path, "train_nomap.sh", str(tmp_path / "nomap.pt"))
    assert [c[1] for c in calls] == ["diffusion", "autoencoder", "export", "calibrate"]
    assert "--no-map" in calls[0] and "--no-map" in calls[1] and "--freeze-encoder" in calls[1]
    assert _flag(calls[3], "--model") == str(tmp_path / "nomap.pt")


def assert_recorded(stated: dict, recorded: dict, where: str) -> None:
    """Every value the recipe states (nested) is the one the checkpoint records."""
    for key, value in stated.items():
        assert key in recorded, f"{where}.{key}"
        if isinstance(value, dict):
            assert_recorded(value, recorded[key], f"{where}.{key}")
        else:
            got = list(recorded[key]) if isinstance(recorded[key], tuple) else recorded[key]
            assert got == value, f"{where}.{key}: recipe {value!r}, shipped {got!r}"


def test_the_recipes_are_what_the_shipped_model_records():
    """The shipped model is configs/fast.json's autoencoder and its diffusion model fine-tuned by
    configs/density.json (the density condition), then by configs/signals.json (the traffic lights'
    channels, the token-weighted loss), its decoder then trained on by configs/token_decoder.json's
    stages (the decoder reads the tokens), configs/token_speed.json's (a token's one given speed
    read in both channels, more partial tokens, the speed term), configs/token_exact.json's (its
    token inputs reading the tokens' exact values), configs/token_turns.json's (a turning
    vehicle's trajectory weighted 40), configs/token_told.json's (the speed of a vehicle whose
    token gives it weighted 11), configs/token_branch.json's (a token branch added) and
    configs/token_mix.json's (the branch's gate toward the token's speeds)."""
    shipped = ckpt.load(os.path.join(REPO, "sumo_scendiff", "weights", "scendiff.pt"), "scenario-diffusion")
    fast, density = rc.load(FAST), rc.load(os.path.join(REPO, "configs", "density.json"))
    signals = rc.load(os.path.join(REPO, "configs", "signals.json"))
    ae, decoder, diffusion = (rc.stage(fast, n) for n in ("autoencoder", "decoder", "diffusion"))
    tuned, lit = rc.stage(density, "diffusion"), rc.stage(signals, "diffusion")
    reads = [st for name in ("token_decoder.json", "token_speed.json", "token_exact.json", "token_turns.json",
                             "token_told.json", "token_branch.json", "token_mix.json")
             for st in rc.load(os.path.join(REPO, "configs", name))["stages"] if st["run"] == "autoencoder"]
    # the decoder stages continue the autoencoder's config with their own overrides on top
    config = _merge(ae["model_config"], decoder["model_config"])
    for st in reads:
        config = _merge(config, st.get("model_config", {}))
    assert_recorded(config, shipped["autoencoder_config"], "autoencoder_config")
    assert shipped["autoencoder_config"]["C_t"] == 13                 # the decoder reads the tokens
    assert shipped["autoencoder_config"]["token_speeds_filled"]       # ... a lone speed in both channels
    assert shipped["autoencoder_config"]["loss"]["category_weights"][2] == 40.0   # ... the turns weighted
    assert shipped["autoencoder_config"]["loss"]["told_speed_weight"] == 10.0     # ... a told speed too
    assert shipped["autoencoder_config"]["token_branch"] == 32        # ... corrected where a token stands
    assert shipped["autoencoder_config"]["token_branch_mix"]          # ... drawn toward its speeds
    assert_recorded(_merge(_merge(diffusion["model_config"], tuned["model_config"]), lit["model_config"]),
                    shipped["diffusion_config"], "diffusion_config")
    assert shipped["diffusion_config"]["unet"]["global_dim"] == 23    # p_mask, density, its presence bit
    assert shipped["diffusion_config"]["C_m"] == 21                   # the map with the lights' channels
    trained = shipped["trained"]
    assert trained["autoencoder_steps"] == ae["steps"] + decoder["steps"] + sum(st["steps"] for st in reads)
    assert trained["diffusion_steps"] == diffusion["steps"] + tuned["steps"] + lit["steps"]
    assert trained["diffusion_ema"]   # the diffusion stage's default EMA, which the export ships
    record = rc.stage(signals, "record-train")
    assert trained["data"]["scenes"] == record["scenes"]
    with open(os.path.join(REPO, "networks", "splits.json")) as f:
        nets = json.load(f)[record["split"]]
    assert trained["data"]["nets"] == [n.removesuffix(".net.xml") for n in nets]
    export = rc.stage(density, "export")
    assert (shipped["scene_guidance"], shipped["scene_guidance_sigma"]) == (export["scene_guidance"],
                                                                           export["scene_guidance_sigma"])
    assert shipped["density_guidance"] > 1.0     # calibrated by the recipe's last stage


def recipe_cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "recipe", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, check=False)


@pytest.mark.parametrize("change, words", [
    ({"version": 2}, "recipe format version 2"),
    ({"format": "other"}, "not a sumo-scendiff-recipe file"),
    ({"stages": [{"name": "a", "run": "autoencoder", "data": ["d"], "output_dir": "o", "stepz": 3}]},
     "stage a: unrecognized arguments: --stepz 3"),
    ({"stages": [{"name": "a", "run": "trian"}]}, "stage a: run 'trian'"),
])
def test_bad_recipe_exit_2_naming_the_file(tmp_path, change, words):
    with open(FAST) as f:
        recipe = {**json.load(f), **change}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(recipe))
    res = recipe_cli(path, "--print-stage", "a", "--out", "o", "--data-dir", "d")
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert str(path) in res.stderr and words in res.stderr and not res.stdout


@pytest.mark.parametrize("args, words", [
    (["--print-stage", "autoencoder", "--data-dir", "d"], "stage autoencoder: {out}/ae needs --out"),
    (["--print-stage", "nope", "--out", "o", "--data-dir", "d"], "no stage 'nope'"),
    (["--print-stage", "export", "--out", "o", "--data-dir", "d", "--procs", "3"],
     "stage autoencoder: batch 16 does not split over 3 processes"),
    (["--print", "stages", "--steps", "export=5"], "stage export (export) has no steps"),
])
def test_bad_recipe_request_exit_2(args, words):
    res = recipe_cli("configs/fast.json", *args)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert words in res.stderr and not res.stdout


@pytest.mark.parametrize("name", sorted(f for f in os.listdir(os.path.join(REPO, "configs")) if f.endswith(".json")))
def test_every_recipe_parses_with_todays_clis(name):
    """Every stage of every recipe in configs/ (the shipped rounds and the candidates) is checked by
    its program's parser."""
    recipe = rc.load(os.path.join(REPO, "configs", name))
    for stage in recipe["stages"]:
        res = recipe_cli(f"configs/{name}", "--print-stage", stage["name"], "--out", "runs/x",
                         "--data-dir", "data/x", "--procs", "2")
        assert res.returncode == 0, res.stderr
        assert res.stdout.split("\n")[0] == stage["run"]
