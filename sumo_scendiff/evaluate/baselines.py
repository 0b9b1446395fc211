"""Baselines the generated scenes are compared against (paper sec. 4.1 "Baselines", plus SUMO's own).

* :class:`RandomLogSelection` (the paper's heuristic baseline): the agents of a random training scene,
  copied unchanged in scene coordinates into the target window -- the map is ignored.
* :class:`LaneUniform`: what a SUMO user does today without data: vehicles of a standard type mix
  inserted at uniformly random positions on random normal lanes of the window, at the lane's speed
  limit times SUMO's speed factor, driving along the lane centre line.

Both have ``generate(window, n=None, index=None) -> Scene``. They are deterministic given the seed:
with ``index=None`` draws come from one generator (so results depend on the call order); with an
explicit ``index`` the draws come from ``SeedSequence([seed, index])`` and do not depend on order.
"""
from __future__ import annotations

from typing import Callable, Union

import numpy as np
import shapely

from ..core.geometry import T0, TIMES, Window, box_corners
from ..core.scene import VEHICLE_CLASSES, Scene
from ..data.demand import VEHICLE_MIX

# Typical moderate density a SUMO user without data would pick: 25 vehicles per km of lane (a vehicle
# every 40 m per lane: free-flowing urban traffic, well below the ~130 veh/km/lane of a standing queue).
DENSITY_PER_KM_LANE = 25.0
# SUMO's default speedFactor distribution for passenger cars: normc(1, 0.1, 0.2, 2), i.e. N(1, 0.1)
# limited to [0.2, 2]; we clip (the limits are 8 and 10 standard deviations away: never hit in practice).
SPEED_FACTOR_MEAN, SPEED_FACTOR_STD, SPEED_FACTOR_RANGE = 1.0, 0.1, (0.2, 2.0)
MAX_TRIES = 30           # placement attempts per vehicle before giving up on it (no overlap found)
TYPE_PROB = np.array([m[9] for m in VEHICLE_MIX], np.float64)
TYPE_LENGTH = np.array([m[3] for m in VEHICLE_MIX], np.float64)
TYPE_WIDTH = np.array([m[4] for m in VEHICLE_MIX], np.float64)
TYPE_VMAX = np.array([m[8] for m in VEHICLE_MIX], np.float64)
TYPE_VCLASS = np.array([VEHICLE_CLASSES.index(m[1]) for m in VEHICLE_MIX], np.int8)

CountRule = Union[str, Callable[[float, np.random.Generator], int]]


def _rng(seed: int, index: int | None, shared: np.random.Generator) -> np.random.Generator:
    return shared if index is None else np.random.default_rng(np.random.SeedSequence([seed, index]))


# ---- Random Log Selection ----------------------------------------------------------------------
class RandomLogSelection:
    """Random Log Selection (sec. 4.1): the agents of a uniformly random scene of ``pool_scenes``
    (training scenes: a list of :class:`Scene` or a ``SceneStore``), with boxes, trajectories,
    speeds and classes copied unchanged in scene coordinates into the target window. Agents whose
    centre falls outside the target window (only possible if the window sizes differ) are dropped.

    ``generate(window, n)``: with ``n`` given, the source scene is drawn among the pool scenes whose
    agent count is closest to ``n`` ("told the true count")."""

    def __init__(self, pool_scenes, seed: int = 0):
        if len(pool_scenes) == 0:
            raise ValueError("RandomLogSelection needs a non-empty pool of training scenes")
        self.pool = pool_scenes
        self.seed = seed
        self._shared = np.random.default_rng(seed)
        self._counts: np.ndarray | None = None

    def _scene(self, i: int) -> Scene:
        return self.pool.scene(i) if hasattr(self.pool, "scene") else self.pool[i]

    def _pick(self, rng: np.random.Generator, n: int | None) -> int:
        if n is None:
            return int(rng.integers(len(self.pool)))
        if self._counts is None:
            self._counts = np.array([len(self._scene(i)) for i in range(len(self.pool))])
        gap = np.abs(self._counts - n)
        cand = np.flatnonzero(gap == gap.min())
        return int(cand[rng.integers(len(cand))])

    def generate(self, window: Window, n: int | None = None, index: int | None = None) -> Scene:
        """A pool scene's agents in ``window`` (``meta['source']`` = its pool index)."""
        src_i = self._pick(_rng(self.seed, index, self._shared), n)
        src = self._scene(src_i)
        out = Scene(window, src.boxes.copy(), src.traj.copy(), src.traj_mask.copy(), src.speed.copy(),
                    src.vclass.copy(), src.net, src.time,
                    {"baseline": "random_log", "source": src_i, "source_net": src.net})
        return out.select(window.contains(out.boxes[:, :2].astype(np.float64)))


