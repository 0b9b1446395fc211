"""How much traffic a demand has on the road at time T, without simulating it.

    est = DemandEstimate.at(net, ["city.rou.xml"], begin=28800.0)
    est.vehicles                       # en route at T: departed, not yet arrived
    est.window_density(net, window)    # vehicles per km of car lane, weighted as EdgeData's

Each vehicle, trip and flow departure of the route files up to ``begin`` is laid on the route SUMO
gives it (SUMO's router reads every form of a route file: :mod:`.routing`) and run along it as queues (:mod:`.queues`) by the clock of :mod:`.travel` (its vType's desired
speed, the junctions' internal lanes and the time lost slowing for them, giving way, the start
from standing): a light with a fixed program (SUMO's ``static``) lets its vehicles through as
SUMO's clock runs it, in the order they reach its stop line, in its green only, so the queues
stand at ``begin`` on the approaches that are red then; an actuated light holds each vehicle its
expected (Webster's) delay at the degree of saturation the demand's own flows give it; an edge
holds what its lanes hold, and a queue that fills it spills back; a stop holds its vehicle where
it ends for its duration (or to its until), braking to it and starting again. Those not yet at their end at
``begin`` count on the edge they are on (a vehicle waiting at a light on the edge it waits on,
one crossing a junction at the start of the edge it enters; one still waiting to be inserted
not at all; one at its stop knows how long it has stood there: :attr:`EnRoute.stopped`). No
simulation of the cars, as the issue allows: it misses what :mod:`.travel` and :mod:`.queues` leave
out (lane changes, the choice of lanes).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..map.network import window_square
from ..sim.scenario import SUMO_DEFAULT_SEED

HORIZON_S = 7200.0           # departures longer ago than this are not followed (none is en route)
FLOW_SPAN_S = 3600.0         # the lights' load is the demand's flow over this long before --begin
SPILL_EDGES = 3              # a queue longer than its edge stands back over this many of the route's edges


@dataclass(frozen=True)
class EnRoute:
    """One of the demand's vehicles en route at ``begin``, where the estimate has it."""

    id: str                        # SUMO's id (a flow's k-th vehicle: ``flow.k``)
    type: str | None               # its ``type`` attribute (a vType or vTypeDistribution id)
    edges: tuple[str, ...]         # its route from the edge it is on to its end
    since: float                   # s it has been on that edge
    travel: float                  # s the edge takes at the typical speed (then it waits, if signalised)
    speed: float                   # m/s on that edge while moving
    behind: tuple[str, ...] = ()   # the route's edges before it, nearest first (where a queue that does
                                   # not fit its edge stands: :data:`SPILL_EDGES` of them)
    offset: float = 0.0            # m along the edge where it began moving on it (its departPos)
    stops: tuple[dict, ...] = ()   # its route's <stop>s (attributes; the seeder keeps those ahead)
    stop: int | None = None        # the one of ``stops`` it makes on this edge (None: none here)
    stop_at: float = 0.0           # m along the edge where that stop ends (where its front stands)
    to_stop: float = 0.0           # s after entering the edge it reaches that stop
    hold: float = 0.0              # s it stands there (its duration, or to its until)
    lots: Lots | None = None       # the lots of the parking area that stop is at (None: no parking area)
    stop_lane: str | None = None   # the lane that stop is on

    @property
    def waiting(self) -> bool:
        """At the edge's end, waiting for its light (the signal delay)."""
        return self.since >= self.travel

    @property
    def stopped(self) -> float | None:
        """The seconds it has stood at its stop on this edge at ``begin``; None: not standing at one."""
        if self.stop is None or not self.to_stop <= self.since < self.to_stop + self.hold:
            return None
        return self.since - self.to_stop

    @property
    def front(self) -> float:
        """m along the edge where its front is while it moves (or stands at its stop): at the typical
        speed from where it began on the edge, the time at its stop left out."""
        if self.stop is None:
            return self.offset + self.since * self.speed
        if self.since < self.to_stop:
            return self.offset + (self.stop_at - self.offset) * self.since / max(self.to_stop, 1e-6)
        length, after = self.offset + self.speed * self.travel, self.to_stop + self.hold
        share = (self.since - after) / max(self.travel - after, 1e-6)
        return self.stop_at + (length - self.stop_at) * min(max(share, 0.0), 1.0)

    def stops_left(self, late: float = 0.0) -> tuple[dict, ...]:
        """Its stops as the seeded vehicle is given them: the one it stands at with what remains of
        its ``duration`` (SUMO ends a stop ``duration`` after it began, or at its ``until``), less
        ``late``: the seconds after ``begin`` the seeded vehicle begins it."""
        from ..sim.stops import stop_seconds
        stood = self.stopped
        if stood is None or not self.stops[self.stop].get("duration"):
            return self.stops
        rest = max(stop_seconds(self.stops[self.stop]) - stood - late, 0.0)
        return self.stops[:self.stop] + (dict(self.stops[self.stop], duration=f"{rest:.3f}"),) + self.stops[self.stop + 1:]


