"""Tiles that agree: a grid of overlapping windows over a whole network, generated colour by colour.

    tiles = tile_grid(net, stride=75.0, size=100.0)            # every core with car lane in it
    for colour in colours(tiles):                              # 4 batches; no two tiles of one overlap
        pins = [pins_for(t, accepted) for t in colour]         # earlier neighbours' vehicles in t
        ...generate colour with pins...
        accepted.add(keep_core(t, scene))                      # own core only, no overlaps

Each tile is a ``size`` m window (yaw 0) centred on a ``stride`` m *core* cell; the cores partition
the plane (half-open cells), so every vehicle has exactly one owner tile. With stride < size two
neighbouring windows overlap by ``size - stride`` m, and tiles two cells apart do not overlap when
``2 stride >= size``: colouring the grid by (i mod 2, j mod 2) gives four batches whose tiles are
independent of each other. A tile sees the vehicles its already generated neighbours own inside
its window as pinned tokens, so the model continues their traffic instead of drawing a second car
where one stands (no seams, no duplicates).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from ..core.geometry import T0, Window, box_polygons

MIN_AREA = 1e-3   # m^2: boxes touching along an edge are not an overlap (as scene_passes.remove_overlaps)
AT_BOUNDARY = 0.01   # m: an --area side this close to the network's boundary is on it (its file's 2 decimals)


class TileError(ValueError):
    """One line naming the flag and the problem."""


@dataclass(frozen=True)
class Tile:
    index: int
    i: int                  # column (x) and row (y) in the grid
    j: int
    window: Window
    core: tuple             # (x0, y0, x1, y1), half-open: x0 <= x < x1
    core_km: float          # car lane inside the core (and the area)

    @property
    def colour(self) -> int:
        return (self.i % 2) * 2 + (self.j % 2)

    def in_core(self, xy: np.ndarray) -> np.ndarray:
        x0, y0, x1, y1 = self.core
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)


def parse_area(text: str | None) -> tuple | None:
    if text is None:
        return None
    try:
        v = [float(p) for p in text.split(",")]
    except ValueError:
        raise TileError(f"--area: not four numbers X0,Y0,X1,Y1: {text!r}") from None
    if len(v) != 4 or not all(math.isfinite(p) for p in v) or v[2] <= v[0] or v[3] <= v[1]:
        raise TileError(f"--area: needs X0,Y0,X1,Y1 with X1 > X0 and Y1 > Y0, got {text!r}")
    return tuple(v)


def car_bounds(net) -> tuple:
    """The bounding box of the network's car lanes."""
    xy = np.concatenate([net.lanes[i].shape for i in net.car_lane_ids])
    return (*xy.min(0), *xy.max(0))


def whole_area(net, area: tuple | None) -> tuple | None:
    """``area`` as the fill uses it: each side on or beyond the network's boundary (sumolib's
    ``getBoundary``, the junctions and the edges' centre lines) taken out to the outline of the
    outermost car lanes, which lie half a lane width and more beyond it; the other sides kept exactly.
    A user giving the network's boundary means the whole network, outer streets included."""
    if area is None:
        return None
    bx0, by0, bx1, by1 = net.sumo_net.getBoundary()
    lx0, ly0, lx1, ly1 = shapely.total_bounds([net.lanes[i].polygon for i in net.car_lane_ids])
    x0, y0, x1, y1 = area
    return (min(x0, lx0) if x0 <= bx0 + AT_BOUNDARY else x0, min(y0, ly0) if y0 <= by0 + AT_BOUNDARY else y0,
            max(x1, lx1) if x1 >= bx1 - AT_BOUNDARY else x1, max(y1, ly1) if y1 >= by1 - AT_BOUNDARY else y1)