# ---- Lane-uniform insertion --------------------------------------------------------------------
class LanePath:
    """A lane centre line as a polyline with arc length: poses at any distance ``s`` along it; beyond
    the ends the path continues straight along the end tangent."""

    def __init__(self, shape: np.ndarray):
        pts = np.asarray(shape, np.float64)[:, :2]
        keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-6])
        pts = pts[keep]
        if len(pts) == 1:
            pts = np.vstack([pts, pts + [1e-3, 0.0]])
        self.pts = pts
        self.seg = np.diff(pts, axis=0)
        self.seg_len = np.hypot(self.seg[:, 0], self.seg[:, 1])
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.length = float(self.cum[-1])

    def pose(self, s) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) (..., 2) and heading (...) at distances ``s`` (...) along the lane."""
        s = np.asarray(s, np.float64)
        k = np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.seg) - 1)
        u = (s - self.cum[k]) / self.seg_len[k]          # < 0 before the start, > 1 past the end
        xy = self.pts[k] + u[..., None] * self.seg[k]
        return xy, np.arctan2(self.seg[k, 1], self.seg[k, 0])


def window_polygon(window: Window) -> shapely.Polygon:
    """The (rotated) window square in world coordinates."""
    h = 0.5 * window.size
    return shapely.Polygon(window.scene_to_world(np.array([[h, h], [-h, h], [-h, -h], [h, -h]])))


def inside_intervals(line: shapely.LineString, square: shapely.Polygon) -> np.ndarray:
    """(K, 2) intervals [a, b] of distance along ``line`` that lie inside ``square``."""
    parts = [p for p in shapely.get_parts(shapely.intersection(line, square))
             if p.geom_type == "LineString" and p.length > 0]
    if not parts:
        return np.zeros((0, 2))
    ends = np.array([[line.project(shapely.Point(p.coords[0])), line.project(shapely.Point(p.coords[-1]))]
                     for p in parts])
    return np.sort(ends, axis=1)


def uniform_on_intervals(iv: np.ndarray, rng: np.random.Generator) -> float:
    """A uniform draw on the union of intervals ``iv`` (K, 2)."""
    lens = iv[:, 1] - iv[:, 0]
    cum = np.cumsum(lens)
    u = rng.random() * cum[-1]
    k = min(int(np.searchsorted(cum, u, side="right")), len(iv) - 1)
    return float(iv[k, 0] + u - (cum[k] - lens[k]))


def poisson_count(lane_km: float, rng: np.random.Generator) -> int:
    """LaneUniform's own count rule: Poisson(lane km inside the window * 25 vehicles/km/lane)."""
    return int(rng.poisson(lane_km * DENSITY_PER_KM_LANE))


def speed_factor(rng: np.random.Generator) -> float:
    """SUMO's default speedFactor: N(1, 0.1) clipped to [0.2, 2]."""
    return float(np.clip(rng.normal(SPEED_FACTOR_MEAN, SPEED_FACTOR_STD), *SPEED_FACTOR_RANGE))


