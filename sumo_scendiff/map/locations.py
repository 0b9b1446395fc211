"""Where to put a 100 m window: validate a user centre (``run --center X,Y``) or pick busy, varied ones.

    net = Network.load("networks/city.net.xml")
    x, y = parse_center("1000,750")                # LocationError on anything but "X,Y"
    window = window_at(net, x, y)                  # LocationError when no car lane is within 30 m
    for loc in auto_windows(net, 8, seed=0):       # list[Location]; traffic=xy: where vehicles are
        loc.window, loc.kind, loc.junction_id      # Window, one of KINDS (or "road"), SUMO node id

Candidates are junctions where cars interact: nodes with >= 3 car arms (dead ends, internal and pure
geometry nodes excluded), merges / diverges (2 car edges into 1, 1 into 2, lane drops, zipper nodes)
and roundabouts (one candidate per ring, centred on its nodes' mean). A candidate's score is its number
of incoming car lanes, plus ``TLS_BONUS`` when signalised (a roundabout: entry lanes + ring lanes).
``auto_windows`` takes kinds round-robin (seeded order) and, inside a kind, junctions with probability
proportional to score, keeping centres at least ``size / 2`` apart; the separation is relaxed
(``size / 4``, then none) when that leaves fewer than ``n``, and when ``n`` exceeds the candidates they
are reused with a random yaw. A network without candidates (one long road) gets windows on random
car-lane points, kind ``"road"``.

Given ``traffic`` (the host's vehicle positions at the seeding time: ``run`` with a demand), the
traffic decides first: among the candidates whose window holds vehicles, those holding at least their
median count are drawn with probability proportional to that count (any kind; centres ``size / 2``,
then ``size / 4`` apart), then the other windows holding vehicles, then the layout's choice above fills
the rest; road points go by their count too. Without a vehicle in any candidate window the choice is
the layout's alone. Same (net, n, seed, size, traffic) -> same windows.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import shapely

from ..core.geometry import Window
from .network import CAR, Network, window_square

KINDS = ("signalised", "roundabout", "merge_diverge", "unsignalised")
NEAR = 30.0      # a user centre must have a car lane within this many metres
TLS_BONUS = 2.0  # score bonus of a signalised junction (in incoming-lane units)


class LocationError(ValueError):
    """A centre that cannot be used; the message is one line starting with ``--center``."""


@dataclass(frozen=True)
class Location:
    """A window chosen by :func:`auto_windows` (or a candidate from :func:`candidates`)."""

    window: Window
    kind: str                 # one of KINDS, or "road" for the no-junction fallback
    junction_id: str | None   # SUMO node id (a roundabout: its first node); None for "road"
    score: float = 0.0        # incoming car lanes (+ TLS_BONUS); 0 for "road"


def _fmt(v: float) -> str:
    return f"{v:.2f}".rstrip("0").rstrip(".") if math.isfinite(v) else str(v)


def parse_center(text: str) -> tuple[float, float]:
    """``"X,Y"`` or ``"X, Y"`` (network metres) -> ``(x, y)``; :class:`LocationError` otherwise."""
    parts = str(text).split(",")
    err = LocationError(f"--center {text!r}: expected X,Y in network metres, e.g. --center 1000,750")
    if len(parts) != 2:
        raise err
    try:
        x, y = float(parts[0]), float(parts[1])
    except ValueError:
        raise err from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise err
    return x, y


def window_at(net: Network, x: float, y: float, yaw: float = 0.0, size: float = 100.0) -> Window:
    """The window centred on a user point; :class:`LocationError` if no car lane lies within ``NEAR`` m."""
    x, y, yaw, size = float(x), float(y), float(yaw), float(size)
    where = f"--center {_fmt(x)},{_fmt(y)}"
    if not (math.isfinite(x) and math.isfinite(y)):
        raise LocationError(f"{where}: not a finite point")
    if not (math.isfinite(yaw) and math.isfinite(size) and size > 0):
        raise LocationError(f"{where}: bad window (yaw {yaw}, size {size}; need finite yaw, size > 0)")
    pt = shapely.Point(x, y)
    if any(net.lanes[i].car for i in net.lane_tree.query(pt, predicate="dwithin", distance=NEAR)):
        return Window(x, y, yaw, size)
    dist = float(shapely.distance(pt, net.lane_tree.geometries.take(net.car_lane_ids)).min())
    if net.sumo_net is not None:
        (x0, y0), (x1, y1) = net.sumo_net.getBBoxXY()
    else:
        x0, y0, x1, y1 = net.bounds
    raise LocationError(f"{where}: off the network {os.path.basename(net.path)} (nearest car lane "
                        f"{dist:.0f} m away; the network spans x {x0:.0f}..{x1:.0f}, y {y0:.0f}..{y1:.0f})")


def _car_lanes(edge) -> int:
    return sum(1 for lane in edge.getLanes() if lane.allows(CAR))


def _car_edges(edges) -> list:
    return [e for e in edges if e.getFunction() == "" and e.allows(CAR)]


def candidates(net: Network, size: float = 100.0) -> list[Location]:
    """Every junction where cars interact, as a yaw-0 window on its centre, in network file order."""
    sn = net.sumo_net
    out: list[Location] = []
    ring_nodes: set[str] = set()
    for rb in sn.getRoundabouts():
        ring = set(rb.getEdges() or ())
        nodes = [sn.getNode(i) for i in rb.getNodes()]
        ring_nodes.update(rb.getNodes())
        entries = [e for n in nodes for e in _car_edges(n.getIncoming()) if e.getID() not in ring]
        ring_lanes = max((_car_lanes(sn.getEdge(e)) for e in ring if sn.hasEdge(e)), default=0)
        if entries:
            cx, cy = np.mean([n.getCoord()[:2] for n in nodes], axis=0)
            out.append(Location(Window(float(cx), float(cy), 0.0, size), "roundabout", nodes[0].getID(),
                                float(sum(map(_car_lanes, entries)) + ring_lanes)))
    for node in sn.getNodes():
        typ = node.getType()
        if typ in ("dead_end", "internal") or node.getID() in ring_nodes:
            continue
        ins, outs = _car_edges(node.getIncoming()), _car_edges(node.getOutgoing())
        froms = {e.getFromNode().getID() for e in ins}
        tos = {e.getToNode().getID() for e in outs}
        in_lanes, out_lanes = sum(map(_car_lanes, ins)), sum(map(_car_lanes, outs))
        merge = ((len(ins), len(outs)) in ((2, 1), (1, 2)) and not (froms & tos)) or typ == "zipper" or (
            len(ins) == 1 == len(outs) and in_lanes > out_lanes)
        if len(froms | tos) < 3 and not merge:
            continue  # dead end, geometry node, plain continuation
        tls = typ.startswith("traffic_light")
        kind = "signalised" if tls else "merge_diverge" if merge else "unsignalised"
        x, y = node.getCoord()[:2]
        out.append(Location(Window(float(x), float(y), 0.0, size), kind, node.getID(),
                            float(in_lanes + (TLS_BONUS if tls else 0.0))))
    return [c for c in out if net.has_road(c.window)]


def vehicles_in(windows, points) -> np.ndarray:
    """How many of ``points`` (world x, y; e.g. the host's vehicles) lie in each window, edge included."""
    pts = np.asarray(points if points is not None else (), dtype=np.float64).reshape(-1, 2)
    if not len(windows) or not len(pts):
        return np.zeros(len(windows), dtype=np.int64)
    tree = shapely.STRtree(shapely.points(pts))
    hit, _ = tree.query([window_square(w) for w in windows], predicate="intersects")
    return np.bincount(hit, minlength=len(windows))


def auto_windows(net: Network, n: int, seed: int = 0, size: float = 100.0, traffic=None) -> list[Location]:
    """``n`` busy, varied windows (see the module docstring); deterministic in (net, n, seed, size,
    traffic). ``traffic``: the host's vehicle positions (world x, y) at the seeding time, or None."""
    if n < 0:
        raise ValueError(f"auto_windows: n must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    cands = candidates(net, size)
    if not cands:
        return _road_windows(net, n, rng, size, traffic)
    by_kind = {k: [i for i, c in enumerate(cands) if c.kind == k] for k in KINDS}
    kinds = [k for k in KINDS if by_kind[k]]
    kinds = [kinds[i] for i in rng.permutation(len(kinds))]
    score = np.array([max(c.score, 1e-3) for c in cands])
    seps = (0.5 * size, 0.25 * size, 0.0)
    rounds = [([by_kind[k] for k in kinds], score, sep) for sep in seps]
    load = vehicles_in([c.window for c in cands], traffic)
    if load.any():   # the traffic first: the busier half of the windows holding vehicles, then the rest
        busy = np.flatnonzero(load)
        busier = busy[load[busy] >= np.median(load[busy])]
        rounds = [([pool], load, sep) for pool in (busier, busy) for sep in seps[:2]] + rounds
    xy = np.array([(c.window.cx, c.window.cy) for c in cands])
    out = [cands[i] for i in _pick(xy, rounds, n, rng)]
    while len(out) < n:  # more windows than candidates: reuse them, turned
        for k in kinds[: n - len(out)]:
            c = cands[_draw(np.asarray(by_kind[k]), score, rng)]
            w = Window(c.window.cx, c.window.cy, float(rng.uniform(-np.pi, np.pi)), size)
            out.append(Location(w, c.kind, c.junction_id, c.score))
    return out


def _draw(pool: np.ndarray, weight: np.ndarray, rng: np.random.Generator) -> int:
    return int(pool[rng.choice(len(pool), p=weight[pool] / weight[pool].sum())])


def _pick(xy: np.ndarray, rounds: list, n: int, rng: np.random.Generator) -> list[int]:
    """Up to ``n`` of the points ``xy``: each round (groups, weights, separation) takes its groups
    round-robin, drawing in proportion to the weights among the points at least the separation from
    every point already taken, until no group has one left."""
    gap = np.full(len(xy), np.inf)  # distance to the nearest chosen centre; -1 once chosen
    chosen: list[int] = []
    for groups, weight, sep in rounds:
        active = list(range(len(groups)))
        while active and len(chosen) < n:
            for g in list(active):
                if len(chosen) >= n:
                    break
                pool = np.asarray(groups[g])[gap[groups[g]] >= sep]
                if len(pool):
                    i = _draw(pool, weight, rng)
                    chosen.append(i)
                    gap = np.minimum(gap, np.hypot(*(xy - xy[i]).T))
                    gap[chosen] = -1.0
                else:
                    active.remove(g)
    return chosen


def _road_windows(net: Network, n: int, rng: np.random.Generator, size: float, traffic) -> list[Location]:
    """No junction candidates: windows on random car-lane points, ``size / 2`` apart where possible
    (with traffic: the points whose window holds the most vehicles first)."""
    if n == 0:
        return []
    xy, _ = net.random_road_points(max(4 * n, 32), rng)
    load = vehicles_in([Window(float(x), float(y), 0.0, size) for x, y in xy], traffic)
    order = np.argsort(-load, kind="stable").tolist()
    keep = order[:1]
    for i in order[1:]:
        if len(keep) < n and np.hypot(*(xy[keep] - xy[i]).T).min() >= 0.5 * size:
            keep.append(i)
    keep += [i for i in order if i not in keep][: n - len(keep)]
    return [Location(Window(float(xy[i, 0]), float(xy[i, 1]), 0.0, size), "road", None) for i in keep]
