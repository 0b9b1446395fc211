"""Checkpoints: state_dicts + plain-data configs, saved with torch.save, loaded with weights_only=True.

A checkpoint is a dict ``{"format": FORMAT, "version": VERSION, "kind": ..., "config": {...},
"state": {...}, ...}`` holding only tensors and plain Python data — no pickled code — so that
``torch.load(path, weights_only=True)`` can read it. Anything else (missing, empty, truncated, not a
torch file, another program's file, another version of this format) raises :class:`CheckpointError`
with one line naming the file and the problem.
"""
from __future__ import annotations

import dataclasses
import os
import typing

import torch

from ..core.files import file_sha256 as sha256

FORMAT = "sumo-scendiff"
# 2: configs hold this version's fields; 1 (the shipped file's): configs as earlier versions wrote
# them, read through EARLIER_DEFAULTS and RETIRED
VERSION = 2
READS = (1, 2)


class CheckpointError(ValueError):
    """A checkpoint that cannot be used; the message names the file."""


# Fields whose default changed, each with the value a version-1 config that lacks it was trained
# with (a config holds the fields its version had): part -> field -> value. ``stem`` (the encoders'
# first layers) came after version 1 and every earlier model has the full one, whatever the default
EARLIER_DEFAULTS = {
    "autoencoder": {"C_m": 21, "kl_weight": 0.1, "latent_noise": 1.0, "heading_bins": 0, "C_t": 0,
                    "token_branch": 0, "map_skips": False, "token_speeds_filled": False,
                    "token_branch_mix": False, "stem": "full"},
    "autoencoder.loss": {"box_weight": 1.0, "vertex_weight": 1.0, "category_weights": [0.1, 0.3, 4.0],
                         "heading_bin_weight": 1.0, "speed_weight": 0.0, "told_speed_weight": 0.0},
    "diffusion": {"P_mean": -0.5, "P_std": 1.0, "stem": "full"},
    "diffusion.unet": {"pos_freqs": 0, "splat_ch": 0},
}
# Switches version-1 configs stored that this version no longer has: what each switched on is now the only
# way, so a config must have had it on wherever it mattered. part -> field -> where it mattered
RETIRED = {"autoencoder": {"map_skips": lambda c: True,
                           "token_speeds_filled": lambda c: c["C_t"] > 0,
                           "token_branch_mix": lambda c: c["C_t"] > 0 and c["token_branch"] > 0}}
# the stored configs of each kind of checkpoint: key -> part
CONFIGS = {"scenario-diffusion": {"autoencoder_config": "autoencoder", "diffusion_config": "diffusion"},
           "autoencoder-train": {"model_config": "autoencoder"},
           "diffusion-train": {"model_config": "diffusion"}}


def upgraded_config(d: dict, part: str, path: str) -> dict:
    """A stored config of ``part`` as this version reads it: missing fields at the value that model
    was trained with (:data:`EARLIER_DEFAULTS`), retired switches (:data:`RETIRED`) checked and dropped."""
    out = {**EARLIER_DEFAULTS.get(part, {}), **d}
    for key in {k.split(".")[1] for k in EARLIER_DEFAULTS if k.startswith(part + ".")}:
        out[key] = upgraded_config(d.get(key, {}), f"{part}.{key}", path)
    for field, mattered in RETIRED.get(part, {}).items():
        if out.get(field) is not True and mattered(out):
            raise CheckpointError(f"{path}: a model with {field} {out.get(field)} (this version always "
                                  f"has it on): train it again, or read it with an earlier version")
        out.pop(field, None)
    return out


def config_to_dict(cfg) -> dict:
    return dataclasses.asdict(cfg)


def config_from_dict(cls, d: dict):
    """Rebuild a (nested) config dataclass from :func:`config_to_dict` output; lists -> tuples."""
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        v, t = d[f.name], hints[f.name]
        if dataclasses.is_dataclass(t):
            v = config_from_dict(t, v)
        elif isinstance(v, list):
            v = tuple(v)
        kwargs[f.name] = v
    unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise CheckpointError(f"unknown {cls.__name__} fields {sorted(unknown)}")
    return cls(**kwargs)


def save(path: str, kind: str, **content) -> str:
    """Atomically write a checkpoint of ``kind`` (``PATH.partial``, then rename); returns its SHA-256."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".partial"
    torch.save({"format": FORMAT, "version": VERSION, "kind": kind, **content}, tmp)
    os.replace(tmp, path)
    return sha256(path)


def load(path: str, kind: str | tuple[str, ...]) -> dict:
    """Load and check a checkpoint; ``kind`` is the expected kind (or kinds)."""
    if not os.path.exists(path):
        raise CheckpointError(f"{path}: no such checkpoint")
    if os.path.getsize(path) == 0:
        raise CheckpointError(f"{path}: empty file")
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # zip / pickle / unpickler errors: all a damaged or foreign file
        first = str(e).strip().splitlines()[0][:160] if str(e).strip() else type(e).__name__
        raise CheckpointError(f"{path}: not a readable checkpoint ({first})") from None
    if not isinstance(ck, dict) or ck.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a sumo-scendiff checkpoint")
    if ck.get("version") not in READS:
        raise CheckpointError(f"{path}: checkpoint format version {ck.get('version')} "
                              f"(this code reads versions {', '.join(map(str, READS))})")
    kinds = (kind,) if isinstance(kind, str) else kind
    if ck.get("kind") not in kinds:
        raise CheckpointError(f"{path}: a {ck.get('kind')!r} checkpoint, expected {' or '.join(kinds)}")
    for key, part in CONFIGS.get(ck["kind"], {}).items() if ck["version"] == 1 else ():
        if isinstance(ck.get(key), dict):
            ck[key] = upgraded_config(ck[key], part, path)
    return ck


def update(path: str, kind: str, **changes) -> str:
    """Rewrite the checkpoint at ``path`` with some of its entries replaced (atomically, as
    :func:`save`); returns its new SHA-256."""
    ck = load(path, kind)
    content = {k: v for k, v in ck.items() if k not in ("format", "version", "kind")}
    return save(path, kind, **{**content, **changes})


def load_state(module: torch.nn.Module, state: dict, path: str) -> None:
    """``load_state_dict`` with a one-line error when the weights do not fit the code's model."""
    try:
        module.load_state_dict(state)
    except RuntimeError as e:
        first = str(e).strip().splitlines()
        detail = first[1].strip() if len(first) > 1 else first[0]
        raise CheckpointError(f"{path}: weights do not fit this version's model ({detail[:160]})") from None