class LaneUniform:
    """Uniform insertion on lanes -- what a SUMO user does today without data.

    For a window: the normal (non-internal) car lanes crossing it, each weighted by its length inside
    the window. Each vehicle: a lane by that weight, a position uniform along the lane's inside part, a
    type from :data:`VEHICLE_MIX` by its probability (among the types the lane allows), heading = lane
    heading there, speed = min(lane limit * speedFactor, type max speed) with speedFactor ~ N(1, 0.1)
    clipped to [0.2, 2] (SUMO's default), trajectory t = -2..+2 s by constant-speed motion along the
    lane centre line (straight on along the end tangent past the lane's ends), all 5 poses observed.
    A draw whose box overlaps an already placed box (oriented boxes, shapely) is redrawn, at most
    :data:`MAX_TRIES` times per vehicle; then that vehicle is skipped (``meta['placed']`` < requested).

    Count: ``generate(window, n)`` places ``n`` ("told the true count"); with ``n=None`` the
    ``count_rule`` decides: ``"poisson"`` (:func:`poisson_count`) or a callable (lane_km, rng) -> int.
    """

    def __init__(self, net, count_rule: CountRule = "poisson", seed: int = 0):
        if isinstance(count_rule, str) and count_rule != "poisson":
            raise ValueError(f"unknown count_rule {count_rule!r}: use 'poisson' or a callable")
        self.net = net
        self.count_rule = poisson_count if isinstance(count_rule, str) else count_rule
        self.seed = seed
        self._shared = np.random.default_rng(seed)
        self._paths: dict[int, LanePath] = {}
        self._type_p: dict[int, np.ndarray] = {}

    def candidate_lanes(self, window: Window) -> tuple[np.ndarray, list[np.ndarray]]:
        """Normal car lanes crossing the window and their inside intervals (distance along the lane)."""
        square = window_polygon(window)
        idx, ivs = [], []
        for i in self.net.lanes_in(window):
            ln = self.net.lanes[i]
            if not ln.car or ln.function != "":
                continue
            iv = inside_intervals(self.net.lines[i], square)
            if len(iv) and (iv[:, 1] - iv[:, 0]).sum() > 0:
                idx.append(int(i))
                ivs.append(iv)
        return np.array(idx, np.int64), ivs

    def _path(self, i: int) -> LanePath:
        if i not in self._paths:
            self._paths[i] = LanePath(self.net.lanes[i].shape)
        return self._paths[i]

    def _type_probs(self, i: int) -> np.ndarray:
        """VEHICLE_MIX probabilities restricted to the types lane ``i`` allows."""
        if i not in self._type_p:
            p = TYPE_PROB.copy()
            sn = getattr(self.net, "sumo_net", None)
            if sn is not None:
                lane = sn.getLane(self.net.lanes[i].id)
                p *= np.array([lane.allows(m[1]) for m in VEHICLE_MIX], np.float64)
            self._type_p[i] = p / p.sum() if p.sum() > 0 else TYPE_PROB / TYPE_PROB.sum()
        return self._type_p[i]

    def _draw_vehicle(self, lane: int, iv: np.ndarray, rng: np.random.Generator):
        """(type index, distance along the lane, speed) of one vehicle on ``lane``."""
        d = uniform_on_intervals(iv, rng)
        t = int(rng.choice(len(VEHICLE_MIX), p=self._type_probs(lane)))
        v = min(self.net.lanes[lane].speed * speed_factor(rng), TYPE_VMAX[t])
        return t, d, v

    def generate(self, window: Window, n: int | None = None, index: int | None = None) -> Scene:
        """``n`` (default: the count rule) lane-uniform vehicles in ``window``; ``meta`` records
        ``requested``, ``placed`` and ``lane_km`` (normal car-lane km inside the window)."""
        rng = _rng(self.seed, index, self._shared)
        lanes, ivs = self.candidate_lanes(window)
        inside = np.array([(iv[:, 1] - iv[:, 0]).sum() for iv in ivs])
        lane_km = float(inside.sum()) / 1000.0
        if n is None:
            n = self.count_rule(lane_km, rng)
        meta = {"baseline": "lane_uniform", "requested": int(n), "lane_km": lane_km}
        if len(lanes) == 0 or n <= 0:
            return Scene.empty(window, meta={**meta, "placed": 0})
        weights = inside / inside.sum()
        times = np.asarray(TIMES)
        placed: list[shapely.Polygon] = []
        rows = []
        for _ in range(int(n)):
            for _try in range(MAX_TRIES):
                k = int(rng.choice(len(lanes), p=weights))
                t, d, v = self._draw_vehicle(int(lanes[k]), ivs[k], rng)
                xy, yaw = self._path(int(lanes[k])).pose(d + v * times)
                c = window.world_to_scene(xy[T0])
                if not window.contains(c):
                    continue
                poly = shapely.Polygon(box_corners(xy[T0, 0], xy[T0, 1], yaw[T0], TYPE_LENGTH[t], TYPE_WIDTH[t]))
                if placed and shapely.intersects(poly, np.array(placed, dtype=object)).any():
                    continue
                placed.append(poly)
                rows.append((t, v, window.world_to_scene(xy), window.yaw_to_scene(yaw)))
                break
        meta["placed"] = len(rows)
        if not rows:
            return Scene.empty(window, meta=meta)
        ts = np.array([r[0] for r in rows])
        traj = np.concatenate([np.stack([r[2] for r in rows]), np.stack([r[3] for r in rows])[..., None]], -1)
        boxes = np.concatenate([traj[:, T0], TYPE_LENGTH[ts, None], TYPE_WIDTH[ts, None]], -1)
        speed = np.repeat(np.array([r[1] for r in rows])[:, None], len(TIMES), 1)
        return Scene(window, boxes, traj, np.ones((len(rows), len(TIMES)), bool), speed,
                     TYPE_VCLASS[ts], getattr(self.net, "name", ""), 0.0, meta)
