"""Training recipes as data: a JSON file under configs/ lists a model's stages in order, each as the
flags of the program that runs it.

    {"format": "sumo-scendiff-recipe", "version": 1, "procs": 2, "stages": [
        {"name": "record-train", "run": "data", "split": "train", "output_dir": "{data}/train", ...},
        {"name": "autoencoder", "run": "autoencoder", "steps": 5500, "batch_size": 16,
         "lr_drop_at_percent": 85, "model_config": {...}, ...},
        {"name": "export", "run": "export", ...}, {"name": "calibrate", "run": "calibrate", ...}]}

``run`` is ``data`` (``python -m sumo_scendiff.data``) or a ``train`` subcommand; every other key is
that program's long flag with ``_`` for ``-`` (true: the flag alone; a list: its values; an object:
JSON), except:

- ``split``: ``-n networks/NET`` for each network of that split of networks/splits.json; ``nets``:
  the same for the networks listed (names under networks/);
- ``batch_size`` of a training stage: the global batch, split over the recipe's ``procs``
  DistributedDataParallel processes;
- ``lr_drop_at_percent``: ``--lr-drop-at`` at that share of the stage's steps, down to a hundred.

Strings may name ``{out}`` (the run's output) and ``{data}`` (where recordings go).

``scales`` (optional) holds other sizes of the same recipe, e.g. the tests' ``toy``: ``procs``,
``every`` (values given to each stage that has that key) and ``stages`` (name -> keys set on that
stage; an object merges into an object, null removes the key). :func:`scaled` applies one.
"""
from __future__ import annotations

import json
import os

FORMAT = "sumo-scendiff-recipe"
VERSION = 1
RUNS = ("data", "autoencoder", "diffusion", "export", "calibrate")
TRAINING = ("autoencoder", "diffusion")
LOG = "recipe.json"   # a run's log in its output directory (recipe_run.py writes it, card.py reads it)
NETWORKS = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "networks")
SPLITS = os.path.join(NETWORKS, "splits.json")


class RecipeError(ValueError):
    """A recipe that cannot be used; the message names the file."""


def load(path: str) -> dict:
    """Read and check a recipe file."""
    try:
        with open(path) as f:
            recipe = json.load(f)
    except OSError as e:
        raise RecipeError(f"{path}: {e.strerror.lower()}") from None
    except json.JSONDecodeError as e:
        raise RecipeError(f"{path}: not JSON ({e})") from None
    if not isinstance(recipe, dict) or recipe.get("format") != FORMAT:
        raise RecipeError(f"{path}: not a {FORMAT} file")
    if recipe.get("version") != VERSION:
        raise RecipeError(f"{path}: recipe format version {recipe.get('version')} "
                          f"(this code reads version {VERSION})")
    stages = recipe.get("stages")
    if not isinstance(stages, list) or not stages:
        raise RecipeError(f"{path}: no stages")
    names = [s.get("name") if isinstance(s, dict) else None for s in stages]
    for s, name in zip(stages, names):
        if not isinstance(name, str) or names.count(name) > 1:
            raise RecipeError(f"{path}: every stage needs a name of its own ({name!r})")
        if s.get("run") not in RUNS:
            raise RecipeError(f"{path}: stage {name}: run {s.get('run')!r}, expected one of {', '.join(RUNS)}")
    if not isinstance(recipe.get("procs", 1), int) or recipe.get("procs", 1) < 1:
        raise RecipeError(f"{path}: procs must be a positive integer")
    for name, scale in recipe.get("scales", {}).items():
        unknown = set(scale.get("stages", {})) - set(names)
        if unknown:
            raise RecipeError(f"{path}: scale {name}: no stage {', '.join(sorted(unknown))}")
    return recipe


def _merged(base: dict, over: dict) -> dict:
    out = dict(base)
    for key, v in over.items():
        if v is None:
            out.pop(key, None)
        elif isinstance(v, dict) and isinstance(base.get(key), dict):
            out[key] = _merged(base[key], v)
        else:
            out[key] = v
    return out


