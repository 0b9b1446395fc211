"""Builders for networks/build.py shaped like the OpenStreetMap cities the project is judged on
(the ``train_wide`` split beside ``train``).

The real cities (RESCO's Cologne and Ingolstadt, Berlin, Wildau) differ from the first training
networks in ways these builders aim at: short edges (median 30-110 m) meeting at uneven angles,
dead ends, 30 km/h zones with right-before-left junctions beside 50 km/h main roads, 10-20 % one-way
streets, 2-4 lane arterials with turn pockets, and traffic lights of both kinds, fixed-time
(``static``) and ``actuated``. Each builder makes a street graph with netgenerate (``--rand`` or
``--grid``, written as plain XML), gives its streets classes (arterial / collector / residential:
lanes, speed, priority, one-way, junction control) and converts the result with netconvert.
"""
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from _city import strongly_connected
from _organic import bent_shape
from _specs import PEDESTRIANS, node, road

POCKET = 35.0       # m: length of the left-turn pocket added before a traffic light
PLAIN = "base"      # prefix of netgenerate's plain-XML output in the build directory


@dataclass
class Street:
    """An undirected street between two graph nodes; a one-way street runs from its first node."""
    cls: str = "residential"
    lanes: int = 1
    speed: float = 8.33
    priority: int = 1
    oneway: bool = False


@dataclass
class Style:
    """How a builder classes its streets (speeds in m/s, shares of residential streets)."""
    arterial_lanes: int = 2
    arterial_speed: float = 13.89
    collector_speed: float = 13.89
    zone_speeds: tuple = (8.33,)        # right-before-left residential zones
    other_speeds: tuple = (13.89,)      # residential streets outside the zones
    p_zone: float = 0.5                 # share of districts that are right-before-left zones
    p_oneway: float = 0.15
    p_actuated: float = 0.5             # share of the traffic lights that are actuated
    bend: float = 0.06                  # s.d. of a street's bend, as a share of its length
    pockets: bool = True


def street_graph(ws, *args):
    """netgenerate's street graph: ({node id: (x, y)}, {(a, b): Street()} one per street)."""
    ws.netgenerate(*args, "--plain-output-prefix", PLAIN)
    nodes = {n.get("id"): (float(n.get("x")), float(n.get("y")))
             for n in ET.parse(os.path.join(ws.tmpdir, PLAIN + ".nod.xml")).getroot().iter("node")}
    streets = {}
    for e in ET.parse(os.path.join(ws.tmpdir, PLAIN + ".edg.xml")).getroot().iter("edge"):
        a, b = e.get("from"), e.get("to")
        if (b, a) not in streets and a != b:
            streets[(a, b)] = Street()
    return nodes, streets


def shortest_path(nodes, streets, src, dst):
    """Node ids of the shortest path (by straight-line length) from ``src`` to ``dst``."""
    ids = sorted(nodes)
    index = {n: i for i, n in enumerate(ids)}
    rows, cols, w = [], [], []
    for a, b in streets:
        d = math.dist(nodes[a], nodes[b])
        rows += [index[a], index[b]]
        cols += [index[b], index[a]]
        w += [d, d]
    graph = csr_matrix((w, (rows, cols)), shape=(len(ids), len(ids)))
    _, pred = dijkstra(graph, indices=index[src], return_predecessors=True)
    path, k = [dst], index[dst]
    while k != index[src]:
        k = pred[k]
        if k < 0:
            return []
        path.append(ids[k])
    return path[::-1]


def extreme(nodes, direction):
    """The node farthest along ``direction`` (a unit vector)."""
    return max(sorted(nodes), key=lambda n: nodes[n][0] * direction[0] + nodes[n][1] * direction[1])


def mark(streets, path, cls):
    """Give the streets along ``path`` the class ``cls`` (an arterial stays one)."""
    for a, b in zip(path, path[1:]):
        key = (a, b) if (a, b) in streets else (b, a)
        if streets[key].cls != "arterial":
            streets[key].cls = cls


def routes_across(nodes, streets, pairs, cls):
    """Mark the shortest paths between the extreme nodes of each pair of directions (degrees)."""
    for d0, d1 in pairs:
        src = extreme(nodes, (math.cos(math.radians(d0)), math.sin(math.radians(d0))))
        dst = extreme(nodes, (math.cos(math.radians(d1)), math.sin(math.radians(d1))))
        mark(streets, shortest_path(nodes, streets, src, dst), cls)


def district(xy, nodes, rng_cells):
    """The 3x3 district cell of a point within the nodes' bounding box."""
    xs, ys = [p[0] for p in nodes.values()], [p[1] for p in nodes.values()]
    i = min(2, int(3 * (xy[0] - min(xs)) / max(1e-6, max(xs) - min(xs))))
    j = min(2, int(3 * (xy[1] - min(ys)) / max(1e-6, max(ys) - min(ys))))
    return rng_cells[(i, j)]


