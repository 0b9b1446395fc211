"""The batched post-processing of generation gives what the straightforward loops it replaced gave,
bit for bit, on random inputs: overlap removal (scene_passes.remove_overlaps) and junction headings
(lane_heading.junction_yaw). The references below are those loops as they were."""
from __future__ import annotations

import os

import numpy as np
import pytest
import shapely
import torch

from sumo_scendiff.core.geometry import Window, box_corners, wrap_angle
from sumo_scendiff.generation.generator import remove_overlaps
from sumo_scendiff.generation.lane_heading import junction_yaw
from sumo_scendiff.map.network import Network
from sumo_scendiff.map.raster import MAP_CHANNELS, render_map
from sumo_scendiff.model.detection import C_Y, decode_boxes, on_junction
from sumo_scendiff.model.heading import decode_heading, heading_probability

CITY = os.path.join(os.path.dirname(__file__), "..", "networks", "city.net.xml")


def reference_remove_overlaps(boxes, prob):
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    order = np.argsort(-prob, kind="stable")
    polys = shapely.polygons(box_corners(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3], boxes[:, 4]))
    a, b = shapely.STRtree(polys).query(polys, predicate="intersects")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    overlaps: dict[int, list[int]] = {}
    for i, j in zip(a, b):
        if i != j and shapely.area(shapely.intersection(polys[i], polys[j])) > 1e-3:
            overlaps.setdefault(int(i), []).append(int(j))
    removed = np.zeros(len(boxes), bool)
    for i in order:
        if removed[i]:
            continue
        for j in overlaps.get(int(i), ()):
            if rank[j] > rank[i]:
                removed[j] = True
    return np.sort(np.flatnonzero(~removed))


def reference_junction_yaw(y, windows, net, junction, size=100.0, min_prob=0.5, radius=1.5):
    yf = y.flatten(2).transpose(1, 2)
    yaw = decode_heading(yf[..., C_Y:])
    dec = decode_boxes(y[:, :C_Y], size, yaw=yaw)
    for i, win in enumerate(windows):
        cells = torch.nonzero(dec.prob[i] >= min_prob).squeeze(1)
        if len(cells) == 0:
            continue
        on = on_junction(dec.boxes[i, cells], torch.zeros_like(cells), junction[i:i + 1], size)
        if not on.any():
            continue
        cells = cells[on]
        point, _, heading = net.lane_headings_at(win.scene_to_world(dec.boxes[i, cells, :2].numpy()), radius)
        if len(point) == 0:
            continue
        cand = torch.from_numpy(np.asarray(wrap_angle(heading - win.yaw), np.float32))
        score = heading_probability(yf[i, cells[torch.from_numpy(point)], C_Y:], cand).numpy()
        best = {}
        for p, s, c in zip(point.tolist(), score.tolist(), cand.tolist()):
            if p not in best or s > best[p][0]:
                best[p] = (s, c)
        for p, (_, c) in best.items():
            yaw[i, cells[p]] = c
    return yaw


@pytest.mark.parametrize("seed", range(4))
def test_overlap_removal_as_the_loop(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 80))
    boxes = np.c_[rng.uniform(-20, 20, (n, 2)), rng.uniform(-np.pi, np.pi, n),
                  rng.uniform(3, 6, n), rng.uniform(1.5, 2.2, n)].astype(np.float32)
    prob = np.round(rng.uniform(0.5, 1.0, n), 1).astype(np.float32)     # ties, as rounded scores have
    kept = remove_overlaps(boxes, prob)
    assert np.array_equal(kept, reference_remove_overlaps(boxes, prob))
    assert n < 10 or len(kept) < n                       # crowded enough that some go


def test_junction_headings_as_the_loop():
    net = Network.load(CITY)
    rng = np.random.default_rng(0)
    centres = [j.polygon.centroid for j in net.junctions if j.polygon.area > 50][:6]
    windows = [Window(c.x + rng.uniform(-10, 10), c.y + rng.uniform(-10, 10), rng.uniform(-np.pi, np.pi))
               for c in centres]
    maps = torch.from_numpy(np.stack([render_map(net, w) for w in windows]))
    junction = maps[:, MAP_CHANNELS.index("junction")]
    g = torch.Generator().manual_seed(0)
    y = torch.randn(len(windows), C_Y + 32, 64, 64, generator=g)
    y[:, 0] = 3.0 * torch.randn(len(windows), 64, 64, generator=g)      # about a third of the cells >= 0.5
    got = junction_yaw(y, windows, net, junction)
    want = reference_junction_yaw(y, windows, net, junction)
    changed = (want != decode_heading(y.flatten(2).transpose(1, 2)[..., C_Y:])).sum()
    assert changed > 20                                  # junction cells given a lane's heading
    assert torch.equal(got, want)
