"""The demand's own vehicles at the fill's time, put on their lanes: where a fill with demand puts them.

    est = DemandEstimate.at(net, routes, begin)            # fill/demand.py: who is en route, on which edge
    placed, skipped = place_en_route(net, est, vtype_sizes([*routes, *additional]))
    placed[k].x, placed[k].y, placed[k].heading            # world pose of its box centre
    placed[k].vehicle.edges                                # the rest of its route

The estimate knows each vehicle's edge and how long it has been on it; here it gets a lane and a
place on it. The lane is one from which its route continues (SUMO's connections to its next edge;
any car lane on its last edge), the least occupied of those. A vehicle waiting at its light stands
in the queue from the stop line back; a moving one at the distance it has driven (its time on the
edge at the typical speed). Along a lane no two overlap: each front stays behind the back of the
vehicle ahead by SUMO's default minGap, queues first (longest waiting at the front), then the movers
from the furthest on; one that finds no room on any of its lanes stands back on the route's edges
before it, at the end of the queue there (a queue spilling back, as SUMO's do), else is skipped
(counted). A lane shared by both directions (an edge with a ``bidi`` edge: one road, its lanes on
top of each other's) takes one direction only, and only where the edge has no lane of its own
that the route may use: SUMO lets no vehicle onto a bidi lane an oncoming one is on, and two put
there face to face collide in the first step. Sizes are the
vTypes' (``length``/``width``, else SUMO's defaults for the vClass).

A fill with demand gives these positions to its tiles as tokens (pose and size); the model draws
each one's speed and motion around the others, and the seeder gives each the rest of its own route.
"""
from __future__ import annotations

import zlib
from collections import Counter
from dataclasses import dataclass, replace

from .demand import DemandEstimate, EnRoute

MIN_GAP = 2.5          # m, SUMO's default minGap: the space kept between two placed vehicles
STOP_MARGIN = 0.3      # m a queue's first front stays behind the stop line
# SUMO's vType defaults per vClass (length, width), sumo.dlr.de "Vehicle Type Parameter Defaults"
CLASS_SIZE = {"passenger": (5.0, 1.8), "private": (5.0, 1.8), "taxi": (5.0, 1.8), "evehicle": (5.0, 1.8),
              "delivery": (6.5, 2.16), "emergency": (6.5, 2.16), "authority": (5.0, 1.8),
              "army": (5.0, 1.8), "vip": (5.0, 1.8), "custom1": (5.0, 1.8), "custom2": (5.0, 1.8),
              "truck": (7.1, 2.4), "trailer": (16.5, 2.55), "bus": (12.0, 2.5), "coach": (14.0, 2.6),
              "motorcycle": (2.2, 0.9), "moped": (2.1, 0.8)}
DEFAULT_SIZE = CLASS_SIZE["passenger"]   # DEFAULT_VEHTYPE


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


def vtype_sizes(paths) -> dict[str, tuple[float, float]]:
    """(length, width) of every vType in ``paths`` (route and additional files) by id, and of every
    vTypeDistribution (its first member's)."""
    from .travel import vtype_table

    def size(el) -> tuple[float, float]:
        cls_len, cls_wid = CLASS_SIZE.get(getattr(el, "vClass", None) or "passenger", DEFAULT_SIZE)
        return (float(getattr(el, "length", None) or cls_len), float(getattr(el, "width", None) or cls_wid))
    return vtype_table(paths, size)


def write_vtypes(route_files, path: str) -> list[str]:
    """An additional file at ``path`` with the vType and vTypeDistribution definitions of
    ``route_files`` (top level; a distribution with the vTypes inside it), so that a SUMO started
    without the demand knows its types; returns their ids ([]: none, no file written)."""
    import xml.etree.ElementTree as ET
    found: list = []
    for f in route_files:
        for _, el in ET.iterparse(f, events=("end",)):
            if el.tag in ("vType", "vTypeDistribution") and el.get("id") and \
                    el.get("id") not in {e.get("id") for e in found}:
                found.append(el)
            elif el.tag in ("vehicle", "trip", "flow", "route", "person", "personFlow"):
                el.clear()     # a large demand is read without holding it
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


def _fit(lanes: list[int], vid: str, want: float | None, length: float, room: dict, used: Counter, net,
         shared: dict[int, int], taken: set[int]):
    """(lane, front) for a vehicle of ``length`` whose front would be at ``want`` (None: as far
    forward as the lane allows) on the least used of ``lanes`` where it fits (a lane of its own
    before one shared with the other direction, never one the other direction has ``taken``),
    else None."""
    for lane in sorted(lanes, key=lambda i: (i in shared, used[i], _stable(f"{vid}/{i}"))):
        if lane in taken:
            continue
        end = net.lanes[lane].length
        front = min(room.get(lane, end - STOP_MARGIN), end - STOP_MARGIN)
        if want is not None:
            front = min(front, max(want, length))
        if front - length >= 0.0:
            return lane, front
    return None


def place_en_route(net, est: DemandEstimate, sizes: dict[str, tuple[float, float]] | None = None
                   ) -> tuple[list[Placed], list[EnRoute]]:
    """(the placed vehicles, those without room on any of their lanes); deterministic."""
    snet, sizes = net.sumo_net, sizes or {}
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
        return (0, -(v.since - v.travel), v.id) if v.waiting else (1, -(v.offset + v.since * v.speed), v.id)

    room: dict[int, float] = {}                  # lane -> where the next front may be at most
    used: Counter = Counter()                    # lane -> vehicles placed on it
    shared = net.shared_lanes
    taken: set[int] = set()                      # shared lanes the other direction is on
    placed: list[Placed] = []
    skipped: list[EnRoute] = []
    for v in sorted(est.en_route, key=order):
        length, width = sizes.get(v.type, DEFAULT_SIZE) if v.type else DEFAULT_SIZE
        want = None if v.waiting else v.offset + v.since * v.speed
        best = _fit(lanes_for(v.edges), v.id, want, length, room, used, net, shared, taken)
        for k in range(len(v.behind) if best is None else 0):
            # a queue longer than its edge stands back on the route's edges before it, as a queue
            # spills back in SUMO (a short edge before a light; a long red on a short block)
            edges = v.behind[k::-1] + v.edges
            best = _fit(lanes_for(edges), v.id, None, length, room, used, net, shared, taken)
            if best is not None:
                v = replace(v, edges=edges, since=0.0, behind=v.behind[k + 1:], offset=0.0)
                break
        if best is None:
            skipped.append(v)
            continue
        lane, front = best
        room[lane] = front - length - MIN_GAP      # the vehicles come front-most first on each lane
        used[lane] += 1
        if lane in shared:
            taken.add(shared[lane])
        xy, heading = net.lane_pose(lane, front - 0.5 * length)
        placed.append(Placed(v, lane, float(front), float(xy[0]), float(xy[1]), heading, length, width))
    return placed, skipped


__all__ = ["CLASS_SIZE", "Placed", "place_en_route", "vtype_sizes", "write_vtypes"]
