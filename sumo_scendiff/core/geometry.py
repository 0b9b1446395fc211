"""Frames, SUMO angle / front-bumper conversions, windows and the metre <-> pixel map.

This is the one place where the project's fixed conventions (see DESIGN.md) live:

* world frame: SUMO network coordinates in metres, x east, y north;
* heading ("yaw"): radians, counter-clockwise from +x, wrapped to (-pi, pi];
  SUMO's vehicle angle is degrees clockwise from north: ``yaw = radians(90 - angle)``;
* SUMO reports a vehicle's *front bumper* middle; box centre = front - length/2 * (cos yaw, sin yaw);
* a :class:`Window` has a centre, a yaw and a side; the scene frame is the window frame
  (x forward along the window yaw, y to the left);
* raster: row 0 is the window's +y edge, column 0 its -x edge, pixel size = side / H.
  :func:`metres_to_pixels` / :func:`pixels_to_metres` are the only metre <-> pixel conversions.

Everything is vectorised over numpy arrays; scalars work too.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

TIMES = (-2.0, -1.0, 0.0, 1.0, 2.0)  # trajectory time stamps (s); index 2 is the box (t = 0)
T0 = 2  # index of t = 0 in TIMES
T_FINAL = TIMES.index(2.0)  # index of t = +2 s (the "final" speed and pose)


def wrap_angle(a):
    """Wrap angles (radians) to (-pi, pi]."""
    a = np.asarray(a, dtype=np.float64)
    w = np.mod(a + np.pi, 2.0 * np.pi) - np.pi  # [-pi, pi)
    return np.where(w <= -np.pi, w + 2.0 * np.pi, w)


def sumo_angle_to_yaw(angle_deg):
    """SUMO vehicle angle (degrees, clockwise from north) -> yaw (radians, CCW from +x)."""
    return wrap_angle(np.radians(90.0 - np.asarray(angle_deg, dtype=np.float64)))


def yaw_to_sumo_angle(yaw):
    """Yaw (radians, CCW from +x) -> SUMO angle in degrees, clockwise from north, in [0, 360)."""
    return np.mod(90.0 - np.degrees(np.asarray(yaw, dtype=np.float64)), 360.0)


def front_to_center(x, y, yaw, length):
    """SUMO front-bumper position -> box centre (same frame)."""
    return x - 0.5 * length * np.cos(yaw), y - 0.5 * length * np.sin(yaw)


def center_to_front(x, y, yaw, length):
    """Box centre -> SUMO front-bumper position (same frame)."""
    return x + 0.5 * length * np.cos(yaw), y + 0.5 * length * np.sin(yaw)


def box_corners(x, y, yaw, length, width):
    """Corners of oriented boxes, shape (..., 4, 2): front-left, rear-left, rear-right, front-right."""
    x, y, yaw, length, width = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64)
                                                     for v in (x, y, yaw, length, width)))
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])  # (4, 2) in (l, w) units
    lx = local[:, 0] * hl[..., None]
    ly = local[:, 1] * hw[..., None]
    cx = x[..., None] + c[..., None] * lx - s[..., None] * ly
    cy = y[..., None] + s[..., None] * lx + c[..., None] * ly
    return np.stack([cx, cy], axis=-1)


OVERLAP_AREA = 0.01   # m^2: two boxes sharing more than this overlap


def box_polygons(boxes) -> np.ndarray:
    """Boxes (N, >= 5: x, y, yaw, length, width, ...) as an (N,) array of shapely polygons."""
    if not len(boxes):
        return np.zeros(0, dtype=object)
    b = np.asarray(boxes, np.float64)
    return shapely.polygons(box_corners(b[:, 0], b[:, 1], b[:, 2], b[:, 3], b[:, 4]))


@dataclass(frozen=True)
class Window:
    """A square bird's-eye-view window: centre and yaw in world coordinates, side in metres."""

    cx: float
    cy: float
    yaw: float = 0.0
    size: float = 100.0

    def world_to_scene(self, xy):
        """World points (..., 2) -> scene frame (x along the window yaw, y to its left)."""
        xy = np.asarray(xy, dtype=np.float64)
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        dx, dy = xy[..., 0] - self.cx, xy[..., 1] - self.cy
        return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)

    def scene_to_world(self, xy):
        """Scene-frame points (..., 2) -> world coordinates."""
        xy = np.asarray(xy, dtype=np.float64)
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.stack([self.cx + c * xy[..., 0] - s * xy[..., 1],
                         self.cy + s * xy[..., 0] + c * xy[..., 1]], axis=-1)

    def yaw_to_scene(self, yaw):
        return wrap_angle(np.asarray(yaw, dtype=np.float64) - self.yaw)

    def yaw_to_world(self, yaw):
        return wrap_angle(np.asarray(yaw, dtype=np.float64) + self.yaw)

    def contains(self, xy_scene, margin: float = 0.0):
        """Whether scene-frame points lie inside the window (shrunk by ``margin`` metres)."""
        xy = np.asarray(xy_scene, dtype=np.float64)
        h = 0.5 * self.size - margin
        return (np.abs(xy[..., 0]) <= h) & (np.abs(xy[..., 1]) <= h)

    def world_bounds(self):
        """Axis-aligned world bounding box (xmin, ymin, xmax, ymax) of the (rotated) window."""
        h = 0.5 * self.size
        corners = self.scene_to_world(np.array([[h, h], [-h, h], [-h, -h], [h, -h]]))
        return (*corners.min(axis=0), *corners.max(axis=0))

    def as_tuple(self):
        return (float(self.cx), float(self.cy), float(self.yaw), float(self.size))