@dataclass
class DemandEstimate:
    begin: float
    on_edge: dict[str, int]        # edge id -> vehicles on it at ``begin``
    vehicles: int                  # en route at ``begin``
    unrouted: int                  # trips with no path between their edges (not counted)
    departed: int                  # departures up to ``begin`` looked at
    en_route: list[EnRoute] = field(default_factory=list)   # each of them (``vehicles`` long)

    @classmethod
    def at(cls, net, route_files, begin: float, additional=(), due: float | None = None,
           depart_speed: str | None = None, junction_taz: bool = False, scale: str | None = None,
           sumo_random: tuple[int, tuple[str, ...]] = (SUMO_DEFAULT_SEED, ())) -> DemandEstimate:
        """The departures up to ``begin`` and, with ``due`` (> ``begin``), those before ``due`` too, as
        if departing at ``begin``: a fill's state is saved a seeding step after ``begin``, and SUMO
        started from it skips the demand's departures before that time, so the fill carries them.
        ``depart_speed``: SUMO's ``default.departspeed`` the demand runs with (None: the installed
        SUMO's); ``junction_taz``, ``scale``: its ``junction-taz`` and ``scale`` options; ``sumo_random``:
        the seed and random options it runs under (sim.scenario.own_random; SUMO's default seed unless
        given). Raises :class:`~.routing.RoutingError` when SUMO's router cannot read the demand."""
        from .queues import Trip, run_to
        from .routing import routed_departures
        from .travel import DEFAULT_DRIVER, TravelTimes, link_flows, vtype_drivers
        snet = net.sumo_net
        drivers = vtype_drivers([*route_files, *additional])
        departures, unrouted = routed_departures(net.path, route_files, additional, until=max(begin, due or begin),
                                                 since=begin - HORIZON_S, depart_speed=depart_speed,
                                                 junction_taz=junction_taz, scale=scale,
                                                 sumo_random=sumo_random)
        if due is not None and due > begin:
            departures = [replace(d, depart=min(d.depart, begin)) for d in departures if d.depart < due]
        # the lights' load: the demand's flow through each link over the last hour (or since it began)
        first = min((d.depart for d in departures), default=begin)
        span = min(FLOW_SPAN_S, begin - first)
        times = TravelTimes(net, additional, link_flows([(d.depart, list(d.edges)) for d in departures], begin, span))
        trips: list[Trip] = []
        stops = _Stops(net, [*route_files, *additional], additional) if any(d.stops for d in departures) else None
        made: dict[int, tuple] = {}                # id(trip) -> (its stops, per edge the one made there)
        for d in departures:
            if not all(snet.hasEdge(e) for e in d.edges):
                continue
            driver = drivers.get(d.type, DEFAULT_DRIVER) if d.type else DEFAULT_DRIVER
            own, which, clock = stops.resolve(d) if stops else ((), (), ())
            trips.append(Trip(d.id, d.type, d.edges, driver, d.depart,
                              times.start(driver, d.edges[0]) if d.standing else 0.0,
                              _depart_offset(d.depart_pos, snet.getEdge(d.edges[0]).getLength()), *clock))
            made[id(trips[-1])] = (own, which)
        on_edge: dict[str, int] = {}
        en_route: list[EnRoute] = []
        for pos in run_to(trips, times, net, begin):
            edges, k = pos.trip.edges, pos.k
            on_edge[edges[k]] = on_edge.get(edges[k], 0) + 1
            ahead = snet.getEdge(edges[k]).getLength() - pos.offset
            en_route.append(EnRoute(pos.trip.id, pos.trip.type, edges[k:], begin - pos.t_enter, pos.travel,
                                    ahead / pos.travel, edges[max(k - SPILL_EDGES, 0):k][::-1], pos.offset,
                                    **(stops.here(pos, *made[id(pos.trip)]) if stops else {})))
        return cls(begin, on_edge, sum(on_edge.values()), unrouted, len(departures), en_route)

    def edge_density(self, net) -> dict[str, float]:
        """Vehicles per km of car lane, per edge with vehicles (its sidewalks and bike lanes left out:
        the vehicles stand on the car lanes, and a region's density is taken over those)."""
        km = net.edge_car_km
        return {e: n / max(km.get(e, 0.0), 1e-3) for e, n in self.on_edge.items()}

    def window_density(self, net, window) -> float | None:
        """The window's density (:meth:`region_density` of its square)."""
        return self.region_density(net, window_square(window))

    def region_density(self, net, region) -> float | None:
        """The density in a shapely region: the estimated vehicles on its edges per km of its car
        lane (:meth:`Network.region_density`, the divisor SUMO's edgeData has), as a window's count
        is taken (round(D x car-lane km) holds the estimate's vehicles); None where it has no normal
        car lane."""
        return net.region_density(region, self.edge_density(net))


