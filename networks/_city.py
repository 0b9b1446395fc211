"""City-like demo network (~2 km x 2 km) for networks/build.py.

Layout, all drawn from a seeded numpy RNG:
  * a 13x13 street grid spanning ~1.7 km with uneven block sizes and node jitter;
  * arterials on grid lines 2/6/10 (2 lanes 13.89 m/s; 3 lanes 16.67 m/s on line 6),
    collectors on lines 4/8 (1 lane 13.89 m/s), residential streets elsewhere
    (1 lane; 8.33 m/s right-before-left districts or 11.11 m/s priority districts);
  * ~15 % of residential blocks removed and ~12 % made one-way, keeping the
    network strongly connected;
  * traffic lights at arterial/arterial, arterial/collector, collector/collector crossings;
  * two roundabouts (one 2-lane on an arterial crossing, one 1-lane on a collector crossing);
  * a rounded-square ring road (2 lanes, 22.22 m/s, 27.78 m/s bypass on the east side)
    fed by the arterials; sidewalks + crossings on all roads up to 16.67 m/s.
"""
import math
from dataclasses import dataclass

import numpy as np

from _specs import PEDESTRIANS, node, road, roundabout

N = 13                      # grid lines per direction
SPAN = 1700.0               # grid extent (m)
RING_HALF, RING_CORNER = 1000.0, 200.0
ARTERIAL = {2: 2, 6: 3, 10: 2}   # grid line -> lanes
COLLECTOR = {4, 8}
ROUNDABOUTS = {(10, 10): (28.0, 2), (4, 8): (20.0, 1)}   # grid node -> (radius, ring lanes)
RES_REMOVE, RES_ONEWAY = 0.15, 0.12


@dataclass
class Segment:
    """An undirected grid street between two grid nodes."""
    cls: str
    lanes: int
    speed: float
    priority: int
    oneway: bool = False


def gid(i, j):
    return "g%d_%d" % (i, j)


def line_class(k):
    if k in ARTERIAL:
        return ("arterial", ARTERIAL[k], 16.67 if ARTERIAL[k] == 3 else 13.89, 3)
    if k in COLLECTOR:
        return ("collector", 1, 13.89, 2)
    return ("residential", 1, None, 1)


def strongly_connected(arcs):
    """True if the directed graph given as a set of (a, b) arcs is strongly connected."""
    fwd, bwd = {}, {}
    for a, b in arcs:
        fwd.setdefault(a, []).append(b)
        bwd.setdefault(b, []).append(a)
    allnodes = set(fwd) | set(bwd)
    start = min(allnodes)
    for adj in (fwd, bwd):
        seen, todo = {start}, [start]
        while todo:
            for m in adj.get(todo.pop(), []):
                if m not in seen:
                    seen.add(m)
                    todo.append(m)
        if seen != allnodes:
            return False
    return True


def grid_positions(rng):
    def coords():
        gaps = rng.uniform(0.7, 1.3, N - 1)
        return np.concatenate([[0.0], np.cumsum(gaps / gaps.sum() * SPAN)]) - SPAN / 2
    xs, ys = coords(), coords()
    pos = {}
    for i in range(N):
        for j in range(N):
            sx = 3.0 if i in ARTERIAL else 12.0
            sy = 3.0 if j in ARTERIAL else 12.0
            pos[(i, j)] = (xs[i] + np.clip(rng.normal(0, sx), -25, 25),
                           ys[j] + np.clip(rng.normal(0, sy), -25, 25))
    return pos


