"""The demand's own vehicles at the fill's time, put on their lanes: where a fill with demand puts them.

    est = DemandEstimate.at(net, routes, begin)            # fill/demand.py: who is en route, on which edge
    placed, skipped = place_en_route(net, est, vtype_bodies([*routes, *additional]))   # fill/vtypes.py
    placed[k].x, placed[k].y, placed[k].heading            # world pose of its box centre
    placed[k].vehicle.edges                                # the rest of its route

The estimate knows each vehicle's edge and how long it has been on it; here it gets a lane and a
place on it. The lane is one from which its route continues (SUMO's connections to its next edge;
any car lane on its last edge), the least occupied of those. A vehicle waiting at its light stands
in the queue from the stop line back; a moving one at the distance it has driven (its time on the
edge at the typical speed). Along a lane no two overlap: each front stays behind the back of the
vehicle ahead by its vType's minGap, queues first (longest waiting at the front), then the movers
from the furthest on; one that finds no room on any of its lanes stands back on the route's edges
before it, at the end of the queue there (a queue spilling back, as SUMO's do), else is skipped
(counted). A lane shared by both directions (an edge with a ``bidi`` edge: one road, its lanes on
top of each other's) takes one direction only, and only where the edge has no lane of its own
that the route may use: SUMO lets no vehicle onto a bidi lane an oncoming one is on, and two put
there face to face collide in the first step. Sizes and gaps are the
vTypes' (``length``/``width``/``minGap``, else SUMO's defaults for the vClass).

A fill with demand gives these positions to its tiles as tokens (pose and size); the model draws
each one's speed and motion around the others, and the seeder gives each the rest of its own route.
"""
from __future__ import annotations

import zlib
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from .demand import DemandEstimate, EnRoute
from .vtypes import DEFAULT_BODY, Body

STOP_MARGIN = 0.3      # m a queue's first front stays behind the stop line
# m a vehicle standing at its stop has its front behind the stop's end: inside SUMO's shortest stop
# (2 x POSITION_EPS, 0.2 m), so that rounding never puts it past the stop (then passed, dropped)
AT_STOP_M = 0.05


@dataclass(frozen=True)
class Placed:
    vehicle: EnRoute
    lane: int              # index into Network.lanes
    pos: float             # m of its front bumper along the lane (SUMO's lane position)
    x: float               # world centre of its box
    y: float
    heading: float         # rad, the lane's there
    length: float
    width: float
    # parked at T in a ``<space>`` of its parking area: SUMO enters every space from the area's end
    space: bool = False


def write_vtypes(route_files, path: str) -> list[str]:
    """An additional file at ``path`` with the vType and vTypeDistribution definitions of
    ``route_files`` (top level; a distribution with the vTypes inside it), so that a SUMO started
    without the demand knows its types; returns their ids ([]: none, no file written)."""
    import copy
    import xml.etree.ElementTree as ET

    from ..core.sumo_xml import elements
    found: list = []
    # read as SUMO reads them (core.sumo_xml: includes, gzip, any root); the reader lets each
    # element go once handed over, so the definitions kept are copies
    for _, el in elements(route_files, ("vType", "vTypeDistribution")):
        if el.get("id") and el.get("id") not in {e.get("id") for e in found}:
            found.append(copy.deepcopy(el))
    # a vType inside a distribution is defined with it: not again on its own
    inner = {c.get("id") for e in found if e.tag == "vTypeDistribution" for c in e}
    found = [e for e in found if e.get("id") not in inner]
    if not found:
        return []
    root = ET.Element("additional")
    root.extend(found)
    ET.ElementTree(root).write(path, encoding="unicode")
    return [e.get("id") for e in found]


def _stable(text: str) -> int:
    return zlib.crc32(text.encode())


def _fit(lanes: list[int], vid: str, want: float | None, body: Body, room: dict, used: Counter, net,
         shared: dict[int, int], taken: set[int]):
    """(lane, front) for a vehicle of ``body`` whose front would be at ``want`` (None: as far
    forward as the lane allows, its minGap behind the back of the one ahead) on the least used of
    ``lanes`` where it fits (a lane of its own before one shared with the other direction, never one
    the other direction has ``taken``), else None."""
    for lane in sorted(lanes, key=lambda i: (i in shared, used[i], _stable(f"{vid}/{i}"))):
        if lane in taken:
            continue
        end = net.lanes[lane].length
        front = min(room.get(lane, np.inf) - body.min_gap, end - STOP_MARGIN)
        if want is not None:
            front = min(front, max(want, body.length))
        if front - body.length >= 0.0:
            return lane, front
    return None


