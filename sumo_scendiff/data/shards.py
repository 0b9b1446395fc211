"""Sharded scene storage and the torch Dataset over it.

A data directory holds ``manifest.json`` and ``shard-XXXXX.npz`` files. Each shard concatenates the
agents of its scenes (``offsets`` delimits them) and stores windows, times and network indices.
Rasters are not stored: :class:`~sumo_scendiff.data.dataset.SceneDataset` renders the map from the network and the agents from
the boxes, for a window rotated by a random angle (rotation augmentation), so nothing is interpolated.
A manifest with ``"disc": true`` holds each window's circumscribed circle (``EpisodeSpec.disc``):
:meth:`SceneStore.scene` gives the window's square, ``scene(i, disc=True)`` the circle to turn.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from ..core.files import file_sha256, read_json
from ..core.geometry import Window
from ..core.scene import Scene, crop_to_window
from ..map.signals import decode_states, encode_states

MANIFEST = "manifest.json"
FORMAT_VERSION = 1


class DataError(ValueError):
    """A data directory that cannot be read; the message names the file."""


def write_shard(path: str, scenes: list[Scene], net_index: int) -> dict:
    """Write scenes atomically (temporary file, then rename); returns the manifest entry."""
    counts = np.array([len(s) for s in scenes], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)])

    def cat(name, shape):
        arrs = [getattr(s, name) for s in scenes]
        return np.concatenate(arrs) if arrs else np.zeros(shape)

    tmp = path + ".tmp.npz"
    np.savez_compressed(
        tmp, offsets=offsets, window=np.array([s.window.as_tuple() for s in scenes]).reshape(-1, 4),
        time=np.array([s.time for s in scenes]), net=np.full(len(scenes), net_index, np.int32),
        kind=np.array([s.meta.get("kind", 0) for s in scenes], np.int8),
        boxes=cat("boxes", (0, 5)), traj=cat("traj", (0, 5, 3)), traj_mask=cat("traj_mask", (0, 5)),
        speed=cat("speed", (0, 5)), vclass=cat("vclass", (0,)),
        signals=np.array([encode_states(s.meta.get("signals") or {}) for s in scenes], dtype=str))
    os.replace(tmp, path)
    return {"file": os.path.basename(path), "scenes": len(scenes), "agents": int(counts.sum()),
            "net": net_index}


def write_manifest(root: str, nets: list[dict], shards: list[dict], **extra) -> dict:
    """Write ``root/manifest.json``: ``nets`` = [{name, path (relative to root), sha256}], ``shards``
    = :func:`write_shard` entries in order."""
    manifest = {"format_version": FORMAT_VERSION, "nets": nets, "shards": shards,
                "scenes": sum(s["scenes"] for s in shards), "agents": sum(s["agents"] for s in shards),
                **extra}
    with open(os.path.join(root, MANIFEST), "w") as f:
        json.dump(manifest, f, indent=1)
    return manifest


def net_entry(net_path: str, root: str, name: str) -> dict:
    return {"name": name, "path": os.path.relpath(os.path.abspath(net_path), os.path.abspath(root)),
            "sha256": file_sha256(net_path)}


@dataclass
class Shard:
    offsets: np.ndarray
    window: np.ndarray
    time: np.ndarray
    net: np.ndarray
    kind: np.ndarray
    boxes: np.ndarray
    traj: np.ndarray
    traj_mask: np.ndarray
    speed: np.ndarray
    vclass: np.ndarray
    signals: np.ndarray = None   # per scene: traffic-light states at t = 0 (map.signals.encode_states)

    @classmethod
    def load(cls, path: str) -> "Shard":
        try:
            with np.load(path) as z:
                fields = {k: z[k] for k in cls.__dataclass_fields__ if k in z.files or k != "signals"}
            shard = cls(**fields)
            if shard.signals is None:   # recorded before traffic lights were: states unknown
                shard.signals = np.full(len(shard.window), "", dtype=str)
            return shard
        except Exception as e:  # zipfile / KeyError / ValueError: all a damaged shard
            raise DataError(f"{path}: unreadable shard ({type(e).__name__}: {e})") from None

    def __len__(self):
        return len(self.window)

    def scene(self, i: int, net_name: str = "") -> Scene:
        a, b = self.offsets[i], self.offsets[i + 1]
        return Scene(Window(*self.window[i]), self.boxes[a:b], self.traj[a:b], self.traj_mask[a:b],
                     self.speed[a:b], self.vclass[a:b], net_name, float(self.time[i]),
                     {"kind": int(self.kind[i]), "signals": decode_states(str(self.signals[i]))})


def read_manifest(root: str) -> dict:
    path = os.path.join(root, MANIFEST)
    if not os.path.exists(path):
        raise DataError(f"{root}: not a data directory (no {MANIFEST})")
    manifest = read_json(path, "manifest", DataError)
    if manifest.get("format_version") != FORMAT_VERSION:
        raise DataError(f"{path}: unsupported format_version {manifest.get('format_version')!r}")
    return manifest


def resolve_net_path(root: str, entry: dict) -> str:
    """A manifest's network path, relative to the data directory unless absolute."""
    p = entry["path"]
    return p if os.path.isabs(p) else os.path.normpath(os.path.join(root, p))


class SceneStore:
    """All scenes of one or more data directories, loaded into memory (scenes are small: boxes, not
    rasters); several directories are read as one, in the order given."""

    def __init__(self, root: str | list[str], nets: list[str] | None = None):
        roots = [root] if isinstance(root, str) else list(root)
        wanted = None if nets is None else set(nets)
        self.shards, self.sources = [], []   # per shard: (its data directory, its manifest's nets)
        self.discs: list[bool] = []          # per shard: scenes hold the window's circumscribed circle
        for r in roots:
            manifest = read_manifest(r)
            entries = manifest["nets"]
            for s in manifest["shards"]:
                if wanted is None or entries[s["net"]]["name"] in wanted:
                    self.shards.append(Shard.load(os.path.join(r, s["file"])))
                    self.sources.append((r, entries))
                    self.discs.append(bool(manifest.get("disc", False)))
        self.index = [(k, i) for k, sh in enumerate(self.shards) for i in range(len(sh))]

    def __len__(self):
        return len(self.index)

    def _entry(self, scene_idx: int) -> tuple[str, dict]:
        k, i = self.index[scene_idx]
        root, entries = self.sources[k]
        return root, entries[int(self.shards[k].net[i])]

    def net_name(self, scene_idx: int) -> str:
        return self._entry(scene_idx)[1]["name"]

    def net_path(self, scene_idx: int) -> str:
        return resolve_net_path(*self._entry(scene_idx))

    def scene(self, idx: int, disc: bool = False) -> Scene:
        """Scene ``idx``: the agents in its window's square; with ``disc``, in the circle through the
        square's corners where the recording holds it (else the square), so that the window turned
        about its centre and cropped (:func:`~sumo_scendiff.core.scene.crop_to_window`) is whole."""
        k, i = self.index[idx]
        scene = self.shards[k].scene(i, self.net_name(idx))
        return scene if disc or not self.discs[k] else crop_to_window(scene)
