"""torch Dataset over recorded scene shards: map and agent rasters rendered on the fly.

    ds = SceneDataset("data/train", rotate=True, seed=0)
    loader = DataLoader(ds, batch_size=16, shuffle=True, collate_fn=collate_scenes, num_workers=1)
"""
from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from ..core.scene import crop_to_window, per_km, rotate_scene
from ..map.raster import RasterConfig, render_agents, render_map
from .shards import SceneStore


class SceneDataset(Dataset):
    """torch-style Dataset: item = dict of map raster, agent raster and the padded-free sparse arrays.

    ``root`` is a data directory or a list of them, read as one. ``rotate=True`` turns each window
    by a uniform random angle (the agents with it) — the augmentation of the recorded data; a
    recording of circles (``"disc"`` in its manifest) fills the turned square whole, one of squares
    leaves its corners empty. The angle
    comes from ``seed`` and the item index and epoch, so a given (seed, epoch, index) always yields
    the same sample.
    """

    def __init__(self, root: str | list[str], nets: list[str] | None = None, rotate: bool = True,
                 seed: int = 0, raster=None, max_agents: int = 256, p_no_signals: float = 0.0):
        self.store = SceneStore(root, nets)
        self.rotate, self.seed, self.epoch = rotate, seed, 0
        self.raster = raster or RasterConfig()
        self.max_agents = max_agents
        # scenes shown with their traffic lights unknown, so that one model serves hosts that give
        # the states and callers that cannot
        self.p_no_signals = p_no_signals
        self._nets: dict[str, object] = {}

    def __len__(self):
        return len(self.store)

    def network(self, path: str):
        from ..map.network import Network
        if path not in self._nets:
            self._nets[path] = Network.load(path)
        return self._nets[path]

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __getitem__(self, idx: int) -> dict:
        scene = self.store.scene(idx, disc=self.rotate)
        if self.rotate:
            rng = np.random.default_rng((self.seed, self.epoch, idx))
            scene = crop_to_window(rotate_scene(scene, float(rng.uniform(-np.pi, np.pi))))
        net = self.network(self.store.net_path(idx))
        # the density condition: every vehicle of the window per km of all its car lanes, internal
        # ones included (the model's unit; the generator converts a requested density into it)
        km = net.condition_km(scene.window)
        density = per_km(len(scene), km)
        density = float("nan") if density is None else density
        if len(scene) > self.max_agents:  # keep the agents nearest the centre
            keep = np.argsort(np.hypot(scene.boxes[:, 0], scene.boxes[:, 1]))[: self.max_agents]
            scene = scene.select(np.sort(keep))
        signals = scene.meta.get("signals") or None
        if signals and self.p_no_signals > 0 and \
                np.random.default_rng((self.seed, self.epoch, idx, 1)).random() < self.p_no_signals:
            signals = None
        return {"density": density,
            "map": render_map(net, scene.window, self.raster, signals=signals),
            "agents": render_agents(scene.boxes, scene.traj, scene.traj_mask, self.raster),
            "boxes": scene.boxes, "traj": scene.traj, "traj_mask": scene.traj_mask,
            "speed": scene.speed, "vclass": scene.vclass, "index": idx, "window": scene.window,
        }


def collate_scenes(items: list[dict]) -> dict:
    """Stack rasters and pad the sparse arrays to the batch's largest scene (``valid`` marks agents)."""
    n = max([len(it["boxes"]) for it in items] + [0])
    b = len(items)
    out = {"map": torch.from_numpy(np.stack([it["map"] for it in items])),
           "agents": torch.from_numpy(np.stack([it["agents"] for it in items])),
           "index": torch.tensor([it["index"] for it in items]),
           "density": torch.tensor([it.get("density", float("nan")) for it in items], dtype=torch.float64),
           "window": [it.get("window") for it in items]}
    shapes = {"boxes": (5,), "traj": (5, 3), "traj_mask": (5,), "speed": (5,), "vclass": ()}
    dtypes = {"traj_mask": np.bool_, "vclass": np.int64}
    for key, shape in shapes.items():
        arr = np.zeros((b, n) + shape, dtype=dtypes.get(key, np.float32))
        for i, it in enumerate(items):
            arr[i, : len(it[key])] = it[key]
        out[key] = torch.from_numpy(arr)
    valid = np.zeros((b, n), bool)
    for i, it in enumerate(items):
        valid[i, : len(it["boxes"])] = True
    out["valid"] = torch.from_numpy(valid)
    return out
