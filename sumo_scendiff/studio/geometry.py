"""The network as the page draws it, a point snapped to a lane, and a fill's density per edge."""
from __future__ import annotations

import math

import numpy as np

from ..map.network import Network

SNAP_RADIUS_M = 6.0   # a click this close to a car lane's centre line lands on it (about a lane and a half)


class StudioError(ValueError):
    """A request the studio cannot serve (one line, answered with a 4xx)."""


def _line(points: np.ndarray) -> list[float]:
    """A polyline as flat [x0, y0, x1, y1, ...], to the centimetre (smaller JSON, same picture)."""
    return [round(float(v), 2) for v in np.asarray(points, dtype=float).reshape(-1)]


def geometry(net: Network) -> dict:
    """Lanes (centre lines, width, kind), junction outlines and traffic-light stop lines."""
    lanes, lights = [], []
    for ln in net.lanes:
        kind = "internal" if ln.internal else "walk" if ln.pedestrian_only else "car" if ln.car else "other"
        lanes.append({"id": ln.id, "edge": ln.edge, "index": ln.index, "kind": kind, "width": round(ln.width, 2),
                      "speed": round(ln.speed, 2), "length": round(ln.length, 2), "shape": _line(ln.shape)})
        if ln.tls and not ln.internal:
            lights.append({"lane": ln.id, "x": round(float(ln.shape[-1, 0]), 2), "y": round(float(ln.shape[-1, 1]), 2)})
    junctions = [{"id": j.id, "type": j.type, "ring": _line(j.ring)} for j in net.junctions if j.ring is not None
                 and len(j.ring) > 2]
    x0, y0, x1, y1 = (float(v) for v in net.bounds)
    return {"name": net.name, "bounds": [x0, y0, x1, y1], "lanes": lanes, "junctions": junctions, "lights": lights}


def _number(body: dict, key: str) -> float:
    v = body.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise StudioError(f"{key}: expected a finite number, got {v!r}")
    return float(v)


def snap(net: Network, body: dict) -> dict:
    """The car lane of a normal edge nearest a point (within ``SNAP_RADIUS_M``): what a token names."""
    x, y = _number(body, "x"), _number(body, "y")
    hit = net.lookup(x, y, radius=SNAP_RADIUS_M, max_angle=math.pi, allow_internal=False)
    if hit is None:
        raise StudioError(f"({x:.1f}, {y:.1f}): no car lane within {SNAP_RADIUS_M:.0f} m")
    lane, pos = hit[0], hit[1]
    xy, heading = net.lane_pose(net.lane_index[lane.id], pos)
    return {"lane": lane.id, "edge": lane.edge, "index": lane.index, "pos": round(pos, 2),
            "length": round(lane.length, 2), "speed_limit": round(lane.speed, 2),
            "x": round(float(xy[0]), 2), "y": round(float(xy[1]), 2), "heading": round(heading, 4)}


def fill_density(net: Network, doc: dict) -> dict:
    """Vehicles per km of lane per edge of a fill's seeded vehicles (``fill.json``)."""
    from ..fill.picture import edge_density
    if not isinstance(doc, dict) or doc.get("format") != "sumo-scendiff-fill":
        raise StudioError("not a fill.json (its format is not 'sumo-scendiff-fill')")
    try:
        rows = np.array([[float(a[k]) for k in ("x", "y", "heading")] for a in doc.get("agents", [])
                         if a.get("vehicle") is not None], dtype=float).reshape(-1, 3)
    except (KeyError, TypeError, ValueError) as e:
        raise StudioError(f"fill.json: an agent without a numeric x, y, heading ({e})") from None
    dens = edge_density(net, rows)
    return {"edges": {e: round(d, 2) for e, d in dens.items() if d > 0}, "vehicles": len(rows),
            "max": round(max(dens.values(), default=0.0), 2)}
