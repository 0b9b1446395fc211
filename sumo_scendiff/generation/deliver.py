"""Delivered tokens: what a user's token gives is what SUMO gets, for a token that is not pinned.

    rows = delivered_rows(tokens)                               # (D, 10): the positioned partial tokens
    pairs = match_rows(boxes, rows, radius, taken)              # generated agent <-> token
    boxes, traj, turned, v = apply_rows(boxes, traj, rows, pairs)   # before lane snap
    traj, lines = pace_rows(traj, v, window, net, owner)        # again after it (and the turn)
    boxes, traj, owner, gone, lines = place_rows(boxes, traj, owner, rows, window, net)  # the unmatched

A pinned token (pose, size and speed: :mod:`.pinning`) is drawn into the latent. A partial one is a
condition only, and the model follows it loosely: asked for 12 m/s it draws the typical speed, and
it never draws a stop (docs/tokens.md, "Delivered tokens"). So the generated agent matched one-to-one
to a positioned partial token (centre within the pins' radius, :func:`~sumo_scendiff.core.matching.assign`)
takes what the token gives: its position, its heading (turned rigidly, as
:func:`~.pinning.turn_to_pins`; lane snap keeps a stated pose no lane runs along,
``lane_snap.snap_to_lanes``' ``exact``), its length and width, and its speed and final speed along
the path the model drew (:func:`~.pinning.pace_to_pins`' re-timing), its future the token's turn
(:func:`turn_path`: the arc, else along the lane graph, else a change of lanes; a warning line where
no lane turns so); what the token does not give stays the model's. A positioned token no generated
agent matches is placed by :func:`place_rows` on the car lane at its position, unless it lies on no
car lane (a warning line, never a silent drop).
"""
from __future__ import annotations

import logging
from typing import Mapping, Sequence

import numpy as np
import shapely

from ..core.geometry import T0, TIMES, Window, box_polygons, wrap_angle
from ..core.matching import assign
from ..core.scene import speeds_from_traj
from ..tokens.encoding import MIN_DISPLACEMENT
from ..tokens.features import is_pinnable
from .lane_snap import GIVEN_MAX_ANGLE, SNAP_MAX_ANGLE, SNAP_RADIUS, walk_lanes
from .pinning import _arc, _distance, match_pins, retime

log = logging.getLogger(__name__)

# a token without a size is placed as the fleet's typical car (data/demand.py VEHICLE_MIX "car")
CAR_LENGTH, CAR_WIDTH = 4.6, 1.8
# columns of a row: the token's index in its list, then its features (NaN: not given)
COLUMNS = ("index", "x", "y", "heading", "length", "width", "speed", "final_speed", "heading_to_final")


def _given(t: Mapping, f: str) -> float:
    v = t.get(f)
    return np.nan if v is None or not np.isfinite(float(v)) else float(v)


def delivered_rows(tokens: Sequence | None, pinned: bool = False) -> np.ndarray:
    """(D, 9) rows (:data:`COLUMNS`) of the token dicts of one window that give a position but are
    not pinnable (``pinned``: those that are, instead): the pinned ones have their own path
    (:mod:`.pinning`), and a token without a position names no vehicle of its own."""
    rows = [[float(i)] + [_given(t, f) for f in COLUMNS[1:]] for i, t in enumerate(tokens or ())
            if isinstance(t, Mapping) and is_pinnable(t) == pinned
            and t.get("x") is not None and t.get("y") is not None]
    return np.array(rows, np.float64).reshape(-1, len(COLUMNS))


def missing_pins(tokens: Sequence | None, boxes: np.ndarray, radius: float) -> np.ndarray:
    """The rows (:data:`COLUMNS`) of the pinned tokens no agent of the finished scene (``boxes``,
    scene frame) stands for, for :func:`place_rows`: the decoder may not find a pinned agent above
    the threshold (its latent is the token's as drawn, off the centre lines the model learnt), or a
    more probable box it overlaps once snapped onto its lane wins; without this it was lost silently."""
    rows = delivered_rows(tokens, pinned=True)
    found = {p for _, p in match_pins(boxes, rows[:, 1:3], radius)}
    return rows[[k for k in range(len(rows)) if k not in found]]


