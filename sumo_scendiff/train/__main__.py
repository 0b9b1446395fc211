"""Train Scenario Diffusion: the detection autoencoder, then the latent diffusion model, then export.

    python -m sumo_scendiff.train recipe configs/scendiff.json runs/scendiff   # the shipped model, every stage
    python -m sumo_scendiff.train autoencoder --data data/train --val data/val -o runs/ae --steps 5500
    python -m sumo_scendiff.train autoencoder --init-from runs/ae/last.pt --freeze-encoder ...  # decoder only
    python -m sumo_scendiff.train diffusion --autoencoder runs/ae/last.pt --data data/train \\
        --val data/val -o runs/diffusion
    python -m sumo_scendiff.train diffusion --autoencoder sumo_scendiff/weights/scendiff.pt \\
        --init-from sumo_scendiff/weights/scendiff.pt ...  # fine-tune the shipped model
    python -m sumo_scendiff.train export --autoencoder runs/ae/last.pt \\
        --diffusion runs/diffusion/last.pt -o runs/scendiff.pt --scene-guidance-sigma 1
    python -m sumo_scendiff.train calibrate --model runs/scendiff.pt --data data/val --turned
    python -m sumo_scendiff.train card runs/scendiff    # the weights card of a finished recipe run

Recipes (configs/): configs/scendiff.json trains the shipped model from nothing (record, autoencoder,
decoder, diffusion, export, calibrate; OUT/recipe.json logs each stage's time), configs/nomap.json
the paper's no-map ablation, configs/finetune_example.json fine-tunes the shipped model on one's
own networks. scripts/run_recipe.sh RECIPE OUT runs the same.

Each training stage writes ``OUT/last.pt`` every ``--ckpt-every`` steps (and when ``--max-minutes``
runs out or on Ctrl-C) and continues from it when started again with the same ``-o``: a stopped run
loses at most the steps since its last checkpoint. Uses CUDA when present; runs unchanged under
``torchrun --nproc_per_node N python -m sumo_scendiff.train ...`` (DistributedDataParallel; gloo on CPU).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
from dataclasses import asdict

from ..generation.config import SAMPLER_NAMES
from . import recipe as rc
from .config import CALIBRATION_WEIGHTS, TrainConfig

PROG = "python -m sumo_scendiff.train"
HELP = {"autoencoder": "train the detection autoencoder (or its decoder alone)",
        "diffusion": "train the latent diffusion model in an autoencoder's latent space",
        "export": "write a trained autoencoder and diffusion model as one model file",
        "calibrate": "calibrate the global token's guidance weight and store it in a model file",
        "recipe": "run a recipe file (configs/*.json) into OUT, or print its stages",
        "card": "print the weights card of a finished recipe run (OUT/card.md): recipe, commit, SHA-256, stages"}


def _add_training_stage(sub, name: str) -> None:
    """The ``autoencoder`` or ``diffusion`` subcommand: data, output, TrainConfig's fields as flags."""
    s = sub.add_parser(name, help=HELP[name], description=HELP[name])
    s.add_argument("--data", required=True, nargs="+",
                   help="training data directory (sumo_scendiff.data); several are read as one")
    s.add_argument("--val", default=None, nargs="+", help="validation data directory (or several)")
    s.add_argument("-o", "--output-dir", dest="out", required=True)
    s.add_argument("--max-minutes", type=float, default=None, help="stop (and save) after this")
    s.add_argument("-v", "--verbose", action="store_true")
    for f, default in asdict(TrainConfig()).items():
        if isinstance(default, bool):
            s.add_argument("--" + f.replace("_", "-"), action=argparse.BooleanOptionalAction, default=None)
        else:
            s.add_argument("--" + f.replace("_", "-"), type=type(default), default=None)
    s.add_argument("--model-config", type=json.loads, default={}, metavar="JSON",
                   help='override model config fields, e.g. \'{"enc_channels": [8, 16, 32, 32]}\'')
    s.add_argument("--init-from", default=None, metavar="CKPT",
                   help=f"warm start a new run from the weights of an earlier {name} run (its "
                        "last.pt; for diffusion its weight average, new input channels at zero) or of "
                        "an exported model (the shipped one); "
                        "ignored when resuming")
    if name == "autoencoder":
        s.add_argument("--freeze-encoder", action="store_true",
                       help="train the decoder only (needs --init-from): the latent space stays "
                            "the same, so a diffusion model trained on it stays valid")
    if name == "diffusion":
        s.add_argument("--autoencoder", required=True, help="autoencoder checkpoint (last.pt, or an exported "
                       "model such as the shipped one)")
    s.add_argument("--no-map", action="store_true",
                   help=f"the paper's no-map ablation: the {name} model sees the map as zeros")


