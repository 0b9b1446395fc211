"""Recorded scenes' episodes run again: other windows at the same instants, or the same windows later.

    again = rerecorded(data_dir, windows, delays=(0.0, 120.0))  # windows[i]: for scene i of data_dir
    whole, later = again[0.0], again[120.0]

Every recorded episode is deterministic (the manifest keeps its spec: seed, demand, warm-up), so it
can be run again and cut anywhere. Two uses in the evaluation:

* **whole turned windows** (delay 0): a window turned by a random angle about its centre covers
  ground the recorded square did not (up to 17 % of it at 45°); cropping the recorded scene leaves
  those corners empty (city: 345 agents in 40 turned windows where SUMO has 378). Recording the
  turned window itself at the scene's instant gives every vehicle in it.
* **the same window later** (delay > 0): the evaluation compares each generated scene with the one
  recorded scene of its window, so even a generator drawing from SUMO's own distribution of what
  that window holds has MMD² > 0. The window ``delay`` s later in the same traffic (the same streets,
  signals and demand, other vehicles) is such a draw: a reference for what the metrics can reach.

Each delay's scenes are cached beside the data directory, keyed by the windows.
"""
from __future__ import annotations

import hashlib
import os
from collections import defaultdict
from dataclasses import replace
from typing import Sequence

import numpy as np

from ..core.geometry import Window
from ..core.scene import Scene
from ..map.network import Network
from .record import EpisodeSpec, record_at
from .shards import SceneStore, Shard, read_manifest, resolve_net_path, write_shard


def _cache(data_dir: str, windows: Sequence[Window], delay: float) -> str:
    key = hashlib.sha1(np.array([w.as_tuple() for w in windows], np.float64).tobytes()).hexdigest()[:12]
    return f"{data_dir.rstrip(os.sep)}-again{delay:g}-{key}.npz"


def rerecorded(data_dir: str, windows: Sequence[Window], delays: Sequence[float],
               progress: bool = False) -> dict[float, list[Scene]]:
    """``{delay: scenes}``: scene i of ``data_dir``'s episode cut ``delay`` s after scene i's
    instant, in ``windows[i]``. One run of each episode serves every delay."""
    store = SceneStore(data_dir)
    if len(windows) > len(store):
        raise ValueError(f"{data_dir}: {len(windows)} windows for {len(store)} scenes")
    out: dict[float, list[Scene]] = {}
    for d in delays:
        path = _cache(data_dir, windows, d)
        if os.path.exists(path):
            shard = Shard.load(path)
            out[d] = [shard.scene(i, store.net_name(i)) for i in range(len(shard))]
    todo = [d for d in delays if d not in out]
    if not todo:
        return out
    manifest = read_manifest(data_dir)
    specs = {e["file"]: EpisodeSpec(**{k: v for k, v in e.items() if k != "file"})
             for e in manifest["episodes"]}
    specs = {f: replace(s, routes=s.routes and os.path.normpath(os.path.join(data_dir, s.routes)))
             for f, s in specs.items()}   # (the manifest keeps them relative to the data directory)
    by_episode: dict[tuple[str, int], list[int]] = defaultdict(list)
    for i in range(len(windows)):
        s = manifest["shards"][store.index[i][0]]
        by_episode[(s["file"], s["net"])].append(i)
    new = {d: [None] * len(windows) for d in todo}
    from tqdm import tqdm
    for (file, net_index), idx in tqdm(sorted(by_episode.items()), desc="recording the windows again",
                                       unit="episode", disable=not progress, leave=False):
        net = Network.load(resolve_net_path(data_dir, manifest["nets"][net_index]))
        times = [store.scene(i).time for i in idx]
        scenes = record_at(net, specs[file], [(t + d, windows[i]) for d in todo for t, i in zip(times, idx)])
        for a, d in enumerate(todo):
            for i, s in zip(idx, scenes[a * len(idx):(a + 1) * len(idx)]):
                new[d][i] = s
    for d in todo:
        write_shard(_cache(data_dir, windows, d), new[d], 0)   # atomic
        out[d] = new[d]
    return out
