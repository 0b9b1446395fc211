"""Reaching a requested vehicle count the first drawing fell short of, by the paper's infill.

A scene asked for N vehicles (``--density``/``--vehicles``) keeps the model's N most probable boxes
(``scene_passes.trim_to_count``). Where the model drew fewer, the window is drawn again with every agent
of the first scene as a pinned token (the paper's Sec. 4.2 infill, as the whole-network fill pins a
tile's neighbours), its global token at p_mask 1 ("add what belongs here": the count is kept by
trimming; a p_mask naming the share the pins describe is, under the tokens' classifier-free guidance,
a push towards adding nothing, and added a vehicle or two a pass): the model adds traffic that fits
around the vehicles already there. The first
scene is kept as it is; only the second drawing's new agents -- clear of every vehicle of the first
and of every token -- are added, most probable first, up to the count.
"""
from __future__ import annotations

import numpy as np
import shapely

from ..core.geometry import T0, box_polygons
from ..core.scene import Scene


def scene_tokens(scene: Scene) -> list[dict]:
    """A scene's agents as pinnable token dicts (scene frame: pose, size, speed at t = 0)."""
    return [{"x": float(b[0]), "y": float(b[1]), "heading": float(b[2]), "length": float(b[3]),
             "width": float(b[4]), "speed": float(v)} for b, v in zip(scene.boxes, scene.speed[:, T0])]


def area_mask(window, boxes: np.ndarray, area: tuple | None, net=None) -> np.ndarray:
    """Which boxes (scene frame of ``window``) count towards a requested count: centre inside
    ``area`` (a world rectangle x0, y0, x1, y1; None: the whole window, every box) and, given the
    network, front bumper outside every junction: SUMO's edgeData ``density`` counts a vehicle on
    the lane of its front bumper, and a junction's internal lanes are in no edge's density."""
    ok = np.ones(len(boxes), bool)
    if not len(boxes):
        return ok
    boxes = np.asarray(boxes, np.float64)
    if area is not None:
        x0, y0, x1, y1 = area
        xy = window.scene_to_world(boxes[:, :2]).reshape(-1, 2)
        ok &= (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
    if net is not None:
        front = boxes[:, :2] + 0.5 * boxes[:, 3:4] * np.c_[np.cos(boxes[:, 2]), np.sin(boxes[:, 2])]
        ok &= ~net.in_junction(window.scene_to_world(front).reshape(-1, 2))
    return ok


def in_area(scene: Scene, area: tuple | None, net=None) -> np.ndarray:
    """:func:`area_mask` of a scene's agents."""
    return area_mask(scene.window, scene.boxes, area, net)


def add_new_agents(first: Scene, second: Scene, count: int, taken: np.ndarray, radius: float,
                   area: tuple | None = None, net=None) -> Scene:
    """``first`` with the agents of ``second`` that are new -- centre farther than ``radius`` m from
    every point of ``taken`` (the first scene's agents and the tokens' positions, (K, 2)) and box
    clear of the first scene's boxes -- most probable first, until it holds ``count`` agents that
    count (:func:`in_area`; only agents in ``area`` are added)."""
    room = count - int(in_area(first, area, net).sum())
    if room <= 0 or not len(second):
        return first
    ok = in_area(second, area)
    if len(taken):
        ok &= (np.linalg.norm(second.boxes[:, None, :2] - np.asarray(taken)[None, :, :2], axis=-1)
               > radius).all(1)
    if len(first) and ok.any():
        tree = shapely.STRtree(box_polygons(first.boxes))
        a, _ = tree.query(box_polygons(second.boxes), predicate="intersects")
        ok[np.unique(a)] = False
    score = np.asarray(second.meta.get("score", np.ones(len(second))), np.float64)
    new = np.flatnonzero(ok)
    new = new[np.argsort(-score[new], kind="stable")]
    counts = in_area(second, area, net)[new]           # the most probable until room of them count
    new = np.sort(new[np.cumsum(counts) - counts < room])
    if not len(new):
        return first
    extra = second.select(new)
    meta = dict(first.meta)
    for key in ("score", "cell"):
        meta[key] = list(first.meta.get(key, [])) + list(extra.meta.get(key, []))
    if "delivers" in first.meta:
        meta["delivers"] = list(first.meta["delivers"]) + [None] * len(extra)
    meta["infilled"] = int(first.meta.get("infilled", 0)) + len(extra)
    return Scene(first.window, np.concatenate([first.boxes, extra.boxes]),
                 np.concatenate([first.traj, extra.traj]), np.concatenate([first.traj_mask, extra.traj_mask]),
                 np.concatenate([first.speed, extra.speed]), np.concatenate([first.vclass, extra.vclass]),
                 first.net, first.time, meta)
