"""How much traffic a demand has on the road at time T, without simulating it.

    est = DemandEstimate.at(net, ["city.rou.xml"], begin=28800.0)
    est.vehicles                       # en route at T: departed, not yet arrived at free flow
    est.window_density(net, window)    # vehicles per km of car lane, weighted as EdgeData's

Each vehicle, trip and flow departure of the route files up to ``begin`` is laid on its route
(a trip's: the shortest path by free-flow time, sumolib's Dijkstra, per from/to pair once) and
moved along it at :data:`TYPICAL_SPEED_FACTOR` of each edge's speed limit, waiting at the end of an
edge whose link to the next one a traffic light controls for that link's mean signal delay
(Webster's uniform delay at low saturation, C (1 - g/C)^2 / 2, from the light's program: the
network's, or an additional file's); those not yet at their end at ``begin`` count on the edge they
are on (a vehicle waiting at a red light on the edge it waits on). No simulation, as the issue
allows; it misses the queues of saturated links (Webster's other terms: a congested demand holds
more vehicles than this counts) and vTypes' own speed factors.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..map.network import window_square

TYPICAL_SPEED_FACTOR = 0.7   # urban traffic averages well below the limit (signals, turns)
HORIZON_S = 7200.0           # departures longer ago than this are not followed (none is en route)


@dataclass(frozen=True)
class EnRoute:
    """One of the demand's vehicles en route at ``begin``, where the estimate has it."""

    id: str                        # SUMO's id (a flow's k-th vehicle: ``flow.k``)
    type: str | None               # its ``type`` attribute (a vType or vTypeDistribution id)
    edges: tuple[str, ...]         # its route from the edge it is on to its end
    since: float                   # s it has been on that edge
    travel: float                  # s the edge takes at the typical speed (then it waits, if signalised)
    speed: float                   # m/s on that edge while moving
    behind: str | None = None      # the route's edge before it (where a queue that does not fit stands)

    @property
    def waiting(self) -> bool:
        """At the edge's end, waiting for its light (the signal delay)."""
        return self.since >= self.travel


@dataclass
class DemandEstimate:
    begin: float
    on_edge: dict[str, int]        # edge id -> vehicles on it at ``begin``
    vehicles: int                  # en route at ``begin``
    unrouted: int                  # trips with no path between their edges (not counted)
    departed: int                  # departures up to ``begin`` looked at
    en_route: list[EnRoute] = field(default_factory=list)   # each of them (``vehicles`` long)

    @classmethod
    def at(cls, net, route_files, begin: float, additional=()) -> DemandEstimate:
        from sumolib.xml import parse
        snet = net.sumo_net
        delay = signal_delays(net, additional)
        named: dict[str, list[str]] = {}
        paths: dict[tuple[str, str], list[str] | None] = {}
        on_edge: dict[str, int] = {}
        en_route: list[EnRoute] = []
        counts = {"unrouted": 0, "departed": 0}

        def edges_of(el) -> list[str] | None:
            if el.hasChild("route"):
                return el.getChild("route")[0].edges.split()
            if getattr(el, "route", None):
                return named.get(el.route)
            # sumolib names the attribute "from" (a Python keyword) attr_from
            a, b = getattr(el, "attr_from", None) or getattr(el, "from", None), getattr(el, "to", None)
            if not (a and b and snet.hasEdge(a) and snet.hasEdge(b)):
                return None
            if (a, b) not in paths:
                path, _ = snet.getShortestPath(snet.getEdge(a), snet.getEdge(b), vClass="passenger")
                paths[(a, b)] = [e.getID() for e in path] if path else None
            return paths[(a, b)]

        def lay(vid, vtype, edges, depart):
            counts["departed"] += 1
            if not edges:
                counts["unrouted"] += 1
                return
            t = begin - depart
            for k, (e, nxt) in enumerate(zip(edges, edges[1:] + [None])):
                if not snet.hasEdge(e):
                    return
                edge = snet.getEdge(e)
                speed = max(edge.getSpeed() * TYPICAL_SPEED_FACTOR, 0.1)
                travel = edge.getLength() / speed
                if t < travel + delay.get((e, nxt), 0.0):
                    on_edge[e] = on_edge.get(e, 0) + 1
                    en_route.append(EnRoute(vid, vtype, tuple(edges[k:]), t, travel, speed,
                                            edges[k - 1] if k else None))
                    return
                t -= travel + delay.get((e, nxt), 0.0)

        for path in route_files:       # named routes first: vehicles may refer to them
            for el in parse(path, "route"):
                if getattr(el, "id", None) and getattr(el, "edges", None):
                    named[el.id] = el.edges.split()
        for path in route_files:       # (one pass per kind: sumolib empties a child it also yields)
            for el in parse(path, ["vehicle", "trip", "flow"]):
                for k, depart in enumerate(_departures(el, begin)):
                    if begin - depart <= HORIZON_S:
                        vid = f"{el.id}.{k}" if el.name == "flow" else el.id
                        lay(vid, getattr(el, "type", None), edges_of(el), depart)
        return cls(begin, on_edge, sum(on_edge.values()), counts["unrouted"], counts["departed"], en_route)

    def edge_density(self, net) -> dict[str, float]:
        """Vehicles per km of car lane, per edge with vehicles (its sidewalks and bike lanes left out:
        the vehicles stand on the car lanes, and a region's density is taken over those)."""
        km = net.edge_car_km
        return {e: n / max(km.get(e, 0.0), 1e-3) for e, n in self.on_edge.items()}

    def window_density(self, net, window) -> float | None:
        """The window's density (:meth:`region_density` of its square)."""
        return self.region_density(net, window_square(window))

    def region_density(self, net, region) -> float | None:
        """The density in a shapely region: the estimated vehicles on its edges (each edge's density
        times its car-lane length inside the region; edges without estimated vehicles are empty) per
        km of all its car lane, the junctions' included, as a window's count is taken (round(D x
        car-lane km) holds the estimate's vehicles); None where it has no normal car lane."""
        dens = self.edge_density(net)
        idx, km = net.car_lanes_in_region(region)
        num = den = 0.0
        normal = False
        for i, k in zip(idx, km):
            if k <= 0:
                continue
            den += k
            if not net.lanes[i].internal:
                normal = True
                num += dens.get(net.lanes[i].edge, 0.0) * k
        return num / den if normal and den > 0 else None