def match_rows(boxes: np.ndarray, rows: np.ndarray, radius: float, taken: np.ndarray | None = None
               ) -> list[tuple[int, int]]:
    """(agent, row) pairs: generated agents (N, 5) not ``taken`` (by a pinned token) matched
    one-to-one to the rows by centre distance within ``radius`` m."""
    if len(boxes) == 0 or len(rows) == 0:
        return []
    d = np.linalg.norm(np.asarray(boxes)[:, None, :2] - rows[None, :, 1:3], axis=-1)
    ok = d <= radius
    if taken is not None:
        ok &= ~np.asarray(taken, bool)[:, None]
    a, r = assign(d, ok)
    return [(int(i), int(j)) for i, j in zip(a, r)]


def _speeds(traj: np.ndarray, row: np.ndarray) -> tuple[float, float]:
    """The (speed, final speed) an agent is paced to: the token's where it gives them; else the
    drawn one, a drawn change of speed kept when only the speed is given (as pace_to_pins). A token
    giving ``heading_to_final`` says the vehicle moves (it is defined only for a displacement of at
    least MIN_DISPLACEMENT in 2 s, tokens/encoding.py): a drawn final speed that would leave it
    standing is raised to cover that distance."""
    v = speeds_from_traj(traj[None], np.ones((1, len(TIMES)), bool))[0]
    v0, v2 = row[6], row[7]
    if not np.isfinite(v0):
        v0 = float(v[T0])
    if not np.isfinite(v2):
        v2 = max(v0 + float(v[-1] - v[T0]), 0.0) if np.isfinite(row[6]) else float(v[-1])
        if np.isfinite(row[8]):
            v2 = _moving(float(v0), float(v2))
    return float(v0), float(v2)


def _moving(v0: float, v2: float) -> float:
    """The least final speed >= ``v2`` whose 2 s from ``v0`` cover MIN_DISPLACEMENT: a token giving
    ``heading_to_final`` says the vehicle moves (tokens/encoding.py)."""
    t = np.asarray(TIMES)
    while _distance(v0, (v2 - v0) / 2.0, t)[-1] < MIN_DISPLACEMENT:   # distance grows with v2
        v2 += 0.1
    return v2


