"""Pictures of scenes (OpenCV): the map, boxes in green, trajectories from pink (past) to blue
(future), token agents circled in orange — the style of the paper's figures.

    img = draw_scene(net, scene, pixels=400, title="ground truth")    # BGR uint8
    cv2.imwrite("scene.png", img)
    cv2.imwrite("sheet.png", contact_sheet([[img_a, img_b], [img_c, img_d]]))
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from ..core.geometry import box_corners, metres_to_pixels
from .raster import MAP_CHANNELS, RasterConfig, render_map

_SHIFT = 4
PAST, FUTURE = np.array([203, 102, 255.0]), np.array([230, 130, 30.0])  # BGR pink -> blue
BOX, TOKEN = (60, 200, 60), (0, 150, 255)


def _px(xy, cfg: RasterConfig) -> np.ndarray:
    return np.round(metres_to_pixels(xy, cfg.size, cfg.shape) * (1 << _SHIFT)).astype(np.int32)


def map_background(net, window, cfg: RasterConfig) -> np.ndarray:
    """Grey drivable area, darker junctions, light sidewalks, white lane centre lines, red stop lines."""
    m = render_map(net, window, cfg)
    ch = {name: m[i] for i, name in enumerate(MAP_CHANNELS)}
    img = np.full(cfg.shape + (3,), 245, np.uint8)
    img[ch["sidewalk"] > 0] = (225, 225, 225)
    img[ch["crossing"] > 0] = (200, 200, 200)
    img[ch["drivable"] > 0] = (150, 150, 150)
    img[ch["junction"] > 0] = (130, 130, 130)
    img[ch["centerline"] > 0] = (235, 235, 235)
    img[ch["stop_line"] > 0] = (60, 60, 220)
    return img


def draw_scene(net, scene, pixels: int = 400, token_xy: np.ndarray | None = None,
               title: str = "") -> np.ndarray:
    """The scene on its map, ``pixels`` square. ``token_xy``: scene-frame points to circle."""
    cfg = RasterConfig(size=scene.window.size, pixels=pixels)
    img = map_background(net, scene.window, cfg)
    for i in range(len(scene)):
        pts = scene.traj[i, scene.traj_mask[i], :2]
        pix = _px(pts, cfg)
        n = len(pix)
        for k in range(n - 1):
            c = PAST + (FUTURE - PAST) * (k / max(n - 2, 1))
            cv2.line(img, tuple(pix[k]), tuple(pix[k + 1]), tuple(int(v) for v in c), 2, cv2.LINE_AA, _SHIFT)
        b = scene.boxes[i]
        corners = _px(box_corners(*b), cfg)
        cv2.fillPoly(img, [corners], BOX, cv2.LINE_AA, _SHIFT)
        front = _px(np.array([b[0], b[1]]) + 0.5 * b[3] * np.array([np.cos(b[2]), np.sin(b[2])]), cfg)
        cv2.line(img, tuple(_px(b[:2], cfg)), tuple(front), (20, 90, 20), 1, cv2.LINE_AA, _SHIFT)
    if token_xy is not None:
        radius = int(round(4.0 / cfg.metres_per_pixel)) << _SHIFT
        for p in _px(np.asarray(token_xy).reshape(-1, 2), cfg):
            cv2.circle(img, tuple(p), radius, TOKEN, 2, cv2.LINE_AA, _SHIFT)
    if title:
        cv2.putText(img, title, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def contact_sheet(rows: Sequence[Sequence[np.ndarray]], gap: int = 4) -> np.ndarray:
    """Tile equally sized images into a grid with white gaps."""
    h, w = rows[0][0].shape[:2]
    ncol = max(len(r) for r in rows)
    sheet = np.full((len(rows) * (h + gap) - gap, ncol * (w + gap) - gap, 3), 255, np.uint8)
    for r, row in enumerate(rows):
        for c, img in enumerate(row):
            sheet[r * (h + gap): r * (h + gap) + h, c * (w + gap): c * (w + gap) + w] = img
    return sheet