def _add_export(sub) -> None:
    e = sub.add_parser("export", help=HELP["export"], description=HELP["export"])
    e.add_argument("--autoencoder", required=True)
    e.add_argument("--diffusion", required=True)
    e.add_argument("-o", "--output", required=True)
    e.add_argument("--fp16", action="store_true", help="store weights in float16 (half the size)")
    e.add_argument("--force", action="store_true", help="replace an existing output file")
    e.add_argument("--scene-guidance", type=float, default=1.0, metavar="W",
                   help="the global token's guidance weight generation uses by default (1 = off; "
                        "`calibrate` finds and stores one)")
    e.add_argument("--scene-guidance-sigma", type=float, default=0.0, metavar="SIGMA",
                   help="apply that guidance only at noise levels above SIGMA (0 = at every step)")


def _add_calibrate(sub) -> None:
    c = sub.add_parser("calibrate", help=HELP["calibrate"], description=HELP["calibrate"] + ": map-only "
                       "generation of validation windows at each weight; the weight where the agents per "
                       "window meet the ground truth's (interpolated, to one decimal) is written into --model")
    c.add_argument("--model", required=True, help="an exported model (train export); rewritten in place")
    c.add_argument("--data", required=True, help="a validation recording of the training networks")
    c.add_argument("--turned", action="store_true",
                   help="windows turned by a random angle, as training and the evaluation see them "
                        "(whole with a recording of circles)")
    c.add_argument("--scenes", type=int, default=128, help="windows to generate per weight")
    c.add_argument("--weights", type=float, nargs="+", default=list(CALIBRATION_WEIGHTS), metavar="W")
    c.add_argument("--sigma", type=float, default=None,
                   help="guide only above this noise level, and store it (default: the model's)")
    c.add_argument("--steps", type=int, default=None, help="sampler steps (default: generation's)")
    c.add_argument("--sampler", choices=SAMPLER_NAMES, default=None, help="default: generation's")
    c.add_argument("-s", "--seed", type=int, default=0)


def _add_recipe(sub) -> None:
    r = sub.add_parser("recipe", help=HELP["recipe"], description=HELP["recipe"] + " (sumo_scendiff/train/"
                       "recipe.py describes the format, recipe_run.py the run)")
    r.add_argument("recipe", metavar="RECIPE.json")
    r.add_argument("out", metavar="OUT", nargs="?", default=None,
                   help="the run's output directory ({out} in the recipe); OUT/recipe.json logs the run")
    what = r.add_mutually_exclusive_group()
    what.add_argument("--print-stage", metavar="NAME",
                      help="print the stage's program (data or a train subcommand), then its arguments, one "
                           "a line, instead of running; nothing for a recording that is complete, --resume "
                           "for one interrupted")
    what.add_argument("--print", choices=("stages", "procs"), dest="print_key",
                      help="print the stage names in order, or the process count of training stages")
    r.add_argument("--data-dir", default=None, help="where recordings go: {data} in the recipe (default OUT/data)")
    r.add_argument("--scale", default=None, help="another size of the recipe from its \"scales\" (e.g. toy)")
    r.add_argument("--procs", type=int, default=None, help="training processes (default: the recipe's)")
    r.add_argument("--steps", action="append", default=[], metavar="STAGE=N",
                   help="another step budget for a training stage (its lr drop moves with it)")


def _problem(o) -> str | None:
    """A flag of ``export`` or ``calibrate`` out of its range, as one line; None if all are fine."""
    if o.stage == "export":
        if not o.scene_guidance >= 0:
            return "--scene-guidance must be >= 0"
        if not o.scene_guidance_sigma >= 0:
            return "--scene-guidance-sigma must be >= 0"
    if o.stage == "calibrate":
        if o.scenes < 1:
            return "--scenes must be positive"
        if min(o.weights) < 0 or (o.sigma is not None and o.sigma < 0):
            return "--weights and --sigma must be >= 0"
    return None


def get_options(args=None):
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                epilog=__doc__.split("\n\n")[2],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="stage", required=True)
    for name in ("autoencoder", "diffusion"):
        _add_training_stage(sub, name)
    _add_export(sub)
    _add_calibrate(sub)
    _add_recipe(sub)
    sub.add_parser("card", help=HELP["card"], description=HELP["card"]).add_argument(
        "out", metavar="OUT", help="a recipe run's output directory")
    o = p.parse_args(args)
    if _problem(o):
        p.exit(2, f"{PROG}: error: {_problem(o)}\n")
    o.parser = p
    return o


def export(o) -> None:
    from .export import export_model
    from .loop import TrainError
    if os.path.exists(o.output) and not o.force:
        raise TrainError(f"{o.output}: exists (add --force to replace it)")
    sha = export_model(o.autoencoder, o.diffusion, o.output, fp16=o.fp16, scene_guidance=o.scene_guidance,
                       scene_guidance_sigma=o.scene_guidance_sigma)
    print(f"{o.output}: {os.path.getsize(o.output) / 2**20:.1f} MiB, sha256 {sha}")