def grid_segments(districts):
    """Grid streets as {(p, q): Segment}; one-way segments run from p to q."""
    segs = {}
    for i in range(N):
        for j in range(N):
            for (p, q, k) in [((i, j), (i + 1, j), j), ((i, j), (i, j + 1), i)]:
                if q[0] < N and q[1] < N:
                    cls, lanes, speed, prio = line_class(k)
                    if speed is None:
                        speed = 8.33 if districts[(i // 4, j // 4)] else 11.11
                    segs[(p, q)] = Segment(cls, lanes, speed, prio)
    return segs


def arcs_of(segs):
    arcs = set()
    for (p, q), s in segs.items():
        arcs.add((p, q))
        if not s.oneway:
            arcs.add((q, p))
    return arcs


def degree(segs, n):
    return sum(1 for k in segs if n in k)


def thin_residential(rng, segs):
    """Remove / one-way some residential segments while keeping strong connectivity."""
    res = sorted(k for k, s in segs.items() if s.cls == "residential")
    order = rng.permutation(len(res))
    n_remove, n_oneway = int(RES_REMOVE * len(res)), int(RES_ONEWAY * len(res))
    removed = oneway = 0
    for idx in order:
        key = res[idx]
        if removed < n_remove and degree(segs, key[0]) > 2 and degree(segs, key[1]) > 2:
            seg = segs.pop(key)
            if strongly_connected(arcs_of(segs)):
                removed += 1
                continue
            segs[key] = seg
        if oneway < n_oneway:
            if rng.random() < 0.5:   # flip direction
                seg = segs.pop(key)
                key = (key[1], key[0])
                segs[key] = seg
            segs[key].oneway = True
            if strongly_connected(arcs_of(segs)):
                oneway += 1
            else:
                segs[key].oneway = False


def ring_polyline():
    """Closed counter-clockwise rounded square, list of points (first != last)."""
    h, rc = RING_HALF, RING_CORNER
    pts = []
    for cx, cy, a0 in [(h - rc, -h + rc, -90), (h - rc, h - rc, 0), (-h + rc, h - rc, 90), (-h + rc, -h + rc, 180)]:
        pts += [(cx + rc * math.cos(math.radians(a0 + t)), cy + rc * math.sin(math.radians(a0 + t)))
                for t in range(0, 91, 15)]
    return pts


def ring_param(p):
    """Angle-like sort key of a point on the ring (counter-clockwise from east)."""
    return math.atan2(p[1], p[0]) % (2 * math.pi)


def ring_road(pos):
    """Ring nodes connected to arterial ends; returns (ring nodes, ring edges, connectors)."""
    h = RING_HALF
    attach = []   # (ring id, ring point, grid node, arterial line)
    for k in ARTERIAL:
        attach += [("ring_s%d" % k, (pos[(k, 0)][0], -h), (k, 0), k),
                   ("ring_n%d" % k, (pos[(k, N - 1)][0], h), (k, N - 1), k),
                   ("ring_w%d" % k, (-h, pos[(0, k)][1]), (0, k), k),
                   ("ring_e%d" % k, (h, pos[(N - 1, k)][1]), (N - 1, k), k)]
    attach.sort(key=lambda a: ring_param(a[1]))
    poly = ring_polyline()
    nodes, edges, connectors = [], [], []
    for n, (rid, p, g, k) in enumerate(attach):
        nodes.append(node(rid, *p, "traffic_light" if ARTERIAL[k] == 3 else "priority"))
        connectors.append((rid, g, k))
        rid1, p1 = attach[(n + 1) % len(attach)][:2]
        t0, t1 = ring_param(p), ring_param(p1)
        if t1 <= t0:
            t1 += 2 * math.pi
        inner = sorted((q for q in poly if t0 < ring_param(q) < t1 or t0 < ring_param(q) + 2 * math.pi < t1),
                       key=lambda q: ring_param(q) + (2 * math.pi if ring_param(q) < t0 else 0))
        speed = 27.78 if p[0] >= h and p1[0] >= h else 22.22   # eastern bypass
        edges += road(rid, rid1, 2, speed, priority=4, shape=[p] + inner + [p1])
    return nodes, edges, connectors


def junction_type(col_cls, row_cls, district_rbl):
    """Junction type from the classes of the vertical / horizontal line through a node (None: absent)."""
    if col_cls is None or row_cls is None:
        return "priority"
    major = [c for c in (col_cls, row_cls) if c != "residential"]
    if len(major) == 2:
        return "traffic_light"
    if major:
        return "priority"
    return "right_before_left" if district_rbl else "priority"


def city(ws):
    """City-like ~2x2 km demo: jittered 13x13 grid with arterials (2-3 lanes, 13.89-16.67 m/s,
    traffic lights), collectors, residential streets (right-before-left / priority, some one-way),
    two roundabouts, a 2-lane ring road (22.22-27.78 m/s), sidewalks + crossings."""
    rng = ws.rng()
    districts = {(a, b): bool(rng.random() < 0.5) for a in range(4) for b in range(4)}
    pos = grid_positions(rng)
    segs = grid_segments(districts)
    thin_residential(rng, segs)
    lines = {}   # grid node -> {"v": column class, "h": row class}
    for (p, q), s in segs.items():
        for n in (p, q):
            lines.setdefault(n, {})["v" if p[0] == q[0] else "h"] = s.cls
    nodes, edges, rbs = [], [], []
    rename = {}   # (roundabout centre, neighbour) -> ring node replacing the centre
    for (i, j), (r, lanes) in ROUNDABOUTS.items():
        cx, cy = pos[(i, j)]
        nbs = [q if p == (i, j) else p for (p, q) in segs if (i, j) in (p, q)]
        angles = {nb: math.degrees(math.atan2(pos[nb][1] - cy, pos[nb][0] - cx)) % 360 for nb in nbs}
        rn, re, rb = roundabout("rb%d_%d_" % (i, j), cx, cy, r, sorted(angles.values()), lanes=lanes, speed=8.33)
        nodes += rn
        edges += re
        rbs.append(rb)
        order = sorted(nbs, key=lambda nb: angles[nb])
        for k, nb in enumerate(order):
            rename[((i, j), nb)] = rn[k]["id"]
    for (i, j), cls in sorted(lines.items()):
        if (i, j) not in ROUNDABOUTS:
            jt = junction_type(cls.get("v"), cls.get("h"), districts[(i // 4, j // 4)])
            nodes.append(node(gid(i, j), *pos[(i, j)], jt))
    for (p, q), s in sorted(segs.items()):
        a = rename.get((p, q), gid(*p))
        b = rename.get((q, p), gid(*q))
        edges += road(a, b, s.lanes, s.speed, priority=s.priority, two_way=not s.oneway)
    rnodes, redges, connectors = ring_road(pos)
    nodes += rnodes
    edges += redges
    for rid, g, k in connectors:
        edges += road(gid(*g), rid, ARTERIAL[k], line_class(k)[2], priority=3)
    ws.netconvert(nodes, edges, "--no-turnarounds.tls", *PEDESTRIANS, roundabouts=rbs)