def scaled(recipe: dict, scale: str | None) -> dict:
    """The recipe at one of its ``scales`` (None: as written)."""
    if scale is None:
        return recipe
    if scale not in recipe.get("scales", {}):
        raise RecipeError(f"no scale {scale!r} (scales: {', '.join(recipe.get('scales', {})) or 'none'})")
    sc = recipe["scales"][scale]
    every, named = sc.get("every", {}), sc.get("stages", {})
    stages = [_merged(_merged(s, {k: v for k, v in every.items() if k in s}), named.get(s["name"], {}))
              for s in recipe["stages"]]
    return {**recipe, "procs": sc.get("procs", recipe.get("procs", 1)), "stages": stages}


def stage(recipe: dict, name: str) -> dict:
    for s in recipe["stages"]:
        if s["name"] == name:
            return s
    raise RecipeError(f"no stage {name!r} (stages: {', '.join(s['name'] for s in recipe['stages'])})")


def check_steps(recipe: dict, steps: dict) -> None:
    """Raise unless every stage named in ``steps`` (name -> step budget) is a training stage."""
    for name in steps:
        run = stage(recipe, name)["run"]
        if run not in TRAINING:
            raise RecipeError(f"--steps {name}=…: stage {name} ({run}) has no steps")


def drop_at(steps: int, percent: int) -> int:
    """The step ``percent`` % of the way through ``steps``, down to a hundred."""
    return steps * percent // 100 // 100 * 100


def _flag(key: str) -> str:
    return "--" + key.replace("_", "-")


def _value(v, paths: dict) -> str:
    if not isinstance(v, str):
        return str(v)
    for key, path in paths.items():
        if "{" + key + "}" in v and path is None:
            raise RecipeError(f"{v} needs {'OUT' if key == 'out' else '--data-dir'}")
    return v.format(**paths)


def stage_args(recipe: dict, name: str, out: str | None = None, data: str | None = None,
               procs: int | None = None, steps: int | None = None) -> list[str]:
    """The stage's command line: its ``run`` first, then its program's arguments. ``steps``
    replaces a training stage's step budget (its learning-rate drop moves with it)."""
    s = dict(stage(recipe, name))
    run = s.pop("run")
    s.pop("name")
    procs = procs or recipe.get("procs", 1)
    if steps is not None:
        check_steps(recipe, {name: steps})
        s["steps"] = steps
    if "lr_drop_at_percent" in s:
        s["lr_drop_at"] = drop_at(s["steps"], s.pop("lr_drop_at_percent"))
    if run in TRAINING and "batch_size" in s:
        if s["batch_size"] % procs:
            raise RecipeError(f"stage {name}: batch {s['batch_size']} does not split over {procs} processes")
        s["batch_size"] //= procs
    paths = {"out": out, "data": data}
    args = [run]
    for key, v in s.items():
        if key == "split":
            with open(SPLITS) as f:
                args += [a for net in json.load(f)[v] for a in ("-n", os.path.join(NETWORKS, net))]
        elif key == "nets":
            args += [a for net in v for a in ("-n", os.path.join(NETWORKS, net))]
        elif isinstance(v, bool):
            args += [_flag(key)] if v else []
        elif isinstance(v, dict):
            args += [_flag(key), json.dumps(v)]
        elif isinstance(v, list):
            args += [_flag(key)] + [_value(x, paths) for x in v]
        else:
            args += [_flag(key), _value(v, paths)]
    return args


def pending(args: list[str]) -> list[str]:
    """A recording stage's arguments as they stand: none when its recording is complete,
    ``--resume`` added when an interrupted one waits in ``DIR.partial``."""
    if args[0] != "data":
        return args
    out = args[args.index("--output-dir") + 1]
    if os.path.exists(os.path.join(out, "manifest.json")):
        return []
    return args + ["--resume"] if os.path.isdir(out + ".partial") else args
