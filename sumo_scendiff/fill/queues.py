"""The demand's departures run through the network as queues, without simulating the cars.

    trips = [Trip(id, type, edges, driver, depart, start_s, offset), ...]
    for pos in run_to(trips, times, net, begin):       # where each trip is at ``begin``
        pos.trip, pos.k, pos.t_enter, pos.travel, pos.offset

Each trip enters its first edge at its departure and moves edge by edge by :mod:`.travel`'s clock
(its cruise along an edge, then the link to the next: giving way, crossing the junction). The
events are taken in the order of time, so what one vehicle does holds up the next:

* a fixed light (:class:`~.programs.Program`) lets each link's vehicles through in the order they
  reached its stop line, in its green only, one per lane every 1 / SATURATION_FLOW s; where the
  link yields in its green (a left turn through the oncoming stream, ``g``), one per gap in its
  foes' flow (:meth:`~.travel.TravelTimes.gap_capacity`) and, as the green ends, SNEAKERS per lane
  that waited inside the junction: a turn whose demand exceeds that grows its queue, as SUMO's
  does; an actuated one holds each its expected (Webster's) delay;
* a link without a light that gives way (a minor road's) lets its queue through one per gap of
  MINOR_GAP s in its foes' flow (:meth:`~.travel.TravelTimes.gap_capacity`), its head waiting Adams'
  delay for its gap: a minor approach whose demand exceeds what the major stream leaves it grows
  its queue;
* a vehicle stands on the lanes of its edge that lead on along its route (SUMO's best lanes: those
  that reach its next edge, and of them those whose lane there reaches the edge after), the least
  occupied of them, and a lane holds its length over JAM_SPACING vehicles: a vehicle whose lanes on
  its next edge are full waits at its stop line until one leaves them (the queue of a turn spills
  back over the junction while the other lanes flow), a departure onto full lanes waits to be
  inserted (not yet on the network, as SUMO counts it). A vehicle already on the network goes
  before a waiting insertion, as in SUMO's step.

What it leaves out: a vehicle that stands in another lane waiting to change into its own when that
is full (blocking that lane's traffic), vehicles passing at amber, a blocked junction's foes.
"""
from __future__ import annotations

import heapq
import itertools
from collections import deque
from dataclasses import dataclass

import numpy as np

from .travel import MINOR_GAP, SATURATION_FLOW, Driver, TravelTimes
from .vtypes import DEFAULT_BODY

# m of lane per standing vehicle: SUMO's default car's length and minGap, whatever the vTypes (each
# vType's own spacing held the clock worse on the real cities, docs/fill.md)
JAM_SPACING = DEFAULT_BODY.spacing
MIN_STORAGE_M = 30.0  # m: a shorter edge holds no queue of its own (:func:`run_to`)
# vehicles per lane of a yielding link that wait inside the junction (netconvert's waiting position
# of a turn holds one car) and leave as the green ends; 0, 1 and 2 measured (docs/fill.md)
SNEAKERS = 1


@dataclass(frozen=True)
class Trip:
    id: str
    type: str | None
    edges: tuple[str, ...]
    driver: Driver
    depart: float
    start_s: float                 # s spent before its first cruise (accelerating from standing)
    offset: float = 0.0            # m along its first edge where it enters (departPos)
    dwell: tuple[float, ...] = ()  # s it stands at its stops on each edge of its route (none: ())
    until: tuple[float, ...] = ()  # the time its stops on each edge hold it until (-inf: none; none: ())
    stop_at: tuple[float, ...] = ()  # m along each edge where its first stop there ends (nan: none; none: ())


@dataclass(frozen=True)
class OnEdge:
    """Where a trip is at the time run to: on its ``k``-th edge since ``t_enter``, which takes it
    ``travel`` s to its end (past that, it waits there), having entered at ``offset`` m."""

    trip: Trip
    k: int
    t_enter: float
    travel: float
    offset: float
    to_stop: float = 0.0           # s after ``t_enter`` it reaches its stop on this edge (if it has one)
    hold: float = 0.0              # s it stands at its stops on this edge


def run_to(trips: list[Trip], times: TravelTimes, net, begin: float) -> list[OnEdge]:
    """Every trip on the network at ``begin`` (those arrived, or still waiting to be inserted, are
    not); deterministic: ties in time go in the order of ``trips``."""
    q = _Queues(times, net)
    for trip in trips:
        q.push(trip.depart, DEPART, trip)
    while q.events and q.events[0][0] <= begin:
        t, _, kind, trip, k = heapq.heappop(q.events)
        if kind == DEPART:
            q.depart(trip, t)
        elif k + 1 == len(trip.edges):       # at its route's end: it leaves the network
            del q.where[id(trip)]
            q.leave(trip, trip.edges[k], t)
        elif kind == LINE:
            q.at_line(trip, k, t)
        else:
            q.go(trip, k, t)
    return list(q.where.values())