def in_area(xy: np.ndarray, area: tuple | None) -> np.ndarray:
    """Per point (x, y: a vehicle's box centre) whether it lies in ``area`` (X0, Y0, X1, Y1, its sides
    included; None: everywhere): the one rule of the fill's "in the area"."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if area is None:
        return np.ones(len(xy), bool)
    x0, y0, x1, y1 = area
    return (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)


def tile_grid(net, area: tuple | None = None, stride: float = 75.0, size: float = 100.0) -> list[Tile]:
    """The tiles whose core holds car lane (inside ``area`` when given), in row-major order."""
    if not (0 < stride <= size and 2 * stride >= size):
        # stride > size leaves gaps between windows; 2 stride < size lets same-colour tiles overlap
        raise TileError(f"--stride: must be in [{size / 2:g}, {size:g}] m for {size:g} m windows, got {stride:g}")
    x0, y0, x1, y1 = area if area is not None else car_bounds(net)
    nx, ny = max(1, math.ceil((x1 - x0) / stride)), max(1, math.ceil((y1 - y0) / stride))
    # the grid centred on the area: the margin it sticks out is the same on both sides
    gx, gy = 0.5 * (x0 + x1) - 0.5 * nx * stride, 0.5 * (y0 + y1) - 0.5 * ny * stride
    clip = shapely.box(x0, y0, x1, y1) if area is not None else None
    tiles = []
    for j in range(ny):
        for i in range(nx):
            core = (gx + i * stride, gy + j * stride, gx + (i + 1) * stride, gy + (j + 1) * stride)
            region = shapely.box(*core)
            if clip is not None:
                region = shapely.intersection(region, clip)
            km = net.car_lane_km_in(region) if not region.is_empty else 0.0
            if km <= 0:
                continue       # nothing of the network to own here: the neighbours' windows see it
            w = Window(0.5 * (core[0] + core[2]), 0.5 * (core[1] + core[3]), 0.0, size)
            tiles.append(Tile(len(tiles), i, j, w, core, km))
    return tiles


def colours(tiles: list[Tile]) -> list[list[Tile]]:
    """The generation batches: by colour, then tile index (fixed, so a seed gives one fill)."""
    return [[t for t in tiles if t.colour == c] for c in range(4) if any(t.colour == c for t in tiles)]


class Accepted:
    """Every kept vehicle so far, world frame: x, y, heading, length, width, speed; and its tile."""

    def __init__(self):
        self.rows = np.zeros((0, 6))
        self.tile = np.zeros(0, np.int64)
        self.polys = np.zeros(0, dtype=object)

    def __len__(self):
        return len(self.rows)

    def add(self, rows: np.ndarray, tile: int) -> None:
        rows = np.asarray(rows, np.float64).reshape(-1, 6)
        self.rows = np.concatenate([self.rows, rows])
        self.tile = np.concatenate([self.tile, np.full(len(rows), tile)])
        self.polys = np.concatenate([self.polys, box_polygons(rows)])

    def inside(self, window: Window) -> np.ndarray:
        """Indices of the kept vehicles whose centre lies in ``window``."""
        if not len(self.rows):
            return np.zeros(0, np.int64)
        return np.flatnonzero(window.contains(window.world_to_scene(self.rows[:, :2])))

    def overlapping(self, rows: np.ndarray) -> np.ndarray:
        """Per candidate row, whether its box overlaps a kept vehicle's."""
        out = np.zeros(len(rows), bool)
        if not len(self.rows) or not len(rows):
            return out
        mine = box_polygons(rows)
        a, b = shapely.STRtree(self.polys).query(mine, predicate="intersects")
        for k, m in zip(a, b):
            if not out[k] and shapely.area(shapely.intersection(mine[k], self.polys[m])) > MIN_AREA:
                out[k] = True
        return out


def pins_for(tile: Tile, accepted: Accepted) -> tuple[list[dict], np.ndarray]:
    """The pinned tokens (window frame: pose, size and speed) of the vehicles earlier tiles own in
    ``tile``'s window, and their indices into ``accepted``."""
    idx = accepted.inside(tile.window)
    w, r = tile.window, accepted.rows[idx]
    xy = w.world_to_scene(r[:, :2]) if len(r) else np.zeros((0, 2))
    yaw = w.yaw_to_scene(r[:, 2]) if len(r) else np.zeros(0)
    return [{"x": float(p[0]), "y": float(p[1]), "heading": float(h), "length": float(v[3]),
             "width": float(v[4]), "speed": float(v[5])} for p, h, v in zip(xy, yaw, r)], idx


def known_share(net, tile: Tile, owned_cores: list[tuple]) -> float:
    """The share of ``tile``'s window (by car-lane length) that earlier tiles' cores cover: the
    share of its traffic its pinned tokens describe when the neighbours are as dense as it is."""
    square = shapely.box(*tile.window.world_bounds())
    total = net.car_lane_km_in(square)
    if total <= 0 or not owned_cores:
        return 0.0
    covered = shapely.intersection(shapely.union_all([shapely.box(*c) for c in owned_cores]), square)
    return 0.0 if covered.is_empty else min(net.car_lane_km_in(covered) / total, 1.0)


def scene_rows(scene) -> np.ndarray:
    """A generated scene's agents as world rows x, y, heading, length, width, speed (t = 0)."""
    w, b = scene.window, scene.boxes.astype(np.float64)
    if not len(b):
        return np.zeros((0, 6))
    xy = w.scene_to_world(b[:, :2])
    return np.column_stack([xy, w.yaw_to_world(b[:, 2]), b[:, 3], b[:, 4], scene.speed[:, T0]])


def keep_core(tile: Tile, scene, accepted: Accepted, area: tuple | None = None) -> np.ndarray:
    """Indices of ``scene``'s agents the tile keeps: centre in its own core (and the area), box
    overlapping no vehicle kept before. Pinned neighbours the model redrew lie in their owners'
    cores, so they are never kept twice."""
    rows = scene_rows(scene)
    ok = tile.in_core(rows[:, :2]) & in_area(rows[:, :2], area) if len(rows) else np.zeros(0, bool)
    idx = np.flatnonzero(ok)
    return idx[~accepted.overlapping(rows[idx])]


__all__ = [
    "Accepted",
    "Tile",
    "TileError",
    "car_bounds",
    "colours",
    "in_area",
    "keep_core",
    "known_share",
    "parse_area",
    "pins_for",
    "scene_rows",
    "tile_grid",
    "whole_area",
]
