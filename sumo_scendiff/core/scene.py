"""Scenes: the sparse representation of agents in one window (boxes + -2..+2 s poses).

A :class:`Scene` stores every array in the *scene frame* of its window (x along the window yaw,
y to the left, metres, radians). Array shapes, for N agents:

* ``boxes``     (N, 5)    x, y, yaw, length, width of the box at t = 0
* ``traj``      (N, 5, 3) x, y, yaw of the box centre at t = -2, -1, 0, +1, +2 s
* ``traj_mask`` (N, 5)    whether the pose at that time was observed
* ``speed``     (N, 5)    speed (m/s) at those times (0 where unobserved)
* ``vclass``    (N,)      index into :data:`VEHICLE_CLASSES`
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .geometry import T0, TIMES, Window, wrap_angle

VEHICLE_CLASSES = ("passenger", "delivery", "truck", "bus", "motorcycle")
FORMAT_VERSION = 1


def vclass_from_size(length, width) -> np.ndarray:
    """A vehicle class index fitting a box: motorcycle < 2.8 m or < 1.2 m wide, van up to 7.5 m,
    truck up to 11 m, bus beyond; passenger car otherwise."""
    length, width = np.asarray(length, np.float64), np.asarray(width, np.float64)
    out = np.zeros(length.shape, np.int8)
    out[(length >= 5.5) & (length < 7.5)] = VEHICLE_CLASSES.index("delivery")
    out[(length >= 7.5) & (length < 11.0)] = VEHICLE_CLASSES.index("truck")
    out[length >= 11.0] = VEHICLE_CLASSES.index("bus")
    out[(length < 2.8) | (width < 1.2)] = VEHICLE_CLASSES.index("motorcycle")
    return out


def per_km(count: float, km: float | None) -> float | None:
    """Vehicles per km of car lane, the product's density: ``count`` over a window's ``km``; None
    for a window without car lane (no density, whatever the count)."""
    return count / km if km is not None and km > 0 else None


@dataclass
class Scene:
    window: Window
    boxes: np.ndarray
    traj: np.ndarray
    traj_mask: np.ndarray
    speed: np.ndarray
    vclass: np.ndarray
    net: str = ""
    time: float = 0.0
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        n = len(self.boxes)
        self.boxes = np.asarray(self.boxes, dtype=np.float32).reshape(n, 5)
        self.traj = np.asarray(self.traj, dtype=np.float32).reshape(n, len(TIMES), 3)
        self.traj_mask = np.asarray(self.traj_mask, dtype=bool).reshape(n, len(TIMES))
        self.speed = np.asarray(self.speed, dtype=np.float32).reshape(n, len(TIMES))
        self.vclass = np.asarray(self.vclass, dtype=np.int8).reshape(n)

    def __len__(self):
        return len(self.boxes)

    @classmethod
    def empty(cls, window: Window, **kw) -> "Scene":
        return cls(window, np.zeros((0, 5)), np.zeros((0, len(TIMES), 3)),
                   np.zeros((0, len(TIMES)), bool), np.zeros((0, len(TIMES))), np.zeros(0), **kw)

    def velocities(self) -> np.ndarray:
        """(N, 2) velocity vectors at t = 0 in the scene frame (speed along the box heading)."""
        yaw = self.boxes[:, 2]
        return np.stack([np.cos(yaw), np.sin(yaw)], -1) * self.speed[:, T0:T0 + 1]

    def select(self, keep) -> "Scene":
        """A new scene with only the agents where ``keep`` (bool mask or indices) selects;
        per-agent lists in ``meta`` (e.g. the generator's scores) are selected with them."""
        idx = np.arange(len(self))[keep]
        meta = {k: ([v[i] for i in idx] if isinstance(v, list) and len(v) == len(self) else v)
                for k, v in self.meta.items()}
        return Scene(self.window, self.boxes[keep], self.traj[keep], self.traj_mask[keep],
                     self.speed[keep], self.vclass[keep], self.net, self.time, meta)

    def world_agents(self) -> list[dict]:
        """Agents in world coordinates (centre, heading, size, speed, the five poses)."""
        w = self.window
        out = []
        for i in range(len(self)):
            xy = w.scene_to_world(self.boxes[i, :2])
            poses = w.scene_to_world(self.traj[i, :, :2])
            yaws = w.yaw_to_world(self.traj[i, :, 2])
            out.append({
                "x": float(xy[0]), "y": float(xy[1]),
                "heading": float(w.yaw_to_world(self.boxes[i, 2])),
                "length": float(self.boxes[i, 3]), "width": float(self.boxes[i, 4]),
                "speed": float(self.speed[i, T0]),
                "vclass": VEHICLE_CLASSES[int(self.vclass[i])],
                "poses": [{"t": t, "x": float(p[0]), "y": float(p[1]), "heading": float(h),
                           "observed": bool(m), "speed": float(v)}
                          for t, p, h, m, v in zip(TIMES, poses, yaws, self.traj_mask[i], self.speed[i])],
            })
        return out

    def to_json(self) -> dict:
        return {"format_version": FORMAT_VERSION, "net": self.net, "time": self.time,
                "window": dict(zip(("cx", "cy", "yaw", "size"), self.window.as_tuple())),
                "agents": self.world_agents(), "meta": self.meta}

    @classmethod
    def from_json(cls, d: dict) -> "Scene":
        if d.get("format_version") != FORMAT_VERSION:
            raise ValueError(f"unsupported scene format_version {d.get('format_version')!r}")
        w = Window(**d["window"])
        ag = d["agents"]
        n = len(ag)
        boxes = np.zeros((n, 5))
        traj = np.zeros((n, len(TIMES), 3))
        mask = np.zeros((n, len(TIMES)), bool)
        speed = np.zeros((n, len(TIMES)))
        vclass = np.zeros(n, int)
        for i, a in enumerate(ag):
            boxes[i, :2] = w.world_to_scene([a["x"], a["y"]])
            boxes[i, 2:] = (w.yaw_to_scene(a["heading"]), a["length"], a["width"])
            for k, p in enumerate(a["poses"]):
                traj[i, k, :2] = w.world_to_scene([p["x"], p["y"]])
                traj[i, k, 2] = w.yaw_to_scene(p["heading"])
                mask[i, k], speed[i, k] = p["observed"], p["speed"]
            vclass[i] = VEHICLE_CLASSES.index(a["vclass"])
        return cls(w, boxes, traj, mask, speed, vclass, d.get("net", ""), d.get("time", 0.0),
                   d.get("meta", {}))

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=1)


