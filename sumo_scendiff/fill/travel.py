"""How long a demand's vehicle takes along its route, without simulating it: the demand estimate's clock.

    times = TravelTimes(net, drivers=vtype_drivers(files), additional=files)
    times.edge(edge, driver)            # s cruising along the edge
    times.link(edge, nxt, driver)       # (s waiting at its light, s across the junction incl. slowing down)
    times.light(times.link_of(edge, nxt)).next_green(indices, t)   # a fixed light's next green after t
    times.flows = link_flows(routes)    # veh/s per (edge, next): the lights' degree of saturation

A vehicle cruises at its vType's desired speed (speedFactor x the limit, at most its maxSpeed), as
SUMO's car-following does on a free road. At each junction it crosses the internal lanes of the
connection at their speed (SUMO lowers it for a turn's radius) and loses the time of braking to it
and accelerating back. At a traffic light it waits Webster's delay (:func:`webster`) at the link's
green share λ and degree of saturation x (the demand's own flow through the link over the capacity
of its lanes at green, SATURATION_FLOW per lane, capped at X_MAX: an oversaturated queue grows
without bound, which a steady-state formula cannot hold); the share of vehicles that stop,
(1 - λ) / (1 - λx), lose the time of stopping and starting as well. A vehicle departing at speed 0
(its departSpeed, or SUMO's ``default.departspeed`` where it gives none: 0 in older SUMO, the
lane's speed, "avg", in 1.28: :func:`~.routing.routed_departures`) loses the time of accelerating. An actuated light's phases are taken
at the durations its gap control gives them under the demand's flows (:mod:`.actuated`), not at
their programmed ones. Every speeding up is at the vType's
mean acceleration under Krauss' dawdling, accel (1 - sigma / 2) (:attr:`Driver.pickup`).

A link that yields (a minor link, ``m``; right before left, ``=``; one that must stop, ``s``/``w``;
a turn at a light through a yielding green, ``g``) waits for a gap of YIELD_GAP s in the flow of
the links it gives way to (the junction's ``<request response=...>``; at a light, those green at
once with a phase where the link is a yielding ``g``): Adams' delay, (e^{qT} - qT - 1) / q for a
Poisson stream of q veh/s (a light's foe flow concentrated into its green share), grown by the
minor flow's own queue, 1 / (1 - x) at x = its flow over the gap-acceptance capacity
q e^{-qT} / (1 - e^{-q t_f}); the share that finds no gap, 1 - e^{-qT} (every one at a stop sign),
stops and starts again.

A light with a fixed program is also a clock (:class:`~.programs.Program`, SUMO's phases at
simulation time t from its offset): :mod:`.queues` lets its queue through in its green only, one vehicle per lane
each 1 / SATURATION_FLOW s, instead of the expected delay, and holds queues back where an edge is
full; a yielding green's queue one per gap of QUEUE_GAP s in its foes' flow
(:meth:`TravelTimes.gap_capacity`), the head of the queue waiting Adams' delay.

Left out: lane changes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..map.links import gives_way, junction_links
from ..sim.fleet import DEFAULT_ACCEL, DEFAULT_DECEL
from .programs import Program, green_shares, minor_green, signal_programs, under_demand
from .vtypes import CLASS_ACCEL, CLASS_DECEL, CLASS_MAX_SPEED, number, vtype_table

SATURATION_FLOW = 0.5   # veh/s per lane discharging at green (SUMO's Krauss defaults: ~1 800 veh/h)
# Traffic cruises below its desired speed: car-following behind slower vehicles (speedFactor's spread),
# SUMO's dawdling (sigma), lane changes. One share for all of it, chosen on the project's held-out
# generated networks with random demand against SUMO's own counts (docs/fill.md), not on real cities.
CRUISE_SHARE = 0.9
X_MAX = 0.95            # the degree of saturation the uniform delay is evaluated at, at most
# a yielding vehicle's critical gap in its foes' stream (SUMO lets it go when it clears the
# conflict jmTimegapMinor, 1 s, before a foe arrives), chosen of 3, 4 and 5 s on the project's
# held-out generated networks as CRUISE_SHARE was (docs/fill.md)
YIELD_GAP = 5.0
# the gap a queue at a yielding green takes one vehicle through (:meth:`TravelTimes.gap_capacity`):
# chosen of 3, 4 and 5 s on the held-out generated networks (docs/fill.md); shorter than
# YIELD_GAP, the wait of one arriving alone, as a queued vehicle starts from the line
QUEUE_GAP = 4.0
# the gap a vehicle standing at a minor road's line takes to cross or join the major stream at a
# junction without a light (it starts from standing over the whole junction): chosen of 4, 5 and 6 s
# on the held-out generated networks as the others (91, 91, 92 of 128 times within ±10 %)
MINOR_GAP = 6.0
FOLLOW_UP = 2.0         # s between minor vehicles taking one gap (the saturation headway)
# net.xml connection states that give way without a light (minor, right before left, stop sign,
# all-way stop); those that stop first
YIELDS, STOPS = "m=sw", "sw"

@dataclass(frozen=True)
class Driver:
    """A vType's parameters the travel times need (SUMO's passenger defaults unless given)."""

    speed_factor: float = 1.0
    max_speed: float = 55.56
    accel: float = DEFAULT_ACCEL
    decel: float = DEFAULT_DECEL
    sigma: float = 0.5           # Krauss' dawdling (SUMO's default car-following model)

    def cruise(self, limit: float) -> float:
        return max(CRUISE_SHARE * min(limit * self.speed_factor, self.max_speed), 0.1)

    @property
    def pickup(self) -> float:
        """Mean acceleration: Krauss takes sigma x accel x U(0, 1) off each step's speed gain
        (MSCFModel_Krauss::dawdle2), so a vehicle speeds up at accel (1 - sigma / 2)."""
        return max(self.accel * (1.0 - self.sigma / 2.0), 0.1)

    def slowing(self, v: float, u: float) -> float:
        """s lost braking from v to u and accelerating back: (v - u)² / (2 v) (1/b + 1/a)."""
        return 0.0 if u >= v else (v - u) ** 2 / (2.0 * v) * (1.0 / self.pickup + 1.0 / self.decel)


DEFAULT_DRIVER = Driver()


def vtype_drivers(paths) -> dict[str, Driver]:
    """The :class:`Driver` of every vType in ``paths`` (route and additional files) by id, and of
    every vTypeDistribution (its first member's)."""
    def driver(el) -> Driver:
        cls = el.get("vClass") or "passenger"
        krauss = (el.get("carFollowModel") or "Krauss").startswith("Krauss")
        return Driver(number(el, "speedFactor", 1.0), number(el, "maxSpeed", CLASS_MAX_SPEED.get(cls, 55.56)),
                      number(el, "accel", CLASS_ACCEL.get(cls, DEFAULT_ACCEL)),
                      number(el, "decel", CLASS_DECEL.get(cls, DEFAULT_DECEL)),
                      number(el, "sigma", 0.5) if krauss else 0.0)

    return vtype_table(paths, driver)


@dataclass(frozen=True)
class Link:
    """What a vehicle meets going from an edge onto the next: the junction and its light."""

    via_m: float                 # length of the internal lanes crossed
    via_speed: float             # their speed limit (m/s)
    cycle: float = 0.0           # the light's cycle (s); 0: no light
    green: float = 1.0           # green share λ of the link (mean over its lane-to-lane links)
    lanes: int = 1               # lanes discharging onto the next edge
    foes: tuple = ()             # the (edge, next edge, their green share, weight) it gives way to
    stop: bool = False           # every vehicle stops first (a stop sign, all-way stop)
    light: str | None = None     # its light, when its program is fixed (a clock: :class:`~.programs.Program`)
    indices: tuple = ()          # the link indices of its lanes at that light


class TravelTimes:
    """Per edge and per (edge, next edge) the times of :mod:`this module's <.travel>` model."""

    def __init__(self, net, additional=(), flows: dict[tuple[str, str], float] | None = None):
        self.snet = net.sumo_net
        self.flows = flows or {}
        self._links: dict[tuple[str, str], Link | None] = {}
        path = getattr(net, "path", None)
        self._programs = (under_demand(signal_programs([path, *additional]), self.snet, self.flows,
                                      SATURATION_FLOW) if path else {})
        self._shares = green_shares(self._programs)
        self._index: dict[str, tuple[dict, list]] = {}    # node -> (connection -> link index, index -> edges)

    def edge(self, edge: str, driver: Driver = DEFAULT_DRIVER) -> tuple[float, float]:
        """(s cruising along ``edge``, the cruising speed m/s)."""
        e = self.snet.getEdge(edge)
        v = driver.cruise(e.getSpeed())
        return e.getLength() / v, v

    def link_of(self, edge: str, nxt: str) -> Link | None:
        if (edge, nxt) not in self._links:
            self._links[(edge, nxt)] = self._read_link(edge, nxt)
        return self._links[(edge, nxt)]

    def _read_link(self, edge: str, nxt: str) -> Link | None:
        a, b = self.snet.getEdge(edge), self.snet.getEdge(nxt)
        conns = a.getConnections(b)
        if not conns:
            return None
        via_m, via_speed = [], []
        cycles, greens, lights = [], [], []
        for c in conns:
            m, speed, lane = 0.0, [], c.getViaLaneID()
            for _ in range(4):            # an internal junction splits a turn into a chain of lanes
                if not lane:
                    break
                ln = self.snet.getLane(lane)
                m += ln.getLength()
                speed.append(ln.getSpeed())
                nxt_conns = ln.getOutgoing()
                lane = nxt_conns[0].getViaLaneID() if nxt_conns and nxt_conns[0].getViaLaneID() else None
            via_m.append(m)
            via_speed.append(min(speed) if speed else b.getSpeed())
            tls, idx = c.getTLSID(), c.getTLLinkIndex()
            if tls and tls in self._shares and 0 <= idx < len(self._shares[tls][1]):
                cycles.append(self._shares[tls][0])
                greens.append(self._shares[tls][1][idx])
                lights.append((tls, idx))
        lanes = len({c.getFromLane().getIndex() for c in conns})
        foes, stop = self._foes(a.getToNode(), conns)
        if cycles:
            tls = lights[0][0]
            fixed = self._programs[tls].fixed and all(t == tls for t, _ in lights)
            return Link(float(np.mean(via_m)), float(np.mean(via_speed)), float(np.mean(cycles)),
                        float(np.mean(greens)), lanes, foes, stop, tls if fixed else None,
                        tuple(sorted({k for _, k in lights})) if fixed else ())
        return Link(float(np.mean(via_m)), float(np.mean(via_speed)), lanes=lanes, foes=foes, stop=stop)

    def _links_of(self, node) -> tuple[dict, list]:
        """Link index of each connection of ``node`` and the (from edge, to edge, connection) of each."""
        if node.getID() not in self._index:
            conns = junction_links(self.snet, node)
            self._index[node.getID()] = ({c: k for k, c in enumerate(conns)},
                                         [(c.getFrom().getID(), c.getTo().getID(), c) for c in conns])
        return self._index[node.getID()]

    def _foes(self, node, conns) -> tuple[tuple, bool]:
        """The (edge, next, green share, weight) links that ``conns`` give way to, and whether they
        stop first. Without a light, the junction's response bits of a yielding state; at a light
        (whose net.xml states are those of the light switched off), the foes green at once with a
        phase in which the link is a yielding green ``g``, weighted by the share of its green that is."""
        index, edges = self._links_of(node)
        foes: dict[tuple[str, str], list[float]] = {}
        yielding = 0
        for c in conns:
            tls, k = c.getTLSID(), c.getTLLinkIndex()
            program = self._programs.get(tls) if tls else None
            phases = program.phases if program is not None else None
            if phases is None and (c.getState() or "") not in YIELDS:
                continue
            own = index.get(c, -1)      # its link index at the junction (k: at the light)
            mine = False
            for j in range(len(edges)):
                if not gives_way(node, own, j):
                    continue
                f, t, fc = edges[j]
                weight, share = 1.0, 1.0
                if phases is not None:
                    tj = fc.getTLLinkIndex() if fc.getTLSID() == tls else -1
                    weight = minor_green(phases, k, tj) if tj >= 0 else 0.0
                    share = float(self._shares[tls][1][tj]) if 0 <= tj < len(self._shares[tls][1]) else 1.0
                if weight > 0:
                    mine = True
                    old = foes.get((f, t), [share, 0.0])
                    foes[(f, t)] = [share, max(old[1], weight)]
            yielding += mine or (phases is None and (c.getState() or "") in STOPS)
        if yielding * 2 <= len(conns):     # most of the link's lanes have the right of way
            return (), False
        stop = all((c.getState() or "") in STOPS and not c.getTLSID() for c in conns)
        return tuple((f, t, g, w) for (f, t), (g, w) in foes.items()), stop

    def foe_flow(self, link: Link) -> float:
        """veh/s of the flows ``link`` gives way to; a foe behind a light flows only in its green, at
        its flow over its green share."""
        return sum(w * self.flows.get((f, t), 0.0) / max(g, 0.1) for f, t, g, w in link.foes)

    def gap_capacity(self, link: Link, gap: float = QUEUE_GAP) -> float:
        """veh/s a yielding link lets through while its foes flow: one vehicle per ``gap`` s, one more
        per FOLLOW_UP s the gap is longer (Siegloch's), over its lanes; inf if it yields to nothing."""
        q = self.foe_flow(link)
        if q <= 1e-9:
            return float("inf")
        return float(q * np.exp(-q * gap) / (1.0 - np.exp(-q * FOLLOW_UP)) * link.lanes)

    def yielding(self, link: Link, edge: str, nxt: str, queued: bool = False) -> tuple[float, float]:
        """(s waiting for a gap in the foes' flow, share of vehicles that stop) at a yielding link;
        with ``queued`` the wait of a vehicle at the head of the queue only (Adams' delay), the queue
        held by the caller."""
        if not link.foes and not link.stop:
            return 0.0, 0.0
        q = self.foe_flow(link)
        if q <= 1e-9:
            return 0.0, 1.0 if link.stop else 0.0
        adams = (np.exp(q * YIELD_GAP) - q * YIELD_GAP - 1.0) / q
        x = 0.0 if queued else min(self.flows.get((edge, nxt), 0.0) / max(self.gap_capacity(link), 1e-9), X_MAX)
        stops = 1.0 if link.stop else 1.0 - np.exp(-q * YIELD_GAP)
        return float(adams / (1.0 - x)), float(stops)

    def link(self, edge: str, nxt: str | None, driver: Driver = DEFAULT_DRIVER) -> tuple[float, float]:
        """(s waiting at the light of edge -> nxt, s crossing the junction including the time lost
        slowing for it and, if stopped, starting again); (0, 0) at a route's end."""
        link = self.link_of(edge, nxt) if nxt is not None else None
        if link is None:
            return 0.0, 0.0
        cross, stopping = self.crossing(link, edge, driver)
        wait, stops = self.yielding(link, edge, nxt)
        if link.cycle > 0:
            lam = link.green
            capacity = SATURATION_FLOW * link.lanes * max(lam, 1e-3)
            q = self.flows.get((edge, nxt), 0.0)
            x = min(q / capacity, X_MAX)
            wait += webster(link.cycle, lam, x, q)
            red = min((1.0 - lam) / (1.0 - lam * x), 1.0)
            stops = red + (1.0 - red) * stops
        return wait, cross + stops * stopping

    def crossing(self, link: Link, edge: str, driver: Driver = DEFAULT_DRIVER) -> tuple[float, float]:
        """(s crossing the junction, slowing for its internal lanes, without stopping; s more if
        stopped first). A stopped vehicle brakes from v to 0 and starts again: the slowing to the
        internal lanes' speed u is then part of it."""
        v = driver.cruise(self.snet.getEdge(edge).getSpeed())
        u = min(driver.cruise(link.via_speed), v)
        return link.via_m / u + driver.slowing(v, u), driver.slowing(v, 0.0) - driver.slowing(v, u)

    def light(self, link: Link) -> Program | None:
        """The fixed program of the light ``link`` passes (None: no light, or an actuated one)."""
        return self._programs.get(link.light) if link.light else None

    def start(self, driver: Driver, edge: str) -> float:
        """s lost accelerating from standing to ``edge``'s cruising speed."""
        return driver.cruise(self.snet.getEdge(edge).getSpeed()) / (2.0 * driver.pickup)


def webster(cycle: float, lam: float, x: float, q: float) -> float:
    """Webster's mean delay (s) at a light of ``cycle`` s: the uniform delay C (1 - λ)² / (2 (1 - λx)),
    the random arrivals' x² / (2q (1 - x)) and his empirical correction -0.65 (C / q²)^⅓ x^(2 + 5λ),
    at green share λ, degree of saturation x and flow q (veh/s)."""
    uniform = cycle * (1.0 - lam) ** 2 / (2.0 * (1.0 - lam * x))
    if q <= 0 or x <= 0:
        return uniform
    random = x * x / (2.0 * q * (1.0 - x))
    correction = 0.65 * (cycle / (q * q)) ** (1.0 / 3.0) * x ** (2.0 + 5.0 * lam)
    return max(uniform + random - correction, uniform)


def link_flows(routes: list[tuple[float, list[str]]], begin: float, span: float) -> dict[tuple[str, str], float]:
    """veh/s through each (edge, next edge) of the routes departed in the ``span`` s before ``begin``."""
    counts: dict[tuple[str, str], int] = {}
    start = begin - span
    for depart, edges in routes:
        if start <= depart <= begin:
            for pair in zip(edges, edges[1:]):
                counts[pair] = counts.get(pair, 0) + 1
    return {k: n / max(span, 1.0) for k, n in counts.items()}


__all__ = ["DEFAULT_DRIVER", "Driver", "Link", "TravelTimes", "link_flows", "vtype_drivers", "webster"]