def dress(rng, nodes, streets, style):
    """Lanes, speeds and priorities by class; residential speeds by district; some one-way streets
    (kept only while every node still reaches every other)."""
    zones = {(i, j): bool(rng.random() < style.p_zone) for i in range(3) for j in range(3)}
    for (a, b), s in sorted(streets.items()):
        mid = ((nodes[a][0] + nodes[b][0]) / 2, (nodes[a][1] + nodes[b][1]) / 2)
        if s.cls == "arterial":
            s.lanes, s.speed, s.priority = style.arterial_lanes, style.arterial_speed, 3
        elif s.cls == "collector":
            s.lanes, s.speed, s.priority = 1, style.collector_speed, 2
        else:
            speeds = style.zone_speeds if district(mid, nodes, zones) else style.other_speeds
            s.speed = float(rng.choice(speeds))
    residential = [k for k in sorted(streets) if streets[k].cls == "residential"]
    for idx in rng.permutation(len(residential))[: int(style.p_oneway * len(residential))]:
        key = residential[idx]
        s = streets.pop(key)
        s.oneway = True
        new = key if rng.random() < 0.5 else key[::-1]
        streets[new] = s
        if not strongly_connected(arcs(streets)):
            del streets[new]
            s.oneway = False
            streets[key] = s
    return zones


def arcs(streets):
    return {a for (p, q), s in streets.items() for a in ([(p, q)] if s.oneway else [(p, q), (q, p)])}


def control(nodes, streets, zones, rng, style):
    """Junction type of each node from the classes of its streets: lights where two main roads
    cross (a ``p_actuated`` share of them actuated, the others fixed-time), right-before-left among
    residential streets in a zone, priority elsewhere, netconvert's choice at a dead end."""
    classes = {n: [] for n in nodes}
    for (a, b), s in streets.items():
        classes[a].append(s.cls)
        classes[b].append(s.cls)
    out = {}
    for n in sorted(nodes):
        c = classes[n]
        major = sum(k != "residential" for k in c)
        if len(c) <= 1:
            out[n] = node(n, *nodes[n])
        elif major >= 3 and len(c) >= 3 and "arterial" in c:
            out[n] = node(n, *nodes[n], "traffic_light")
        elif major == 0 and district(nodes[n], nodes, zones):
            out[n] = node(n, *nodes[n], "right_before_left")
        else:
            out[n] = node(n, *nodes[n], "priority")
    lights = [n for n in sorted(out) if out[n].get("type") == "traffic_light"]
    actuated = set(rng.permutation(len(lights))[: int(round(style.p_actuated * len(lights)))])
    for k, n in enumerate(lights):
        out[n]["tlType"] = "actuated" if k in actuated else "static"
    return out


def edges_of(nodes, streets, junctions, rng, style):
    """Plain edges of the streets (bent a little; a left-turn pocket before a traffic light on a
    street of more than one lane)."""
    edges = []
    for (a, b), s in sorted(streets.items()):
        bend = float(rng.normal(0.0, style.bend)) * math.dist(nodes[a], nodes[b])
        shape = bent_shape(nodes[a], nodes[b], bend) if abs(bend) > 1.0 else None
        pair = road(a, b, s.lanes, s.speed, priority=s.priority, shape=shape, two_way=not s.oneway)
        for e in pair:
            long_enough = math.dist(nodes[e["from"]], nodes[e["to"]]) > 2.5 * POCKET
            if style.pockets and s.lanes > 1 and long_enough and \
                    junctions[e["to"]].get("type") == "traffic_light":
                e["numLanes"] = s.lanes + 1
                e["splits"] = [{"pos": -POCKET, "lanes": " ".join(map(str, range(s.lanes + 1)))},
                               {"pos": 0, "lanes": " ".join(map(str, range(s.lanes)))}]
        edges += pair
    return edges


def finish(ws, nodes, streets, style, *args):
    """Dress, control and convert the street graph."""
    rng = ws.rng()
    zones = dress(rng, nodes, streets, style)
    used = {n for k in streets for n in k}
    nodes = {n: p for n, p in nodes.items() if n in used}
    junctions = control(nodes, streets, zones, rng, style)
    edges = edges_of(nodes, streets, junctions, rng, style)
    ws.netconvert([junctions[n] for n in sorted(junctions)], edges, "--no-turnarounds.tls", *args)