def metres_to_pixels(xy_scene, size: float, shape):
    """Scene-frame metres (..., 2) -> continuous pixel coordinates (..., 2) as (col, row).

    ``shape`` is (H, W). Pixel (col, row) has its centre at integer coordinates (OpenCV's convention),
    row 0 is the window's +y edge and column 0 its -x edge.
    """
    h, w = shape
    xy = np.asarray(xy_scene, dtype=np.float64)
    col = (xy[..., 0] + 0.5 * size) * (w / size) - 0.5
    row = (0.5 * size - xy[..., 1]) * (h / size) - 0.5
    return np.stack([col, row], axis=-1)


def pixels_to_metres(colrow, size: float, shape):
    """Inverse of :func:`metres_to_pixels`: (col, row) pixel coordinates -> scene-frame metres."""
    h, w = shape
    cr = np.asarray(colrow, dtype=np.float64)
    x = (cr[..., 0] + 0.5) * (size / w) - 0.5 * size
    y = 0.5 * size - (cr[..., 1] + 0.5) * (size / h)
    return np.stack([x, y], axis=-1)


def pixel_centres(size: float, shape):
    """Scene-frame metres of every pixel centre, shape (H, W, 2)."""
    h, w = shape
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    return pixels_to_metres(np.stack([cols, rows], axis=-1), size, shape)


def sumo_to_pose(x_front, y_front, angle_deg, length):
    """What SUMO reports (front-bumper middle, angle in degrees clockwise from north) -> box centre
    and yaw: ``(cx, cy, yaw)``. The only place the recorder and the seeder convert SUMO poses."""
    yaw = sumo_angle_to_yaw(angle_deg)
    cx, cy = front_to_center(np.asarray(x_front, np.float64), np.asarray(y_front, np.float64), yaw, length)
    return cx, cy, yaw


def pose_to_sumo(cx, cy, yaw, length):
    """Box centre and yaw -> what SUMO takes: ``(x_front, y_front, angle_deg)``."""
    fx, fy = center_to_front(np.asarray(cx, np.float64), np.asarray(cy, np.float64), yaw, length)
    return fx, fy, yaw_to_sumo_angle(yaw)
