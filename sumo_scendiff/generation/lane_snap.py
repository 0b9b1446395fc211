"""Lane snapping: generated poses onto the centre lines of the network's car lanes.

    boxes, traj, snapped = snap_to_lanes(boxes, traj, window, net)   # scene frame in and out

SUMO's own traffic, which the model learns from, drives on lane centre lines (the recorder runs
without the sublane model), heading along the lane. Decoded poses scatter around those lines
(docs/history.md, item 16, has the measurements), which puts a box's corner or a future waypoint off
the road and tilts it against its lane. Every pose (the box at t = 0 and each trajectory pose) that has a car lane
within ``radius`` m agreeing with its yaw within ``max_angle`` moves to the nearest point of that
lane's centre line and takes the lane's heading there; the lane is the one SUMO seeding would choose
(:meth:`~sumo_scendiff.map.network.Network.match_poses`, the same rule as ``Network.lookup``). A pose with
no such lane (off the road, or against every lane) is left as decoded.

A trajectory pose that finds no such lane of its own (a turn cut short, a waypoint beyond the lane's
end) but follows a snapped one is driven there through the lane graph: from the neighbouring pose's
lane and position, the decoded step length ahead (or back, for the past) along every branch of
successor (predecessor) lanes, the branch ending nearest the decoded pose taken
(:func:`walk_lanes`). Such poses lie 5-10 m from every branch (median 6.4 m on cologne3): the
decoder drew a turn the lane does not make, or a path across the corner; the step length, and so the
speed, is kept.

For an agent that stands still (all its poses within ``STILL`` m of the current one), the trajectory
takes the current pose's snapped point: overlapping internal lanes of a junction must not turn one
standing car into a moving one.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..core.geometry import T0, Window

if TYPE_CHECKING:
    from ..map.network import Network

SNAP_RADIUS = 3.0        # m: as far as seeding looks for a vehicle's lane (Network.lookup)
SNAP_MAX_ANGLE = np.pi / 3
GIVEN_MAX_ANGLE = 0.2    # rad: an agent whose heading a token gave keeps to lanes this close to it
STILL = 0.5              # m: an agent whose poses all lie this close to t = 0 stands still
FOLLOW_DEPTH = 6         # lane-graph edges a walk may cross (junction-internal lanes are short)


def walk_lanes(net: "Network", lane: int, pos: float, d: float, depth: int = FOLLOW_DEPTH
               ) -> list[tuple[int, float]]:
    """Every ``(lane, pos)`` reached by driving ``d`` m from ``pos`` on ``lane`` (negative ``d``:
    backwards) through :attr:`~sumo_scendiff.map.network.Network.successors` (``predecessors``), one per
    branch; where the network ends, or after ``depth`` lanes, the last point reached."""
    length = net.lines[lane].length
    end = pos + d
    if 0.0 <= end <= length:
        return [(lane, end)]
    nxt = net.successors[lane] if end > length else net.predecessors[lane]
    if depth == 0 or not nxt:
        return [(lane, min(max(end, 0.0), length))]
    if end > length:
        return [r for j in nxt for r in walk_lanes(net, j, 0.0, end - length, depth - 1)]
    return [r for j in nxt for r in walk_lanes(net, j, net.lines[j].length, end, depth - 1)]


def snap_to_lanes(boxes: np.ndarray, traj: np.ndarray, window: Window, net: "Network",
                  radius: float = SNAP_RADIUS, max_angle: float = SNAP_MAX_ANGLE,
                  given: np.ndarray | None = None, exact: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes (N, 5: x, y, yaw, length, width) and trajectories (N, T, 3: x, y, yaw) of one scene
    (``window``'s frame) with their poses moved onto lane centre lines. ``given`` (N,) marks agents
    whose heading a token stated (:func:`~sumo_scendiff.generation.pinning.turn_to_pins`): their poses take a
    lane within ``GIVEN_MAX_ANGLE`` of it where there is one, even past a nearer lane that turns
    away (inside a junction the lanes overlap). ``exact`` (N,), a subset of ``given``: agents whose
    pose at t = 0 a user's token stated (:mod:`.deliver`): that pose moves only onto a lane within
    ``GIVEN_MAX_ANGLE`` of it, and where there is none it stays as stated instead of taking a lane
    that turns away (a vehicle half through a junction turn, its nose already on the next edge,
    has a centre on no lane's centre line and a heading between the lanes'). Returns new arrays
    (the box pose is the trajectory's t = 0 pose) and which poses moved (N, T)."""
    boxes, traj = np.array(boxes, np.float64), np.array(traj, np.float64)
    n, t = traj.shape[:2]
    if n == 0:
        return boxes, traj, np.zeros((n, t), bool)
    xy = window.scene_to_world(traj[..., :2].reshape(-1, 2))
    yaw = window.yaw_to_world(traj[..., 2].reshape(-1))
    m = net.match_poses(xy, yaw, radius=radius, max_angle=max_angle)
    if given is not None and np.any(given):                        # only the given agents' poses
        rows = np.flatnonzero(np.repeat(np.asarray(given, bool), t))
        strict = net.match_poses(xy[rows], yaw[rows], radius=radius, max_angle=GIVEN_MAX_ANGLE)
        found = strict.lane >= 0
        for f in ("lane", "pos", "lateral", "heading", "xy", "heading_diff"):
            getattr(m, f)[rows[found]] = getattr(strict, f)[found]
        if exact is not None and np.any(exact):
            # the stated t = 0 poses with no lane along their heading: left where the token put them
            t0 = rows % t == T0
            held = rows[t0 & ~found & np.repeat(np.asarray(exact, bool), t)[rows]]
            m.lane[held] = -1
            m.xy[held] = xy[held]
    snapped = (m.lane >= 0).reshape(n, t)
    lane, pos = m.lane.reshape(n, t).copy(), m.pos.reshape(n, t).copy()
    w_xy, w_yaw = m.xy.reshape(n, t, 2).copy(), m.heading.reshape(n, t).copy()
    dec = xy.reshape(n, t, 2)
    step = np.linalg.norm(np.diff(dec, axis=1), axis=-1)            # (N, T-1) decoded step lengths
    for a in np.flatnonzero(snapped[:, T0] & ~snapped.all(1)):
        for k in [*range(T0 + 1, t), *range(T0 - 1, -1, -1)]:      # outwards from t = 0
            ref = k - 1 if k > T0 else k + 1
            if snapped[a, k] or not snapped[a, ref]:
                continue
            d = step[a, min(k, ref)] * (1.0 if k > T0 else -1.0)
            best = min(((np.linalg.norm(p_xy - dec[a, k]), ln, p, p_xy, h) for ln, p in
                        walk_lanes(net, int(lane[a, ref]), float(pos[a, ref]), d)
                        for p_xy, h in [net.lane_pose(ln, p)]), key=lambda c: c[0])
            _, lane[a, k], pos[a, k], w_xy[a, k], w_yaw[a, k] = best
            snapped[a, k] = True
    new_xy = window.world_to_scene(w_xy.reshape(-1, 2)).reshape(n, t, 2)
    new_yaw = window.yaw_to_scene(w_yaw).reshape(n, t)
    traj[..., :2] = np.where(snapped[..., None], new_xy, traj[..., :2])
    traj[..., 2] = np.where(snapped, new_yaw, traj[..., 2])
    still = (np.linalg.norm(dec - dec[:, T0:T0 + 1], axis=-1) <= STILL).all(1) & snapped[:, T0]
    traj[still] = traj[still, T0:T0 + 1]
    snapped[still] = True
    boxes[:, :3] = traj[:, T0]
    return boxes, traj, snapped
