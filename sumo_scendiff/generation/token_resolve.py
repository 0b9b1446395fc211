"""Token-file references to the network, resolved where the network is known: at generation.

    tokens = resolve_tokens(net, window, spec.for_window(window))   # ScenarioGenerator.generate does it

A token file may place a vehicle in a user's terms instead of metres (docs/tokens.md, "Places on
the road"): ``edge``, ``lane``, ``pos`` (SUMO's lane, metres along it) or ``ahead``,
``lane_offset`` (metres along the window's axis from its centre, lanes to the left (+) or right
(-) of the lane found there running along the window). Both become the window-frame ``x``, ``y``
of the point on that lane's centre line, and ``heading`` the lane's there unless the token gives
one: the lane the user named is the direction of travel. A lane offset is counted on the network
(SUMO's lane index on the same edge), not as a fixed width, so it lands on the lane's centre line
on any road; inside a junction on the road the window's lane leads from or to. A reference the network does not have raises
:class:`~sumo_scendiff.tokens.file.TokenFileError` naming the token and the key.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import shapely

from ..core.geometry import Window, wrap_angle
from ..tokens.file import REFERENCE_KEYS, TokenFileError

AHEAD_RADIUS = 5.0          # m: how far from the point ahead the window's lane may lie
AHEAD_MAX_ANGLE = np.pi / 3  # rad: the lane runs along the window's axis within this
CHAIN = 8                   # internal lanes followed from one connection to its roads


class NotHere(TokenFileError):
    """A place relative to the window (``ahead``, ``lane_offset``) this window's road does not have:
    the file is right, the window (one ``run`` picked, say) is not that road."""


def resolve_tokens(net, window: Window, tokens: Sequence | np.ndarray | None, source: str = "",
                   warnings: list | None = None):
    """``tokens`` (one window's dicts) with network references replaced by window-frame ``x``,
    ``y`` and ``heading``; other tokens, and encoded token arrays, are returned as they are.
    ``source``: the token file, named first in an error. With ``warnings`` (a list), a place
    relative to the window that its road does not have (:class:`NotHere`) is one line there and the
    token goes without its place (the model places its vehicle), instead of an error."""
    if tokens is None or isinstance(tokens, np.ndarray):
        return tokens
    if not any(isinstance(t, Mapping) and any(k in t for k in REFERENCE_KEYS) for t in tokens):
        return tokens
    try:
        return [_resolved(net, window, t, i, warnings) if isinstance(t, Mapping) else t for i, t in enumerate(tokens)]
    except TokenFileError as e:
        raise TokenFileError(f"{source}: {e}" if source else str(e)) from None


def _resolved(net, window: Window, token: Mapping, i: int, warnings: list | None) -> dict:
    try:
        return resolve_token(net, window, token, i)
    except NotHere as e:
        if warnings is None:
            raise
        warnings.append(f"{e}: not in this window; the token is given without its place")
        return {k: v for k, v in token.items() if k not in REFERENCE_KEYS}


def _lane(net, edge: str, index: int, where: str, key: str) -> int:
    k = net.lane_index.get(f"{edge}_{index}")
    if k is None:
        lanes = sorted(ln.index for ln in net.lanes if ln.edge == edge)
        if not lanes:
            raise TokenFileError(f"{where}: {key}: no edge {edge!r} in {net.name}")
        error = NotHere if key == "lane_offset" else TokenFileError
        raise error(f"{where}: {key}: edge {edge!r} has no lane {index} (lanes {lanes[0]}..{lanes[-1]})")
    if not net.lanes[k].car:
        raise TokenFileError(f"{where}: {key}: lane {net.lanes[k].id!r} is not a car lane")
    return k


def _road_lanes(net, inside) -> list:
    """The lanes of the roads (normal edges) the internal lane ``inside`` leads from and to, in that
    order: a lane offset asked where the point ahead lies inside a junction is counted on them, since
    an internal lane is one connection (one lane). Through a chain of internal lanes (an internal
    junction between) both ways."""
    snet, out = net.sumo_net, []
    for step in (lambda ln: ln.getIncoming(), lambda ln: ln.getOutgoingLanes()):
        lane = snet.getLane(inside.id)
        for _ in range(CHAIN):
            nxt = step(lane)
            if not nxt:
                break
            lane = nxt[0]
            if not lane.getID().startswith(":"):
                out.append(net.lanes[net.lane_index[lane.getID()]])
                break
    return out


def resolve_token(net, window: Window, token: Mapping, i: int = 0) -> dict:
    """One token dict with its reference keys resolved (see the module docstring)."""
    t = dict(token)
    if not any(k in t for k in REFERENCE_KEYS):
        return t
    where = f"token {i}"
    if "edge" in t:
        edge, index, pos = str(t.pop("edge")), int(t.pop("lane", 0)), float(t.pop("pos"))
        k = _lane(net, edge, index, where, "edge")
        length = float(net.lines[k].length)
        if not 0.0 <= pos <= length:
            raise TokenFileError(f"{where}: pos: {pos:g} m is not on lane {net.lanes[k].id!r} "
                                 f"(0..{length:.1f} m)")
    else:
        ahead, offset = float(t.pop("ahead", 0.0)), int(t.pop("lane_offset", 0))
        p = window.scene_to_world(np.array([[ahead, 0.0]]))
        m = net.match_poses(p, [window.yaw], radius=AHEAD_RADIUS, max_angle=AHEAD_MAX_ANGLE)
        if m.lane[0] < 0:
            raise NotHere(f"{where}: ahead: no car lane along the window's heading within "
                                 f"{AHEAD_RADIUS:g} m of ({p[0, 0]:.1f}, {p[0, 1]:.1f}), {ahead:g} m "
                                 f"ahead of the window centre")
        ego = net.lanes[int(m.lane[0])]
        if offset and ego.internal:
            roads = _road_lanes(net, ego) or [ego]
            ego = next((r for r in roads if f"{r.edge}_{r.index + offset}" in net.lane_index), roads[0])
        k = _lane(net, ego.edge, ego.index + offset, where, "lane_offset") if offset else int(m.lane[0])
        pos = float(shapely.line_locate_point(net.lines[k], shapely.Point(p[0])))
    xy, heading = net.lane_pose(k, pos)
    x, y = window.world_to_scene(np.asarray(xy)[None])[0]
    half = 0.5 * float(window.size)
    if max(abs(x), abs(y)) > half:
        raise TokenFileError(f"{where}: lane {net.lanes[k].id!r} at {pos:.1f} m is ({x:.2f}, {y:.2f}) m in "
                             f"the window frame, outside the window [-{half:g}, {half:g}] m")
    t["x"], t["y"] = float(x), float(y)
    if t.get("heading") is None:
        t["heading"] = float(wrap_angle(window.yaw_to_scene(heading)))
    return t
