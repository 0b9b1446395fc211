"""Scenario Dreamer's distribution set (Rowe et al., CVPR'25, sec. 5 "Metrics"): Jensen–Shannon
divergences between histograms of per-vehicle features of two sets of scenes, and the share of
vehicles in collision.

Unlike the paper's MMD² (:mod:`.metrics`, per window, paired), these compare *pooled* vehicles: the
two sets need not share windows, so a set's floor is SUMO's own traffic in other windows of the same
network at the same sample size (``python -m sumo_scendiff.evaluate`` compares every method on one
half of the windows and SUMO's traffic on that half with the other half).

Features (:data:`JSD_BINS`: range, bin width and the scale each JSD is reported at, as Scenario
Dreamer's tables):

* ``nearest``: centre distance to the nearest other vehicle of the same scene (a scene of one
  vehicle gives none);
* ``lane_distance`` and ``lane_heading``: distance to the nearest car-lane centre line and the
  signed heading difference to it (degrees), for vehicles within :data:`LANE_REACH` of one;
* ``length``, ``width``: the box;
* ``speed``: at t = 0.

Each JSD is the squared Jensen–Shannon distance (natural logarithm, so in [0, ln 2]) of the two
normalised histograms; values beyond a range count in its edge bin. ``collision``: the share of
vehicles that overlap another, each box approximated by five circles of radius w/2 along its length,
two vehicles colliding when two of their circles' centres are closer than (w_j + w_k) / sqrt(3.8).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.distance import cdist, jensenshannon

from ..core.geometry import T0, wrap_angle
from ..core.scene import Scene

# feature -> (low, high, bin width, scale)
JSD_BINS = {"nearest": (0.0, 50.0, 1.0, 10.0),
            "lane_distance": (0.0, 1.5, 0.1, 10.0),
            "lane_heading": (-200.0, 200.0, 5.0, 100.0),
            "length": (0.0, 25.0, 0.1, 100.0),
            "width": (0.0, 5.0, 0.1, 100.0),
            "speed": (0.0, 50.0, 1.0, 100.0)}
LANE_REACH = 1.5        # m: a vehicle farther from every car-lane centre line has no lane features
CIRCLES = 5             # circles per box in the collision test
COLLISION_DIVISOR = np.sqrt(3.8)
FEATURES = tuple(JSD_BINS)


def _nearest(scene: Scene) -> np.ndarray:
    if len(scene) < 2:
        return np.zeros(0)
    d = cdist(scene.boxes[:, :2].astype(np.float64), scene.boxes[:, :2].astype(np.float64))
    np.fill_diagonal(d, np.inf)
    return d.min(1)


def lane_features(scenes: Sequence[Scene], net) -> tuple[np.ndarray, np.ndarray]:
    """Distance (m) to the nearest car-lane centre line and the signed heading difference to it
    (degrees, in [-180, 180)) of every vehicle within :data:`LANE_REACH` of one, pooled."""
    xy = [s.window.scene_to_world(s.boxes[:, :2].astype(np.float64)) for s in scenes if len(s)]
    yaw = [s.window.yaw_to_world(s.boxes[:, 2].astype(np.float64)) for s in scenes if len(s)]
    if not xy:
        return np.zeros(0), np.zeros(0)
    xy, yaw = np.concatenate(xy), np.concatenate(yaw)
    m = net.match_poses(xy, None, radius=LANE_REACH)   # no yaw: the nearest centre line, any direction
    near = (m.lane >= 0) & (m.lateral <= LANE_REACH)
    return m.lateral[near], np.degrees(wrap_angle(yaw[near] - m.heading[near]))


def vehicle_features(scenes: Sequence[Scene], net) -> dict[str, np.ndarray]:
    """The pooled per-vehicle values of every feature of :data:`JSD_BINS` over ``scenes``."""
    boxes = np.concatenate([s.boxes for s in scenes]) if scenes else np.zeros((0, 5), np.float32)
    speed = np.concatenate([s.speed[:, T0] for s in scenes]) if scenes else np.zeros(0)
    lane_distance, lane_heading = lane_features(scenes, net)
    nearest = [_nearest(s) for s in scenes]
    return {"nearest": np.concatenate(nearest) if nearest else np.zeros(0),
            "lane_distance": lane_distance, "lane_heading": lane_heading,
            "length": boxes[:, 3].astype(np.float64), "width": boxes[:, 4].astype(np.float64),
            "speed": speed.astype(np.float64)}


def histogram(values: np.ndarray, low: float, high: float, width: float) -> np.ndarray:
    """Counts in bins of ``width`` over [low, high]; values beyond count in the edge bins."""
    n = int(round((high - low) / width))
    v = np.clip(np.asarray(values, np.float64), low, high)
    return np.histogram(v, bins=n, range=(low, high))[0].astype(np.float64)


def jsd(a: np.ndarray, b: np.ndarray, low: float, high: float, width: float) -> float:
    """Squared Jensen–Shannon distance (natural log) between the histograms of ``a`` and ``b``;
    NaN when either is empty."""
    ha, hb = histogram(a, low, high, width), histogram(b, low, high, width)
    if ha.sum() == 0 or hb.sum() == 0:
        return float("nan")
    return float(jensenshannon(ha / ha.sum(), hb / hb.sum()) ** 2)


def circle_centres(boxes: np.ndarray) -> np.ndarray:
    """(N, CIRCLES, 2): centres of the circles of radius w/2 spaced evenly along each box, the end
    ones touching its front and rear (a box shorter than wide: all at its centre)."""
    b = np.asarray(boxes, np.float64)
    half = np.maximum(b[:, 3] - b[:, 4], 0.0) / 2
    t = np.linspace(-1.0, 1.0, CIRCLES)[None, :] * half[:, None]
    return b[:, None, :2] + t[..., None] * np.stack([np.cos(b[:, 2]), np.sin(b[:, 2])], -1)[:, None]


def colliding(scene: Scene) -> np.ndarray:
    """(N,) bool: the vehicles of ``scene`` that collide with another (five-circle test)."""
    n = len(scene)
    if n < 2:
        return np.zeros(n, bool)
    c = circle_centres(scene.boxes)
    d = cdist(c.reshape(-1, 2), c.reshape(-1, 2)).reshape(n, CIRCLES, n, CIRCLES).min((1, 3))
    w = scene.boxes[:, 4].astype(np.float64)
    hit = d < (w[:, None] + w[None, :]) / COLLISION_DIVISOR
    np.fill_diagonal(hit, False)
    return hit.any(1)


def collision_share(scenes: Sequence[Scene]) -> float:
    """The share of all vehicles of ``scenes`` in collision with another of their scene (NaN: none)."""
    hits = [colliding(s) for s in scenes if len(s)]
    return float(np.concatenate(hits).mean()) if hits else float("nan")


def jsd_set(features: dict[str, np.ndarray], reference: dict[str, np.ndarray]) -> dict[str, float]:
    """``jsd_FEATURE`` for every feature (scaled as :data:`JSD_BINS` says) between two
    :func:`vehicle_features`."""
    return {f"jsd_{k}": scale * jsd(features[k], reference[k], lo, hi, w)
            for k, (lo, hi, w, scale) in JSD_BINS.items()}


def evaluate_jsd(scenes: Sequence[Scene], reference: Sequence[Scene], net,
                 reference_features: dict[str, np.ndarray] | None = None) -> dict[str, float]:
    """The JSD set of ``scenes`` against ``reference`` (pass ``reference_features`` to reuse them),
    with ``collision``, the share of ``scenes``' vehicles in collision."""
    ref = reference_features if reference_features is not None else vehicle_features(reference, net)
    return {**jsd_set(vehicle_features(scenes, net), ref), "collision": collision_share(scenes)}