def rotate_scene(scene: Scene, angle: float) -> Scene:
    """The same agents seen from a window rotated by ``angle`` (radians) about its centre."""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, s], [-s, c]], dtype=np.float32)  # world->scene for the rotated window
    boxes = scene.boxes.copy()
    boxes[:, :2] = scene.boxes[:, :2] @ rot.T
    boxes[:, 2] = wrap_angle(boxes[:, 2] - angle)
    traj = scene.traj.copy()
    traj[..., :2] = scene.traj[..., :2] @ rot.T
    traj[..., 2] = wrap_angle(traj[..., 2] - angle)
    w = scene.window
    win = Window(w.cx, w.cy, float(wrap_angle(w.yaw + angle)), w.size)
    return Scene(win, boxes, traj, scene.traj_mask, scene.speed, scene.vclass, scene.net, scene.time,
                 dict(scene.meta))


def crop_to_window(scene: Scene) -> Scene:
    """Only the agents whose box centre lies inside the window square (e.g. after :func:`rotate_scene`,
    which turns the square and leaves some agents of the old one outside)."""
    return scene.select(scene.window.contains(scene.boxes[:, :2]))


def speeds_from_traj(traj: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N, 5) speeds at t = -2..+2 from 1-s poses, in SUMO's convention.

    SUMO moves a vehicle by its *new* speed each step (the Euler update, and the recorder's
    ``--step-length 1``), so ``v(t) = |p(t) - p(t-1)|`` exactly: on recorded trajectories it is off
    by 0.02 m/s, where a central difference is off by 0.22-0.35 m/s and a forward one by 0.4-0.7.
    At t = -2 (no earlier pose) the speed is extrapolated at constant acceleration,
    ``2 v(-1) - v(0)``; a step whose earlier pose is unobserved takes the next step's speed.
    """
    p = traj[..., :2]
    step = np.linalg.norm(np.diff(p, axis=1), axis=-1)           # (N, 4): v(-1), v(0), v(+1), v(+2)
    both = mask[:, 1:] & mask[:, :-1]                             # the step's two poses observed
    v = np.zeros(mask.shape, np.float32)
    v[:, 1:] = np.where(both, step, 0.0)
    v[:, 0] = np.where(both[:, 1], np.maximum(2.0 * step[:, 0] - step[:, 1], 0.0), step[:, 0])
    for t in range(1, v.shape[1] - 1):                            # a first observed pose: the next step
        v[:, t] = np.where(~both[:, t - 1] & both[:, t], step[:, t], v[:, t])
    return v * mask