def apply_rows(boxes: np.ndarray, traj: np.ndarray, rows: np.ndarray, pairs: list[tuple[int, int]]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each matched agent takes its token's position (its drawn path moved rigidly there), heading
    (turned rigidly about its pose), size, and speeds along its drawn path, its future turned by the
    token's ``heading_to_final``. Returns new boxes and traj, which agents' heading a token gave (N,)
    and the (N, 4) speed, final speed, heading_to_final (NaN: not given) they were paced to (NaN:
    not paced) and whether the token gave that final speed (1), for :func:`pace_rows` after lane snap."""
    boxes, traj = np.array(boxes, np.float64), np.array(traj, np.float64)
    turned = np.zeros(len(boxes), bool)
    speeds = np.full((len(boxes), 4), np.nan)
    t = np.asarray(TIMES)
    for a, r in pairs:
        row = rows[r]
        # the token's position: the user said where (the model drew it within the match radius)
        traj[a, :, :2] += row[1:3] - traj[a, T0, :2]
        if np.isfinite(row[3]):
            delta = float(wrap_angle(row[3] - traj[a, T0, 2]))
            c, s = np.cos(delta), np.sin(delta)
            rel = traj[a, :, :2] - traj[a, T0, :2]
            traj[a, :, :2] = traj[a, T0, :2] + rel @ np.array([[c, s], [-s, c]])
            traj[a, :, 2] = wrap_angle(traj[a, :, 2] + delta)
            turned[a] = True
        if np.isfinite(row[4]):
            boxes[a, 3:5] = row[4:6]
        if np.isfinite(row[6:9]).any():
            v0, v2 = _speeds(traj[a], row)
            s = _distance(v0, (v2 - v0) / 2.0, t)
            traj[a] = retime(traj[a], s)
            if np.isfinite(row[8]):
                x, y, h = traj[a, T0]
                traj[a, t > 0] = _arc(x, y, h, s, float(row[8]), t)[t > 0]
            speeds[a] = v0, v2, row[8], float(np.isfinite(row[7]))
        boxes[a, :3] = traj[a, T0]
    return boxes, traj, turned, speeds


def _on_lanes(net, window: Window, poses: np.ndarray) -> bool:
    """Whether every scene-frame pose (K, 3) has a car lane within lane snap's radius that agrees
    with its heading (lane snap's angle): a vehicle can drive there."""
    m = net.match_poses(window.scene_to_world(poses[:, :2]), window.yaw_to_world(poses[:, 2]),
                        radius=SNAP_RADIUS, max_angle=SNAP_MAX_ANGLE)
    return bool((m.lane >= 0).all())


TURN_TOLERANCE = 0.1   # rad: a path along the lanes whose +2 s direction is this close delivers the turn


def _scene_pose(net, window: Window, lane: int, pos: float) -> np.ndarray:
    xy, h = net.lane_pose(lane, pos)
    return np.r_[window.world_to_scene(np.asarray(xy, np.float64)[None])[0], window.yaw_to_scene(h)]


def _direction(pose: np.ndarray, end: np.ndarray) -> float:
    d = end[:2] - pose[:2]
    return float(wrap_angle(np.arctan2(d[1], d[0]) - pose[2]))


def turn_path(net, window: Window | None, pose: np.ndarray, v0: float, v2: float, alpha: float,
              free: bool) -> tuple[np.ndarray, float] | None:
    """The (T, 3) poses and final speed of a vehicle at scene-frame ``pose`` now, moving from ``v0``
    to ``v2`` m/s, whose +2 s displacement leaves at ``alpha`` to its heading (the token's
    ``heading_to_final``), on the car lanes (``net`` None: the arc, unchecked). In this order:

    1. the token's arc (:func:`~.pinning._arc`), every +1/+2 s pose within lane snap's radius of a
       lane along it;
    2. along the lane graph from the lane at ``pose``: the branch whose +2 s point lies within
       :data:`TURN_TOLERANCE` of that direction (a vehicle turning with the road: its heading at +2 s
       the lane's, not the arc's);
    3. a change of lanes: straight along that direction, the heading kept (SUMO, without the sublane
       model, moves a vehicle sideways by a lane's width in one step), ending within 1 m of the
       centre line of another lane along the heading.

    2 and 3 with a final speed the token does not give (``free``) also at lower final speeds, the
    highest that fits first (a vehicle slows into a turn), then at higher ones up to the faster of
    ``v0`` and the lane's limit (the drawn final speed may be slower than the turn asked needs).
    None where no path fits."""
    t = np.asarray(TIMES)
    s = _distance(v0, (v2 - v0) / 2.0, t)
    arc = _arc(*pose, s, alpha, t)
    if net is None or window is None or _on_lanes(net, window, arc[t > 0]):
        return arc, v2
    world = window.scene_to_world(np.asarray(pose, np.float64)[None, :2])
    here = net.match_poses(world, [window.yaw_to_world(pose[2])], radius=SNAP_RADIUS, max_angle=SNAP_MAX_ANGLE)
    if here.lane[0] < 0:
        return None
    lane0, pos0 = int(here.lane[0]), float(here.pos[0])
    top = max(v0, v2, net.lanes[lane0].speed)
    finals = [v2] + (list(np.arange(v2 - 0.5, 0.0, -0.5)) + [0.0] + list(np.arange(v2 + 0.5, top + 1e-9, 0.5))
                     if free else [])
    for v in finals:
        v = _moving(v0, float(v))
        s = _distance(v0, (v - v0) / 2.0, t)
        ends = [_scene_pose(net, window, ln, p) for ln, p in walk_lanes(net, lane0, pos0, float(s[-1]))]
        err = [abs(wrap_angle(_direction(pose, e) - alpha)) for e in ends]
        if ends and min(err) <= TURN_TOLERANCE:
            end = ends[int(np.argmin(err))]
            path = np.array(pose, np.float64)[None].repeat(len(t), 0)
            for k in np.flatnonzero(t > 0):
                cands = [_scene_pose(net, window, ln, p) for ln, p in walk_lanes(net, lane0, pos0, float(s[k]))]
                path[k] = min(cands, key=lambda c: np.linalg.norm(c[:2] - end[:2]))
            path[-1] = end
            return path, v
        chord = np.array([pose[0] + s[-1] * np.cos(pose[2] + alpha), pose[1] + s[-1] * np.sin(pose[2] + alpha)])
        m = net.match_poses(window.scene_to_world(chord[None]), [window.yaw_to_world(pose[2])],
                            radius=1.0, max_angle=GIVEN_MAX_ANGLE)
        if m.lane[0] >= 0 and int(m.lane[0]) != lane0:
            d = np.where(t > 0, pose[2] + alpha, pose[2])
            path = np.stack([pose[0] + s * np.cos(d), pose[1] + s * np.sin(d), np.full(len(t), pose[2])], 1)
            return path, v
    return None


def _straight_past(traj: np.ndarray, v0: float, v2: float) -> None:
    """Where the drawn past bends so sharply that its steps no longer give the speed now (a past the
    model drew from another direction than the token's heading, snapped onto that lane: the step
    from t = -1 to 0 cuts the corner), the past becomes straight behind the pose now along its
    heading at the token's speeds (as a pinned token's, :func:`~.pinning.token_trajectories`). In place."""
    t = np.asarray(TIMES)
    v = speeds_from_traj(traj[None], np.ones((1, len(t)), bool))[0]
    if abs(float(v[T0]) - v0) <= 0.05:
        return
    s = _distance(v0, (v2 - v0) / 2.0, t)
    x, y, h = traj[T0]
    past = t < 0
    traj[past] = np.stack([x + s[past] * np.cos(h), y + s[past] * np.sin(h), np.full(past.sum(), h)], 1)


def pace_rows(traj: np.ndarray, speeds: np.ndarray, window: Window | None = None, net=None,
              owner: np.ndarray | None = None) -> tuple[np.ndarray, list[str]]:
    """The paced agents (``speeds`` not NaN) re-timed again along their path at those speeds: lane
    snap moved their poses onto the lanes, and so their steps. An agent whose token gives
    ``heading_to_final`` (``speeds[:, 2]``) drives the token's turn from its pose now
    (:func:`turn_path`: the arc of :func:`~.pinning.pace_to_pins`, else a change of lanes; ``speeds[:,
    3]`` 1 where the token gives the final speed, else it may be lower): lane snap puts the centre
    on a lane's centre line, but a turning vehicle's centre cuts inside the curve its front follows,
    so the snapped path's +2 s direction is not the turn asked. Where no such path stays on the car
    lanes, no lane turns so: the snapped path is kept, and a warning line names the token
    (``owner``: per agent, its token's index). Returns the new traj and the warning lines."""
    traj = np.array(traj, np.float64)
    t = np.asarray(TIMES)
    lines: list[str] = []
    speeds = np.asarray(speeds, np.float64)
    speeds = speeds.reshape(len(traj), speeds.shape[-1] if speeds.ndim == 2 else 2)
    for a in np.flatnonzero(np.isfinite(speeds[:, 0])):
        v0, v2 = speeds[a, :2]
        traj[a] = retime(traj[a], _distance(v0, (v2 - v0) / 2.0, t))
        final = float(v2)
        if speeds.shape[1] > 2 and np.isfinite(speeds[a, 2]):
            free = speeds.shape[1] > 3 and speeds[a, 3] != 1.0
            found = turn_path(net, window, traj[a, T0].copy(), float(v0), float(v2), float(speeds[a, 2]), free)
            if found is not None:
                path, v = found
                final = float(v)
                traj[a] = retime(traj[a], _distance(v0, (v - v0) / 2.0, t))
                traj[a, t > 0] = path[t > 0]
            else:
                x, y = traj[a, T0, :2]
                i = int(owner[a]) if owner is not None else a
                lines.append(f"token {i} at ({x:.1f}, {y:.1f}) m (window frame): heading_to_final "
                             f"{speeds[a, 2]:+.2f} rad: no car lane turns so: the vehicle follows its lane")
        _straight_past(traj[a], float(v0), final)
    for line in lines:
        log.warning(line)
    return traj, lines


def lane_trajectory(net, lane: int, pos: float, v0: float, v2: float, turn: float = np.nan
                    ) -> np.ndarray:
    """(T, 3) world poses of a vehicle ``pos`` m along ``lane`` moving from ``v0`` to ``v2`` m/s
    (SUMO's 1-s update at constant acceleration) along the lane graph: behind it the first
    predecessor branch, ahead the branch whose heading at +2 s is nearest the current heading
    turned by twice ``turn`` (the token's ``heading_to_final``; absent: straight on)."""
    t = np.asarray(TIMES)
    s = _distance(v0, (v2 - v0) / 2.0, t)
    _, h0 = net.lane_pose(lane, pos)
    want = h0 + 2.0 * (0.0 if not np.isfinite(turn) else turn)
    out = np.zeros((len(t), 3))
    end = min(walk_lanes(net, lane, pos, float(s[-1])),
              key=lambda lp: abs(wrap_angle(net.lane_pose(*lp)[1] - want)))
    end_xy = net.lane_pose(*end)[0]
    for k, sk in enumerate(s):
        # nearer points on the chosen branch: the candidate at that distance nearest its end
        cands = walk_lanes(net, lane, pos, float(sk))
        lp = cands[0] if sk <= 0 else min(cands, key=lambda c: np.linalg.norm(net.lane_pose(*c)[0] - end_xy))
        xy, h = net.lane_pose(*lp)
        out[k] = xy[0], xy[1], h
    return out


def _placed(net, window: Window, lane: int, pos: float, v0: float, v2: float, row: np.ndarray,
            stated: bool) -> np.ndarray:
    """(T, 3) scene-frame poses of a placed token's vehicle along the lane graph (:func:`lane_trajectory`),
    its pose now the token's own where ``stated``."""
    world = lane_trajectory(net, lane, pos, v0, v2, float(row[8]))
    tr = np.c_[window.world_to_scene(world[:, :2]), window.yaw_to_scene(world[:, 2])]
    if stated:
        tr[T0] = row[1:4]
    return tr


def _row_lane(net, window: Window, row: np.ndarray) -> tuple[int, float, bool, float | None]:
    """The car lane a row's vehicle is placed on, at the token's position (within lane snap's
    radius, along its heading where it gives one): (lane, pos, stated, world yaw); lane -1: none.
    ``stated``: the pose now is the token's, no lane running along its heading (lane_snap's exact)."""
    xy = window.scene_to_world(row[None, 1:3])[0]
    yaw = None if not np.isfinite(row[3]) else float(window.yaw_to_world(row[3]))
    m = net.match_poses(xy[None], None if yaw is None else [yaw], radius=SNAP_RADIUS,
                        max_angle=SNAP_MAX_ANGLE)
    stated = False
    if yaw is not None and m.lane[0] >= 0 and m.heading_diff[0] > GIVEN_MAX_ANGLE:
        strict = net.match_poses(xy[None], [yaw], radius=SNAP_RADIUS, max_angle=GIVEN_MAX_ANGLE)
        m, stated = (strict, False) if strict.lane[0] >= 0 else (m, True)
    return int(m.lane[0]), float(m.pos[0]), stated, yaw


def _row_path(net, window: Window, row: np.ndarray, lane: int, pos: float, stated: bool,
              lines: list[str], where: str) -> np.ndarray:
    """(T, 3) scene-frame poses of a placed row's vehicle: speeds from the token or the lane's limit,
    along the lane graph, through the token's turn where the lanes let a vehicle drive it."""
    v0 = row[6] if np.isfinite(row[6]) else float(net.lanes[lane].speed)
    v2 = row[7] if np.isfinite(row[7]) else (_moving(float(v0), float(v0)) if np.isfinite(row[8]) else v0)
    tr = _placed(net, window, lane, pos, float(v0), float(v2), row, stated)
    if np.isfinite(row[8]):
        # the token's turn from the pose now, where the lanes let a vehicle drive it (pace_rows)
        t = np.asarray(TIMES)
        found = turn_path(net, window, tr[T0].copy(), float(v0), float(v2), float(row[8]),
                          free=not np.isfinite(row[7]))
        if found is None:
            lines.append(f"{where}: heading_to_final {row[8]:+.2f} rad: no car lane turns so: "
                         f"the vehicle follows its lane")
        else:
            if found[1] != v2:             # slower into the turn: the past at that deceleration
                tr = _placed(net, window, lane, pos, float(v0), found[1], row, stated)
            tr[t > 0] = found[0][t > 0]
    return tr


def _hits(box: np.ndarray, boxes: np.ndarray, owner: np.ndarray, add_b: list, add_o: list,
          removed: set[int]) -> tuple[list[int], np.ndarray]:
    """The agents (not yet removed; the scene's, then those placed so far) a placed box overlaps,
    and every agent's owner."""
    mine = box_polygons(box[None])[0]
    all_b = np.concatenate([boxes, np.array(add_b).reshape(-1, 5)])
    all_o = np.concatenate([owner, np.array(add_o, owner.dtype)])
    hit = np.flatnonzero(shapely.area(shapely.intersection(
        box_polygons(all_b), mine)) > 1e-3) if len(all_b) else np.zeros(0, int)
    return [k for k in hit.tolist() if k not in removed], all_o


def place_rows(boxes: np.ndarray, traj: np.ndarray, owner: np.ndarray, rows: np.ndarray,
               window: Window, net) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int], list[str]]:
    """Place the rows no generated agent matched: on the car lane at the token's position (within
    lane snap's radius; heading from the token, else the lane's), size from the token or a typical
    car, speeds from the token or the lane's limit, moving along the lane graph. A generated agent
    (``owner`` -1; a token's agent holds its token's index) its box overlaps gives way: the user's
    token wins. Returns the scene with the placed agents appended, their owners, the indices of
    the generated agents removed, and one warning line per token that could not be placed."""
    boxes, traj, owner = np.asarray(boxes, np.float64), np.asarray(traj, np.float64), np.asarray(owner)
    removed: set[int] = set()
    lines: list[str] = []
    add_b, add_t, add_o = [], [], []
    done = set(owner[owner >= 0].tolist())
    for row in rows:
        i = int(row[0])
        if i in done:
            continue
        where = f"token {i} at ({row[1]:.1f}, {row[2]:.1f}) m (window frame)"
        lane, pos, stated, yaw = _row_lane(net, window, row)
        if lane < 0:
            lines.append(f"{where}: on no car lane within {SNAP_RADIUS:g} m"
                         f"{'' if yaw is None else ' that runs along its heading'}: not placed")
            continue
        tr = _row_path(net, window, row, lane, pos, stated, lines, where)
        size = row[4:6] if np.isfinite(row[4]) else np.array([CAR_LENGTH, CAR_WIDTH])
        box = np.r_[tr[T0], size]
        hit, all_o = _hits(box, boxes, owner, add_b, add_o, removed)
        if any(all_o[k] >= 0 for k in hit):
            lines.append(f"{where}: overlaps the vehicle of token {int(all_o[[k for k in hit if all_o[k] >= 0][0]])}"
                         f": not placed")
            continue
        removed.update(hit)
        add_b.append(box), add_t.append(tr), add_o.append(i)
    keep = np.array([k for k in range(len(boxes)) if k not in removed], np.int64)
    new_b = np.concatenate([boxes[keep], np.array(add_b).reshape(-1, 5)])
    new_t = np.concatenate([traj[keep], np.array(add_t).reshape(-1, len(TIMES), 3)])
    new_o = np.concatenate([owner[keep], np.array(add_o, owner.dtype)])
    for line in lines:
        log.warning(line)
    return new_b, new_t, new_o, sorted(removed), lines