def osm_irregular(ws):
    """OSM-like irregular net (--rand, 35-130 m edges, angles down to 20 deg, dead ends): two
    crossing 2-lane arterials (13.89 m/s) widening to 3 lanes (left-turn pocket) before their
    actuated / fixed-time lights, collectors, residential streets in 30 km/h right-before-left zones
    (8.33 m/s, some 5.56) or priority districts (13.89), some one-way, bent edges, sidewalks."""
    nodes, streets = street_graph(ws, "--rand", "--rand.iterations", 110, "--rand.min-distance", 35,
                                  "--rand.max-distance", 130, "--rand.min-angle", 20,
                                  "--rand.connectivity", 0.85, "-L", 1, "-S", 13.89)
    routes_across(nodes, streets, [(180, 0), (270, 90)], "arterial")
    routes_across(nodes, streets, [(225, 45), (135, 315)], "collector")
    finish(ws, nodes, streets, Style(zone_speeds=(8.33, 8.33, 8.33, 5.56),
                                     p_actuated=0.6), *PEDESTRIANS)


def osm_suburb(ws):
    """OSM-like suburb (--rand, 50-180 m edges, many dead ends): one 2-lane arterial (13.89 m/s)
    with fixed-time lights, 13.89 m/s collectors, residential streets mostly in 30 km/h
    right-before-left zones (8.33 m/s, some 5.56) or at 11.11-13.89 m/s, some one-way, bent edges."""
    nodes, streets = street_graph(ws, "--rand", "--rand.iterations", 90, "--rand.min-distance", 50,
                                  "--rand.max-distance", 180, "--rand.min-angle", 25,
                                  "--rand.connectivity", 0.7, "-L", 1, "-S", 13.89)
    routes_across(nodes, streets, [(200, 20)], "arterial")
    routes_across(nodes, streets, [(270, 90), (135, 315)], "collector")
    finish(ws, nodes, streets, Style(zone_speeds=(8.33, 8.33, 5.56), other_speeds=(11.11, 13.89),
                                     p_zone=0.7, p_oneway=0.1, p_actuated=0.0, bend=0.1))


def grid_line(streets, is_line, cls):
    """Give the grid streets along lines ``is_line(a, b)`` (netgenerate's node ids: column letter,
    row number) the class ``cls``."""
    for (a, b), s in streets.items():
        if is_line(a, b):
            s.cls = cls if s.cls != "arterial" else s.cls


def col(n):
    return n.rstrip("0123456789")


def row(n):
    return int(n[len(col(n)):])


def arterial_lights(ws):
    """Multi-lane arterial grid (8x6 jittered lattice, 95-125 m): 3-lane arterials (13.89 m/s)
    widening to 4 lanes (left-turn pocket) before the lights where they cross each other or a
    collector, half actuated and half fixed-time; 1-lane 8.33-13.89 m/s side streets (priority /
    right-before-left), some one-way, sidewalks + crossings."""
    nodes, streets = street_graph(ws, "--grid", "--grid.x-number", 8, "--grid.y-number", 6,
                                  "--grid.x-length", 125, "--grid.y-length", 95,
                                  "--perturb-x", "norm(0,7)", "--perturb-y", "norm(0,7)", "-L", 1, "-S", 13.89)
    grid_line(streets, lambda a, b: row(a) == row(b) and row(a) in (1, 4), "arterial")
    grid_line(streets, lambda a, b: col(a) == col(b) and col(a) in ("B", "E", "G"), "arterial")
    grid_line(streets, lambda a, b: col(a) == col(b) and col(a) == "D", "collector")
    finish(ws, nodes, streets, Style(arterial_lanes=3, p_zone=0.4,
                                     p_actuated=0.5, bend=0.02), *PEDESTRIANS)


def dense_urban_grid(ws):
    """Dense inner-city grid (10x9, 55-75 m blocks, jittered): 1-lane residential streets in 30 km/h
    right-before-left zones (8.33 m/s) or priority districts (13.89), a tenth one-way, two 2-lane
    13.89 m/s main streets with fixed-time and actuated lights, collectors, sidewalks + crossings."""
    nodes, streets = street_graph(ws, "--grid", "--grid.x-number", 10, "--grid.y-number", 9,
                                  "--grid.x-length", 70, "--grid.y-length", 58,
                                  "--perturb-x", "norm(0,5)", "--perturb-y", "norm(0,5)", "-L", 1, "-S", 13.89)
    grid_line(streets, lambda a, b: row(a) == row(b) and row(a) == 4, "arterial")
    grid_line(streets, lambda a, b: col(a) == col(b) and col(a) == "E", "arterial")
    grid_line(streets, lambda a, b: (row(a) == row(b) and row(a) == 7) or (col(a) == col(b) and col(a) == "H"),
              "collector")
    finish(ws, nodes, streets, Style(zone_speeds=(8.33,), other_speeds=(13.89,), p_zone=0.6, p_oneway=0.25,
                                     p_actuated=0.3, bend=0.0), *PEDESTRIANS)
