"""The training recipes (configs/*.json) run, and run as the shipped architecture.

configs/scendiff.json runs for real at its toy scale (one small network, a few scenes, two steps a
stage, one process) through every stage, from an empty directory to a model that generates, and
again as a resumed run that skips what is done. Every stage of every recipe is checked by its
program's own option parser (a renamed flag fails here, not hours into a run).
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from sumo_scendiff.train import recipe as rc

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIGS = os.path.join(REPO, "configs")
SCENDIFF = os.path.join(CONFIGS, "scendiff.json")
RECIPES = sorted(f for f in os.listdir(CONFIGS) if f.endswith(".json"))


def recipe_cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "recipe", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, check=False)


@pytest.mark.slow
def test_the_recipe_at_toy_scale_trains_a_model_that_generates(tmp_path, cross_net):
    from sumo_scendiff.core.files import file_sha256
    from sumo_scendiff.core.geometry import Window
    from sumo_scendiff.generation.generator import GenerationConfig, ScenarioGenerator
    from sumo_scendiff.map.network import Network
    from sumo_scendiff.model import checkpoint as ckpt
    from sumo_scendiff.model.autoencoder import AutoencoderConfig
    from sumo_scendiff.model.diffusion import DiffusionConfig
    out = tmp_path / "run"
    res = recipe_cli(SCENDIFF, out, "--scale", "toy", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    log = json.loads((out / "recipe.json").read_text())
    recipe = rc.load(SCENDIFF)
    assert list(log["stages"]) == [s["name"] for s in recipe["stages"]]
    assert all(s["done"] and s["seconds"] > 0 for s in log["stages"].values())
    assert log["recipe"] == "configs/scendiff.json" and log["scale"] == "toy" and log["commit"]
    model = out / "scendiff.pt"
    assert log["model"]["sha256"] == file_sha256(str(model))
    card = (out / "card.md").read_text()   # the weights card, from the run's own log
    assert f"recipe configs/scendiff.json OUT --scale toy` at commit `{log['commit']}`" in card
    assert log["model"]["sha256"] in card and all(f"| {name} |" in card for name in log["stages"])
    assert "train: 8 windows of 1 networks" in card
    printed = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "card", str(out)], capture_output=True,
                             text=True)
    assert printed.returncode == 0 and printed.stdout == card
    gen = ScenarioGenerator.load(str(model), GenerationConfig(steps=2))
    assert isinstance(gen.generate(Network.load(cross_net), [Window(0.0, 0.0, 0.0)], seed=0)[0].boxes.shape[0], int)
    # the defaults are the shipped architecture: the recipe states only training settings
    ck = ckpt.load(str(model), "scenario-diffusion")
    assert ckpt.config_from_dict(DiffusionConfig, ck["diffusion_config"]) == DiffusionConfig()
    ae = ckpt.config_from_dict(AutoencoderConfig, ck["autoencoder_config"])
    assert ae == AutoencoderConfig() and ck["density_guidance"] is not None   # the turns stage ends at the default weights
    # resumed: every finished stage is skipped, its time kept
    again = recipe_cli(SCENDIFF, out, "--scale", "toy", cwd=tmp_path)
    assert again.returncode == 0 and "recipe: stage" not in again.stdout, again.stdout
    assert json.loads((out / "recipe.json").read_text())["stages"] == log["stages"]


@pytest.mark.parametrize("name", RECIPES)
@pytest.mark.parametrize("scale", [None, "toy"])
def test_every_recipe_parses_with_todays_clis(tmp_path, name, scale):
    """Every stage of every recipe, at full and toy scale, is checked by its program's parser (the
    recipe command checks every stage before it prints or runs one)."""
    recipe = rc.load(os.path.join(CONFIGS, name))
    last = recipe["stages"][-1]
    res = recipe_cli(f"configs/{name}", tmp_path / "run", "--print-stage", last["name"],
                     *(["--scale", scale] if scale else []))
    assert res.returncode == 0, res.stderr
    assert res.stdout.split("\n")[0] == last["run"]


@pytest.mark.parametrize("name", RECIPES)
def test_no_recipe_reads_a_checkpoint_it_did_not_write(name):
    """Every checkpoint a stage reads is one an earlier stage of the same recipe writes under {out};
    only the fine-tune example reads the shipped model, by name."""
    recipe = rc.load(os.path.join(CONFIGS, name))
    written = set()
    for stage in recipe["stages"]:
        for key in ("init_from", "autoencoder", "diffusion", "model"):
            path = stage.get(key)
            if path is None or (stage["run"] == "calibrate" and key != "model"):
                continue
            if name == "finetune_example.json" and path == "sumo_scendiff/weights/scendiff.pt":
                continue
            assert path.startswith("{out}/") and (path in written or key == "model"), (name, stage["name"], path)
        written |= {f"{stage.get('output_dir')}/last.pt", stage.get("output")}
    assert not re.search(r"round [0-9]", json.dumps(recipe))   # no recipe is a step of a chain


def test_the_recipe_trains_the_shipped_networks_and_budget():
    """The full-scale recipe: the 15 training networks, the budget its about states, two DDP processes."""
    recipe = rc.load(SCENDIFF)
    assert recipe["procs"] == 2 and all(s.get("split", "train") == "train" for s in recipe["stages"])
    lines = [rc.stage_args(recipe, s["name"], "OUT", "DATA") for s in recipe["stages"]]
    with open(rc.SPLITS) as f:
        train = json.load(f)["train"]
    assert [a for a in lines[1] if a.endswith(".net.xml")] == [os.path.join(rc.NETWORKS, n) for n in train]
    steps = {s["name"]: s["steps"] for s in recipe["stages"] if s["run"] in rc.TRAINING}
    assert steps == {"autoencoder": 5500, "decoder": 3000, "turns": 2000, "diffusion": 4500, "diffusion-anneal": 2000}
    total = re.search(r"about (\d+ h \d+ min) in all", recipe["about"]).group(1)
    with open(os.path.join(ROOT, "docs", "training.md")) as f:  # one budget, stated twice
        assert f"| **total** | | | | **≈ {total}** |" in f.read()


@pytest.mark.parametrize("change, words", [
    ({"version": 2}, "recipe format version 2"),
    ({"format": "other"}, "not a sumo-scendiff-recipe file"),
    ({"stages": [{"name": "a", "run": "autoencoder", "data": ["d"], "output_dir": "o", "stepz": 3}], "scales": {}},
     "stage a: unrecognized arguments: --stepz 3"),
    ({"stages": [{"name": "a", "run": "trian"}]}, "stage a: run 'trian'"),
    ({"scales": {"toy": {"stages": {"nope": {}}}}}, "scale toy: no stage nope"),
])
def test_bad_recipe_exit_2_naming_the_file(tmp_path, change, words):
    with open(SCENDIFF) as f:
        recipe = {**json.load(f), **change}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(recipe))
    res = recipe_cli(path, tmp_path / "out", "--print-stage", "a")
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert str(path) in res.stderr and words in res.stderr and not res.stdout
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("args, words", [
    ([], "give OUT"),
    (["o", "--print-stage", "nope"], "no stage 'nope'"),
    (["o", "--print-stage", "export", "--procs", "3"], "stage autoencoder: batch 16 does not split over 3 processes"),
    (["--print", "stages", "--steps", "export=5"], "stage export (export) has no steps"),
    (["o", "--scale", "huge"], "no scale 'huge'"),
])
def test_bad_recipe_request_exit_2(args, words):
    res = recipe_cli("configs/scendiff.json", *args)
    assert res.returncode == 2 and "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert words in res.stderr and not res.stdout


def test_the_script_is_the_same_command(tmp_path):
    res = subprocess.run(["bash", os.path.join(REPO, "scripts", "run_recipe.sh"), "configs/scendiff.json",
                          str(tmp_path / "run"), "--print", "stages"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == [s["name"] for s in rc.load(SCENDIFF)["stages"]]


def test_a_card_of_no_finished_run_is_one_line(tmp_path):
    res = subprocess.run([sys.executable, "-m", "sumo_scendiff.train", "card", str(tmp_path)], capture_output=True,
                         text=True)
    assert res.returncode == 2 and "no finished recipe run" in res.stderr and "Traceback" not in res.stderr


def test_a_running_stage_writes_its_time_as_it_goes():
    """The runner writes a stage's wall time while it runs: a runner killed with its stage (a
    session ending) leaves the time up to its last tick in recipe.json, not nothing."""
    from sumo_scendiff.train.recipe_run import run_timed
    ticks = []
    status = run_timed([sys.executable, "-c", "import time; time.sleep(1.3)"], dict(os.environ), ticks.append,
                       every=0.4)
    assert status == 0
    assert len(ticks) >= 3 and ticks == sorted(ticks) and 1.2 <= ticks[-1] < 10
    failed = run_timed([sys.executable, "-c", "raise SystemExit(3)"], dict(os.environ), ticks.append, every=0.4)
    assert failed == 3