class _Stops:
    """The demand's stops as the clock and the placement take them: the additional files' stopping
    places (their ends, lanes and parking lots) and the vTypes' classes (a stop of one edge is on
    the first lane its vehicle's class may use)."""

    def __init__(self, net, files, additional):
        from ..sim.stops import place_ends, stopping_places
        from .vtypes import vtype_table
        self.snet = net.sumo_net
        self.ends, self.places = place_ends(additional, net), stopping_places(additional)
        self.lots = parking_lots(additional)
        self.classes = vtype_table(files, lambda el: el.get("vClass") or "passenger")

    def resolve(self, d) -> tuple[tuple, tuple, tuple]:
        """(departure ``d``'s stops, each on its lane; per edge of its route the one it makes there;
        the clock's dwell, until and stop ends per edge: :func:`_dwell`)."""
        own = tuple(on_lane(s, self.snet, self.classes.get(d.type, "passenger")) for s in d.stops)
        dwell, until, at, which = _dwell(replace(d, stops=own), self.ends, self.snet)
        return own, which, (dwell, until, at)

    def here(self, pos, own: tuple, which: tuple) -> dict:
        """The :class:`EnRoute` fields of a trip at ``pos`` (queues.OnEdge) with stops ``own``: the
        one it makes on its edge (``which``: per edge), where it ends, when it is reached and held."""
        from ..sim.stops import stop_lane
        k = which[pos.k] if which else None
        if k is None:
            return {"stops": own}
        return {"stops": own, "stop": k, "stop_at": pos.trip.stop_at[pos.k], "to_stop": pos.to_stop,
                "hold": pos.hold, "lots": self.lots.get(own[k].get("parkingArea")),
                "stop_lane": stop_lane(own[k], self.places)}


def on_lane(stop: dict, snet, vclass: str) -> dict:
    """A ``<stop>`` (attribute dict) of one edge (``edge=``, no lane) on the lane SUMO gives it: the
    edge's first lane that allows the vehicle's class (MSBaseVehicle::addStop, MSEdge::getFirstAllowed);
    any other stop as it is."""
    from ..sim.stops import PLACES
    edge = stop.get("edge")
    if stop.get("lane") or any(stop.get(k) for k in PLACES) or not edge or not snet.hasEdge(edge):
        return stop
    lane = next((ln for ln in snet.getEdge(edge).getLanes() if ln.allows(vclass)), None)
    return stop if lane is None else {k: v for k, v in stop.items() if k != "edge"} | {"lane": lane.getID()}