DEPART, LINE, GO = 0, 1, 2     # the events: a departure, a vehicle at its stop line, one going through


class _Queues:
    """The network's lanes as queues while :func:`run_to` takes the events in the order of time."""

    def __init__(self, times: TravelTimes, net):
        self.times, self.snet = times, net.sumo_net
        self.occupied: dict[tuple[str, int], int] = {}   # (edge, lane index) -> vehicles on it
        self.cap: dict[str, float] = {}
        self.best: dict[tuple[str, tuple[str, ...]], tuple[int, ...]] = {}
        self.lane_of: dict[int, int] = {}           # id(trip) -> the lane of its edge it stands on
        self.waiting_for: dict[str, deque] = {}     # edge -> vehicles at an upstream stop line wanting onto it
        self.inserting: dict[str, deque] = {}       # edge -> departures waiting to be inserted onto it
        self.free_at: dict[tuple[str, str], float] = {}   # a fixed light's link: when it lets the next through
        self.sneaked: dict[tuple[str, str, float], int] = {}   # (link, its green's end): vehicles let through at it
        self.sneaking: dict[int, bool] = {}         # id(trip) -> it goes at its green's end, the light red by then
        self.ready: dict[int, float] = {}           # id(trip) -> when it has its gap, at a yielding green
        self.where: dict[int, OnEdge] = {}          # id(trip) -> where it is (ids may repeat across files)
        self.events: list = []
        self.order = itertools.count()

    def storage(self, e: str) -> float:
        """Vehicles a lane of the edge holds; a short edge (netconvert's stubs before a light, a block
        of a few metres) holds no queue of its own: SUMO's vehicles stand across it and the junction."""
        if e not in self.cap:
            edge = self.snet.getEdge(e)
            short = edge.getLength() < MIN_STORAGE_M
            self.cap[e] = np.inf if short else max(1.0, edge.getLength() / JAM_SPACING)
        return self.cap[e]

    def lanes_for(self, e: str, rest: tuple[str, ...]) -> tuple[int, ...]:
        """The lanes of ``e`` a vehicle going on by ``rest`` (its next edge and the one after) queues
        on: those that lead to its next edge, and of them those whose lane there leads on to the one
        after where some do (SUMO's best lanes, which a vehicle changes to before it stands)."""
        key = (e, rest[:2])
        if key not in self.best:
            lanes = [ln for ln in self.snet.getEdge(e).getLanes() if ln.allows("passenger")] \
                or list(self.snet.getEdge(e).getLanes())
            pick = lanes
            if rest:
                to = {ln: [c.getToLane() for c in ln.getOutgoing() if c.getTo().getID() == rest[0]] for ln in lanes}
                pick = [ln for ln in lanes if to[ln]] or lanes
                if len(rest) > 1:
                    onward = set(self.lanes_for(rest[0], rest[1:2]))
                    pick = [ln for ln in pick if any(m.getIndex() in onward for m in to[ln])] or pick
            self.best[key] = tuple(ln.getIndex() for ln in pick)
        return self.best[key]

    def full(self, e: str, rest: tuple[str, ...]) -> bool:
        return all(self.occupied.get((e, i), 0) >= self.storage(e) for i in self.lanes_for(e, rest))

    def push(self, t: float, kind: int, trip: Trip, k: int = 0) -> None:
        heapq.heappush(self.events, (t, next(self.order), kind, trip, k))

    def enter(self, trip: Trip, k: int, t: float, before: float, offset: float) -> None:
        e = trip.edges[k]
        lane = min(self.lanes_for(e, trip.edges[k + 1:k + 3]), key=lambda i: self.occupied.get((e, i), 0))
        self.occupied[(e, lane)] = self.occupied.get((e, lane), 0) + 1
        self.lane_of[id(trip)] = lane
        length = self.snet.getEdge(e).getLength()
        cruise, _ = self.times.edge(e, trip.driver)
        drive = before + cruise * (length - offset) / length
        # its stop is reached on the way along the edge (about the edge's end where the place is not
        # known), and a stop's until holds it past its duration from there (MSStop::getMinDuration)
        known = bool(trip.stop_at) and not np.isnan(trip.stop_at[k])
        to_stop = before + cruise * max((trip.stop_at[k] if known else length) - offset, 0.0) / length
        if known:          # it brakes to its stop and starts from it again
            v = trip.driver.cruise(self.snet.getEdge(e).getSpeed())
            to_stop += v / (2.0 * trip.driver.decel)
            drive += trip.driver.slowing(v, 0.0)
        hold = trip.dwell[k] if trip.dwell else 0.0
        if trip.until:
            hold = max(hold, trip.until[k] - t - to_stop)
        travel = max(drive + hold, 1e-3)
        self.where[id(trip)] = OnEdge(trip, k, t, travel, offset, to_stop, hold)
        self.push(t + travel, LINE, trip, k)

    def leave(self, trip: Trip, e: str, t: float) -> None:
        """``trip`` leaves ``e``: everyone waiting for a place on it tries again now, in the order they
        came, the network's vehicles before the insertions (one held by its light lets the next
        have it; whoever finds none on its lanes waits on)."""
        self.occupied[(e, self.lane_of.pop(id(trip)))] -= 1
        for waiting, k in self.waiting_for.pop(e, ()):
            self.push(t, GO, waiting, k)
        for waiting in self.inserting.pop(e, ()):
            self.push(t, DEPART, waiting)

    def depart(self, trip: Trip, t: float) -> None:
        e = trip.edges[0]
        if not self.full(e, trip.edges[1:3]):
            self.enter(trip, 0, t, trip.start_s, trip.offset)
        else:
            self.inserting.setdefault(e, deque()).append(trip)

    def _link(self, trip: Trip, k: int):
        """The link from the trip's ``k``-th edge to its next, its light's program, whether it gives way
        without a light (a minor road's)."""
        e, nxt = trip.edges[k], trip.edges[k + 1]
        link = self.times.link_of(e, nxt)
        program = self.times.light(link) if link is not None else None
        return e, nxt, link, program, program is None and link is not None and bool(link.foes)

    def at_line(self, trip: Trip, k: int, t: float) -> None:
        """Reached the stop line: ready after giving way."""
        e, nxt, link, program, minor = self._link(trip, k)
        if minor:                        # the head's gap; the queue is the server's (GO)
            wait = self.times.yielding(link, e, nxt, queued=True)[0]
        elif program is None:
            wait, _ = self.times.link(e, nxt, trip.driver)
        else:                            # a yielding green's gap is waited for in the GO step, in green
            wait = 0.0
            if link.foes:
                self.ready[id(trip)] = t + self.times.yielding(link, e, nxt, queued=True)[0]
        self.push(t + wait, GO, trip, k)

    def _held(self, trip: Trip, k: int, t: float, e, nxt, link, program, minor) -> float | None:
        """When the light (or a minor road's server) lets the trip through, if later than ``t``."""
        if minor:
            go = self.free_at.get((e, nxt), -np.inf)
            return go if go > t else None
        if program is None or self.sneaking.pop(id(trip), False):
            return None
        go = program.next_green(link.indices, max(t, self.ready.get(id(trip), t), self.free_at.get((e, nxt), -np.inf)))
        if go <= t:
            return None
        if link.foes:                # its gap or its turn comes after this green ends?
            start = program.next_green(link.indices, t)
            end = program.green_end(link.indices, start) if start < np.inf else None
            if end is not None and end < go:
                if self.sneaked.get((e, nxt, end), 0) < SNEAKERS * link.lanes:
                    # waiting inside the junction, it leaves as the foes stop at the green's end
                    self.sneaked[(e, nxt, end)] = self.sneaked.get((e, nxt, end), 0) + 1
                    self.sneaking[id(trip)] = True
                    go = end
                else:                # this green's places inside are taken: try the next green's
                    go = min(go, program.next_green(link.indices, end))
        return go

    def go(self, trip: Trip, k: int, t: float) -> None:
        """Through the junction if the light and the next edge let it."""
        e, nxt, link, program, minor = self._link(trip, k)
        held = self._held(trip, k, t, e, nxt, link, program, minor)
        if held is not None:
            self.push(held, GO, trip, k)
            return
        self.ready.pop(id(trip), None)
        if self.full(nxt, trip.edges[k + 2:k + 4]):
            self.waiting_for.setdefault(nxt, deque()).append((trip, k))
            return
        at_line = self.where[id(trip)].t_enter + self.where[id(trip)].travel
        if minor:
            self.free_at[(e, nxt)] = t + 1.0 / min(SATURATION_FLOW * link.lanes,
                                                    self.times.gap_capacity(link, MINOR_GAP))
        if program is None:
            _, before = self.times.link(e, nxt, trip.driver)
        else:
            rate = SATURATION_FLOW * link.lanes
            if link.foes:            # a yielding green: one per gap in its foes' flow
                rate = min(rate, self.times.gap_capacity(link))
            self.free_at[(e, nxt)] = t + 1.0 / rate
            wait, stops = self.times.yielding(link, e, nxt)
            cross, stopping = self.times.crossing(link, e, trip.driver)
            before = cross + (1.0 if t > at_line + wait + 1e-6 else stops) * stopping
        self.leave(trip, e, t)
        self.enter(trip, k + 1, t, before, 0.0)


__all__ = ["JAM_SPACING", "MIN_STORAGE_M", "OnEdge", "Trip", "run_to"]
