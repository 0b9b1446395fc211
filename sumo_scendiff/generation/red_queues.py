"""A queue at a red light stands: the lights a scene is drawn for, held by its vehicles.

    scene = stand_at_red(scene, net, lights)      # lights: tls id -> SUMO state string

The diffusion model draws the vehicles before a red stop line over slow speeds, where SUMO's queue
stands (docs/evaluation.md, "Traffic lights": a share of them at 0.5-4 m/s where SUMO has few);
its decoder carries the queues, its sampler smears them. Given the lights
(``--signals``), the vehicles that form a queue at a red light are made to stand: on a lane whose
every link shows red (or red-amber), from the stop line back, each vehicle slower than CREEP, up to
the first that is faster (one approaching the queue: it and those behind it keep their motion, the
seeder brings them to a safe speed). SUMO's own vehicles near a red line either stand or approach
faster: at 0.5-4 m/s there are 3 % of them. A vehicle made to stand stands from -1 s on (SUMO's
speed at t = 0 is its last second's displacement): its poses from then are its pose now; its -2 s
pose is the model's.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..core.geometry import T0
from ..core.scene import Scene, speeds_from_traj
from ..map.signals import lane_lights

CREEP = 4.0        # m/s: slower than this at t = 0, a vehicle in a red queue is standing in it


def red_lanes(net, lights: dict[str, str]) -> set[int]:
    """The lanes (Network.lanes indices) whose every link to the next edge shows red now."""
    return {lane for lane, kind in lane_lights(net, lights).items() if kind == "red"}


def stand_at_red(scene: Scene, net, lights: dict[str, str] | None) -> Scene:
    """``scene`` with its red queues standing (module docstring); ``meta["stood_at_red"]``, per
    agent, whether it was made to stand (a per-agent list: ``Scene.select`` keeps it aligned)."""
    if not lights or not len(scene):
        return scene
    red = red_lanes(net, lights)
    if not red:
        return scene
    w = scene.window
    xy = w.scene_to_world(scene.boxes[:, :2].astype(np.float64))
    yaw = np.asarray(w.yaw_to_world(scene.boxes[:, 2].astype(np.float64)))
    m = net.match_poses(xy, yaw, allow_internal=False)
    length = scene.boxes[:, 3].astype(np.float64)
    speed = scene.speed[:, T0].astype(np.float64)
    by_lane: dict[int, list[tuple[float, int]]] = {}
    for i, lane in enumerate(m.lane):
        if int(lane) in red:
            front = m.pos[i] + 0.5 * length[i]
            by_lane.setdefault(int(lane), []).append((net.lanes[int(lane)].length - front, i))
    stood = []
    for cars in by_lane.values():
        for _, i in sorted(cars):                  # from the stop line back
            if speed[i] >= CREEP:
                break
            stood.append(i)
    if not stood:
        return scene
    traj = scene.traj.copy()
    k = np.asarray(stood)
    traj[k, T0 - 1:] = traj[k, T0:T0 + 1]
    meta = {**scene.meta, "stood_at_red": [bool(i in set(stood)) for i in range(len(scene))]}
    return replace(scene, traj=traj, speed=speeds_from_traj(traj, scene.traj_mask), meta=meta)


__all__ = ["CREEP", "red_lanes", "stand_at_red"]