def _at_stop(v: EnRoute, parked: Counter, lanes: list[int], edge_lanes: list[int], net
             ) -> tuple[float, list[int], bool]:
    """(front, lanes, in a space) of a vehicle standing at its stop: at the stop's end, on the stop's
    lane (of ``edge_lanes``, its edge's it may use; else ``lanes``). In a parking area SUMO fills its
    roadside lots first, this one at the next free one back from the area's end (``parked``: per area
    the vehicles placed in it), then its ``<space>``s, which SUMO enters from the area's end: there (one
    behind the other on the lane, the placement's room; the seeding moves it to the end,
    fill/seed.py), never at a roadside lot beyond the area's start."""
    area = (v.edges[0], v.stop_at)
    k = parked[area]
    parked[area] += v.lots is not None
    roadside = v.lots is not None and k < v.lots.roadside
    front = v.stop_at - AT_STOP_M - (k * v.lots.spacing if roadside else 0.0)
    on_stop_lane = [i for i in edge_lanes if net.lanes[i].id == v.stop_lane]
    return front, on_stop_lane or lanes, v.lots is not None and not roadside


def allows(net, lane: int, vclass: str) -> bool:
    """Whether the lane (index into ``Network.lanes``) permits ``vclass``."""
    return net.sumo_net.getLane(net.lanes[lane].id).allows(vclass)


def place_en_route(net, est: DemandEstimate, bodies: dict[str, Body] | None = None,
                   classes: dict[str, str] | None = None) -> tuple[list[Placed], list[EnRoute]]:
    """(the placed vehicles, those without room on any of their lanes); deterministic. ``bodies``:
    per vType id its size and minGap (:func:`~.vtypes.vtype_bodies`; SUMO's default car else);
    ``classes``: per vType id its vClass, whose vehicles stand only on the car lanes that permit it
    (a bicycle on an edge whose car lanes forbid bicycles rides its bike lane: not one of ours)."""
    snet, bodies, classes = net.sumo_net, bodies or {}, classes or {}
    by_edge: dict[str, dict[int, int]] = {}      # edge -> lane index on the edge -> Network.lanes index
    for i, ln in enumerate(net.lanes):
        if ln.car and not ln.internal:
            by_edge.setdefault(ln.edge, {})[ln.index] = i

    def lanes_for(edges: tuple[str, ...]) -> list[int]:
        mine = by_edge.get(edges[0], {})
        if len(edges) > 1 and snet.hasEdge(edges[0]) and snet.hasEdge(edges[1]):
            conns = snet.getEdge(edges[0]).getConnections(snet.getEdge(edges[1]))
            linked = sorted({mine[c.getFromLane().getIndex()] for c in conns if c.getFromLane().getIndex() in mine})
            if linked:
                return linked
        return [mine[k] for k in sorted(mine)]

    # queues first, longest waiting at the front; then the movers, furthest along first; ties by id
    def order(v: EnRoute):
        return (0, -(v.since - v.travel), v.id) if v.waiting else (1, -v.front, v.id)

    room: dict[int, float] = {}                  # lane -> the back of its last vehicle
    used: Counter = Counter()                    # lane -> vehicles placed on it
    shared = net.shared_lanes
    taken: set[int] = set()                      # shared lanes the other direction is on
    parked: Counter = Counter()                  # (edge, parking area's end) -> vehicles placed in its lots
    placed: list[Placed] = []
    skipped: list[EnRoute] = []
    for v in sorted(est.en_route, key=order):
        body = bodies.get(v.type, DEFAULT_BODY) if v.type else DEFAULT_BODY
        length, width = body.length, body.width
        vclass = classes.get(v.type) if v.type else None

        def permitted(lanes: list[int]) -> list[int]:
            return lanes if vclass is None else [i for i in lanes if allows(net, i, vclass)]
        want, lanes, space = None if v.waiting else v.front, permitted(lanes_for(v.edges)), False
        if v.stopped is not None:
            want, lanes, space = _at_stop(v, parked, lanes, permitted(list(by_edge.get(v.edges[0], {}).values())), net)
        best = _fit(lanes, v.id, want, body, room, used, net, shared, taken)
        for k in range(len(v.behind) if best is None else 0):
            # a queue longer than its edge stands back on the route's edges before it, as a queue
            # spills back in SUMO (a short edge before a light; a long red on a short block)
            edges = v.behind[k::-1] + v.edges
            best = _fit(permitted(lanes_for(edges)), v.id, None, body, room, used, net, shared, taken)
            if best is not None:
                v = replace(v, edges=edges, since=0.0, behind=v.behind[k + 1:], offset=0.0)
                break
        if best is None:
            skipped.append(v)
            continue
        lane, front = best
        room[lane] = front - length                # the vehicles come front-most first on each lane
        used[lane] += 1
        if lane in shared:
            taken.add(shared[lane])
        xy, heading = net.lane_pose(lane, front - 0.5 * length)
        placed.append(Placed(v, lane, float(front), float(xy[0]), float(xy[1]), heading, length, width, space))
    return placed, skipped


__all__ = ["Placed", "allows", "place_en_route", "write_vtypes"]