def run_calibrate(o) -> None:
    from ..model import checkpoint as ckpt
    ckpt.load(o.model, "scenario-diffusion")   # a wrong file fails before minutes of sampling
    from ..generation.generator import ScenarioGenerator
    density = ScenarioGenerator.load(o.model).has_density
    _calibrate_guidance(o, key="density_guidance" if density else "scene_guidance")


def _calibrate_guidance(o, key: str) -> None:
    """The weight where map-only generation meets the validation windows' count, stored as the
    model's scene guidance; a model with the density condition keeps its exported scene guidance
    for windows without a density and stores this weight for windows given one (the recording's
    count is the level the density condition was trained around, not a traffic level to default to)."""
    from .calibrate import calibrate, write_scene_guidance
    c = calibrate(o.model, o.data, scenes=o.scenes, turned=o.turned, weights=o.weights, sigma=o.sigma,
                  steps=o.steps, sampler=o.sampler, seed=o.seed)
    for w, n, _, _ in c.rows:
        print(f"w = {w:g}: {n:.2f} agents per window")
    sha = write_scene_guidance(o.model, c.weight, o.sigma, key=key)
    print(f"{o.model}: {key.replace('_', ' ')} {c.weight:g} above sigma {c.sigma:g} (ground truth "
          f"{c.gt_count:.2f} agents per window, met at w = {c.best:.2f}), sha256 {sha}")


def _check(args: list[str]) -> None:
    """Parse a stage's command line with its program's own options; raise RecipeError if it fails."""
    if args[0] == "data":
        from ..data.__main__ import get_options as program
    else:
        program = get_options
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            program(args[1:] if args[0] == "data" else args)
    except SystemExit:
        raise rc.RecipeError(err.getvalue().strip().splitlines()[-1].partition("error: ")[2]) from None


def recipe(o) -> int:
    r = rc.load(o.recipe)
    try:
        return run_recipe(o, rc.scaled(r, o.scale))
    except rc.RecipeError as e:
        raise rc.RecipeError(f"{o.recipe}: {e}") from None


def _steps(o) -> dict[str, int]:
    steps = {}
    for item in o.steps:
        name, _, n = item.partition("=")
        if not n.isdigit():
            raise rc.RecipeError(f"--steps {item}: expected STAGE=N")
        steps[name] = int(n)
    return steps


def run_recipe(o, r: dict) -> int:
    """Check every stage's command line (a bad one fails before hours of the ones before it), then
    print what was asked or run the stages."""
    steps = _steps(o)
    names = [s["name"] for s in r["stages"]]
    rc.check_steps(r, steps)
    if o.print_key == "stages":
        print("\n".join(names))
        return 0
    procs = o.procs or r.get("procs", 1)
    if o.print_key == "procs":
        print(procs)
        return 0
    if o.print_stage:
        rc.stage(r, o.print_stage)
    elif o.out is None:
        raise rc.RecipeError("give OUT, the run's output directory (or --print / --print-stage)")
    out = os.path.abspath(o.out) if o.out else None
    data = os.path.abspath(o.data_dir) if o.data_dir else (os.path.join(out, "data") if out else None)
    lines = {}
    for name in names:
        try:
            lines[name] = rc.stage_args(r, name, out, data, procs, steps.get(name))
            _check(lines[name])
        except rc.RecipeError as e:
            raise rc.RecipeError(f"stage {name}: {e}") from None
    if o.print_stage:
        print("\n".join(rc.pending(lines[o.print_stage])))
        return 0
    from .recipe_run import run
    os.makedirs(out, exist_ok=True)
    return run(o.recipe, r, out, data, procs, steps, o.scale, lines)


def main(o) -> int:
    if o.stage in ("recipe", "card"):
        try:
            if o.stage == "card":
                from .card import card
                print(card(o.out), end="")
                return 0
            return recipe(o)
        except rc.RecipeError as e:
            o.parser.exit(2, f"{PROG}: error: {e}\n")
    from ..core.threads import share_cpu
    share_cpu()   # before torch starts its thread pool: idle threads sleep instead of spinning
    import numpy as np
    import torch

    from ..data.shards import DataError
    from ..model.checkpoint import CheckpointError
    from .loop import TrainError, distributed_setup
    from .stages import train_autoencoder, train_diffusion
    torch.manual_seed(0)
    np.random.seed(0)
    try:
        if o.stage == "export":
            export(o)
        elif o.stage == "calibrate":
            run_calibrate(o)
        else:
            distributed_setup()
            (train_autoencoder if o.stage == "autoencoder" else train_diffusion)(o)
    except (CheckpointError, DataError, TrainError) as e:   # bad input: one line, exit 2
        o.parser.exit(2, f"{PROG}: error: {e}\n")
    return 0

if __name__ == "__main__":
    sys.exit(main(get_options()))