def green_shares(paths) -> dict[str, tuple[float, np.ndarray]]:
    """Per traffic light, (cycle s, green share of each link index) of its program in ``paths``
    (the network, then additional files: a later file's program of a light replaces an earlier
    one, as SUMO loads them; of several programs in one file, the first). Green: ``G``/``g``/``s``,
    amber counted half."""
    from sumolib.xml import parse
    out: dict[str, tuple[float, np.ndarray]] = {}
    for path in paths:
        seen: set[str] = set()
        for tl in parse(path, "tlLogic"):
            if tl.id in seen or not tl.hasChild("phase"):
                continue
            seen.add(tl.id)
            phases = [(float(ph.duration), ph.state) for ph in tl.getChild("phase")]
            cycle = sum(d for d, _ in phases)
            if cycle <= 0:
                continue
            n = max(len(st) for _, st in phases)
            green = np.zeros(n)
            for d, st in phases:
                green[: len(st)] += d * np.array([1.0 if c in "Ggs" else 0.5 if c in "yY" else 0.0 for c in st])
            out[tl.id] = (cycle, green / cycle)
    return out


def signal_delays(net, additional=()) -> dict[tuple[str, str], float]:
    """Mean delay (s) at the stop line of each signalised (edge, next edge) pair: Webster's uniform
    delay at low saturation, C (1 - g/C)^2 / 2, averaged over the pair's lane-to-lane links."""
    if net.sumo_net is None or not getattr(net, "path", None):
        return {}
    shares = green_shares([net.path, *additional])
    sums: dict[tuple[str, str], list[float]] = {}
    for edge in net.sumo_net.getEdges(withInternal=False):
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                tls, idx = conn.getTLSID(), conn.getTLLinkIndex()
                if not tls or idx < 0 or tls not in shares or idx >= len(shares[tls][1]):
                    continue
                cycle, green = shares[tls]
                d = 0.5 * cycle * (1.0 - green[idx]) ** 2
                sums.setdefault((edge.getID(), conn.getTo().getID()), []).append(d)
    return {k: float(np.mean(v)) for k, v in sums.items()}


def _departures(el, begin: float) -> list[float]:
    """The departure times up to ``begin`` of a vehicle, trip or flow element."""
    def num(name):
        v = getattr(el, name, None)
        try:
            return None if v is None else float(v)
        except ValueError:      # "triggered", "now", ...: not a timed departure
            return None
    if el.name != "flow":
        d = num("depart")
        return [d] if d is not None and d <= begin else []
    start, end = num("begin") or 0.0, num("end")
    period = num("period")
    if period is None and num("vehsPerHour"):
        period = 3600.0 / num("vehsPerHour")
    if period is None and num("number") and end is not None:
        period = (end - start) / max(num("number"), 1.0)
    if period is None and num("probability"):
        period = 1.0 / num("probability")      # the expected spacing of a random flow
    if period is None or period <= 0:
        return []
    stop = min(begin, end if end is not None else begin)
    return list(np.arange(start, stop + 1e-9, period)) if stop >= start else []


__all__ = ["TYPICAL_SPEED_FACTOR", "DemandEstimate", "EnRoute", "green_shares", "signal_delays"]