@dataclass(frozen=True)
class Lots:
    """A parking area's lots as MSParkingArea lays them out: ``roadside`` lots along its lane, each
    ``spacing`` m on from the last (their ends back from the area's end), then its ``<space>``s
    (``spaces``), each entered from the area's end (their pose is the space's, off the road); SUMO
    fills them in that order."""
    spacing: float      # m (0: no roadside lot)
    roadside: int
    spaces: int

    @property
    def capacity(self) -> int:
        """SUMO's capacity: its roadsideCapacity and its ``<space>``s."""
        return self.roadside + self.spaces


def parking_lots(additional) -> dict[str, Lots]:
    """Every parking area of the additional files with lots: id -> its :class:`Lots`. Roadside lots
    end every (endPos - startPos) / roadsideCapacity m (``MSParkingArea::setRoadsideCapacity``; its
    ``length`` is the lots' size, not their spacing); numbers only (a negative or missing position
    leaves the roadside lots out, not the ``<space>``s)."""
    from ..core.sumo_xml import elements
    out = {}
    for _, el in elements(additional, ("parkingArea",)):
        spaces = sum(1 for c in el if c.tag == "space")
        try:
            roadside = int(el.get("roadsideCapacity", "0"))
            spacing = (float(el.get("endPos")) - float(el.get("startPos", "0"))) / roadside if roadside > 0 else 0.0
        except (TypeError, ValueError):
            roadside, spacing = 0, 0.0
        if spacing <= 0:
            roadside, spacing = 0, 0.0
        if el.get("id") and roadside + spaces > 0:
            out[el.get("id")] = Lots(spacing, roadside, spaces)
    return out


def _stop_end(stop: dict, ends: dict, snet) -> tuple[str, float] | None:
    """(edge, m along it where the stop ends) of a ``<stop>`` (attribute dict) on a lane or at a
    stopping place (``ends``: sim.stops.place_ends), as SUMO reads ``endPos`` (default the lane's
    end, a negative one from it); None where it names neither."""
    from ..sim.stops import PLACES
    place = next((stop[k] for k in PLACES if stop.get(k)), None)
    if place:
        return ends.get(place)
    lane = stop.get("lane")
    if not lane or not snet.hasEdge(lane.rpartition("_")[0]):
        return None
    length = snet.getLane(lane).getLength()
    try:
        end = float(stop["endPos"]) if stop.get("endPos") else length
    except ValueError:
        end = length
    return lane.rpartition("_")[0], min(max(end + length if end < 0 else end, 0.0), length)


def _dwell(d, ends: dict, snet) -> tuple[tuple, tuple, tuple, tuple]:
    """Per edge of ``d``'s route the seconds its stops hold it there, the latest time one holds it
    until (``until``; -inf: none), where the first of them ends (m; nan: none) and which of ``d.stops``
    that is (None: none), its stops in route order, each on the first of its edges at or after the
    one before; four () without stops."""
    from ..sim.stops import stop_seconds, stop_until
    if not d.stops:
        return (), (), (), ()
    n = len(d.edges)
    out, until, at, which, k = [0.0] * n, [float("-inf")] * n, [float("nan")] * n, [None] * n, 0
    for i, s in enumerate(d.stops):
        edge, end = _stop_end(s, ends, snet) or (None, None)
        if edge in d.edges[k:]:
            k = d.edges.index(edge, k)
            out[k] += stop_seconds(s)
            until[k] = max(until[k], stop_until(s) or float("-inf"))
            if which[k] is None:
                at[k], which[k] = end, i
    return tuple(out), tuple(until), tuple(at), tuple(which)


def _depart_offset(pos: str | None, length: float) -> float:
    """m along its first edge where a vehicle with ``departPos`` ``pos`` enters (SUMO's default
    "base": at the start; "random": on average the middle; a negative number counts from the end)."""
    if pos is None:
        return 0.0
    try:
        p = float(pos)
    except ValueError:
        return 0.5 * length if pos in ("random", "random_free") else 0.0
    return min(max(p + length if p < 0 else p, 0.0), length)


__all__ = ["DemandEstimate", "EnRoute", "Lots", "on_lane", "parking_lots"]
