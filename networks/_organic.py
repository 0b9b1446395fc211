"""Builders for networks/build.py whose streets bend, meet at uneven angles or widen into turn lanes.

The first networks were straight-edged; real city networks imported from OpenStreetMap are not
(curved edges, turning pockets, junctions that are not right angles). These three add that to the
training split. Each is a plain ``builder(ws)`` as in ``_specs.py``.
"""
import math

import numpy as np

from _city import junction_type, strongly_connected
from _specs import PEDESTRIANS, node, road

CURVY_N, CURVY_SPACING, CURVY_JITTER = 7, 115.0, 16.0
CURVY_ARTERIAL = {1: 2, 5: 2}   # grid line -> lanes
CURVY_COLLECTOR = {3}


def bent_shape(p, q, bend, samples=9):
    """Points of a quadratic Bezier from p to q whose control point sits ``bend`` metres off the
    chord's midpoint, to the left of p -> q (both end points included)."""
    (x0, y0), (x1, y1) = p, q
    length = math.hypot(x1 - x0, y1 - y0)
    cx = (x0 + x1) / 2 - bend * (y1 - y0) / length
    cy = (y0 + y1) / 2 + bend * (x1 - x0) / length
    ts = np.linspace(0.0, 1.0, samples)
    return [((1 - t) ** 2 * x0 + 2 * (1 - t) * t * cx + t * t * x1,
             (1 - t) ** 2 * y0 + 2 * (1 - t) * t * cy + t * t * y1) for t in ts]


def curvy_line(k):
    """(class, lanes, speed, priority) of grid line k."""
    if k in CURVY_ARTERIAL:
        return "arterial", CURVY_ARTERIAL[k], 13.89, 3
    if k in CURVY_COLLECTOR:
        return "collector", 1, 13.89, 2
    return "residential", 1, 8.33 if k % 2 else 11.11, 1


def curvy_town(ws):
    """7x7 jittered grid (115 m) whose streets bend (quadratic curves, up to ~25 m off the chord),
    2-lane arterials with traffic lights, collectors, residential streets (priority /
    right-before-left, ~15 % removed), sidewalks + crossings."""
    rng = ws.rng()
    n = CURVY_N
    pos = {(i, j): (i * CURVY_SPACING + float(np.clip(rng.normal(0, CURVY_JITTER), -35, 35)),
                    j * CURVY_SPACING + float(np.clip(rng.normal(0, CURVY_JITTER), -35, 35)))
           for i in range(n) for j in range(n)}
    segs = {}   # (p, q) -> (class, lanes, speed, priority)
    for i in range(n):
        for j in range(n):
            if i + 1 < n:
                segs[((i, j), (i + 1, j))] = curvy_line(j)
            if j + 1 < n:
                segs[((i, j), (i, j + 1))] = curvy_line(i)
    residential = sorted(k for k, s in segs.items() if s[0] == "residential")
    for idx in rng.permutation(len(residential))[: int(0.15 * len(residential))]:
        key = residential[idx]
        if sum(key[0] in k for k in segs) > 2 and sum(key[1] in k for k in segs) > 2:
            seg = segs.pop(key)
            if not strongly_connected({a for p, q in segs for a in ((p, q), (q, p))}):
                segs[key] = seg
    rbl = {(a, b): bool(rng.random() < 0.5) for a in range(2) for b in range(2)}
    lines = {}   # grid node -> {"v": class of its column's street, "h": of its row's}
    for (p, q), s in segs.items():
        for k in (p, q):
            lines.setdefault(k, {})["v" if p[0] == q[0] else "h"] = s[0]
    nodes = [node("c%d_%d" % k, *pos[k],
                  junction_type(c.get("v"), c.get("h"), rbl[(k[0] * 2 // n, k[1] * 2 // n)]))
             for k, c in sorted(lines.items())]
    edges = []
    for (p, q), (cls, lanes, speed, prio) in sorted(segs.items()):
        bend = float(np.clip(rng.normal(0, 0.1 * CURVY_SPACING), -25, 25))
        edges += road("c%d_%d" % p, "c%d_%d" % q, lanes, speed, priority=prio,
                      shape=bent_shape(pos[p], pos[q], bend))
    ws.netconvert(nodes, edges, "--no-turnarounds.tls", *PEDESTRIANS)


def organic_turnlanes(ws):
    """Dense random planar net (--rand, 60-160 m edges, angles down to 25 deg), 1-2 lanes with a
    left-turn pocket (40 m) before each junction, 13.89 m/s, guessed traffic lights, sidewalks."""
    ws.netgenerate("--rand", "--rand.iterations", 60, "--rand.min-distance", 60,
                   "--rand.max-distance", 160, "--rand.min-angle", 25, "--rand.connectivity", 0.9,
                   "-L", 2, "--random-lanenumber", "--turn-lanes", 1, "--turn-lanes.length", 40,
                   "-S", 13.89, "-j", "priority", "--tls.guess", "--tls.guess.threshold", 40,
                   "--no-turnarounds.tls", *PEDESTRIANS)


def grid_turnlanes_tls(ws):
    """4x4 grid, 170 m blocks, 2 lanes plus a 50 m left-turn pocket at every junction, 13.89 m/s,
    traffic lights, sidewalks + crossings."""
    ws.netgenerate("--grid", "--grid.number", 4, "--grid.length", 170, "-L", 2,
                   "--turn-lanes", 1, "--turn-lanes.length", 50, "-S", 13.89, "-j", "traffic_light",
                   "--no-turnarounds.tls", *PEDESTRIANS)
