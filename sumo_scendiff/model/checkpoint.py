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
VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint that cannot be used; the message names the file."""


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
    if ck.get("version") != VERSION:
        raise CheckpointError(f"{path}: checkpoint format version {ck.get('version')} "
                              f"(this code reads version {VERSION})")
    kinds = (kind,) if isinstance(kind, str) else kind
    if ck.get("kind") not in kinds:
        raise CheckpointError(f"{path}: a {ck.get('kind')!r} checkpoint, expected {' or '.join(kinds)}")
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
