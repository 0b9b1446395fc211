"""Routes for seeded agents: along the generated trajectory, then by SUMO's router to a destination.

    chooser = RouteChooser(sim, net, exclude_prefix="sd")
    chooser.refresh()                                     # destinations from the host's traffic now
    edges = chooser.complete(["wc"], "wc_0", "sd_passenger", rng)   # ["wc", "cn", "nX", ...]

A generated agent says where it is and where it goes for two seconds; beyond that its route is ours
to choose. A random walk along the network (the old continuation) loops around blocks and turns
where no driver would; and a turn the route invents that the agent's lane does not make forces a
lane change SUMO may only finish standing at the stop line or inside the junction, where cross
traffic hits it. So the route continues to a *destination* by the fastest path (SUMO's own router,
``simulation.findRoute``, for the agent's vehicle type):

* with demand (the host has vehicles on routes), a destination its vehicles drive to, drawn
  with the weight of how many do (the edges where its trips arrive);
* otherwise a fringe edge (one that leads out of the network: no successor but its own reverse),
  drawn uniformly;

only among those the agent can reach, drawn with the seeder's random generator (deterministic for a
seed). An agent that stands for a vehicle of the demand (a fill with demand) drives that vehicle's
own route (:meth:`RouteChooser.along`): from where its generated part leaves it, or, where that part
left the route, by the fastest path to the route's end. The first turn after the generated part is one the agent's lane makes where it can (the
fastest route through the lane's own successors), and no route we choose turns back on itself (a
U-turn) or visits an edge twice; a demand vehicle's own route, and the router's way to its own
destination, may (a turnaround at a dead end is how many scenarios' routes end).
"""
from __future__ import annotations

from collections import Counter
from itertools import pairwise

import numpy as np

from ..map.network import Network

TRIES = 12            # destinations tried per agent before giving up (an unreachable corner of the net)


class RouteChooser:
    def __init__(self, sim, net: Network, exclude_prefix: str = "sd"):
        self.sim, self.net, self.exclude = sim, net, exclude_prefix
        snet = net.sumo_net
        self.fringe: list[str] = sorted(
            e.getID() for e in snet.getEdges(withInternal=False)
            if e.allows("passenger") and not [s for s in e.getOutgoing()
                                              if s.allows("passenger") and not self._reverse(e, s)])
        self.targets: list[str] = []
        self.weights = np.zeros(0)

    @staticmethod
    def _reverse(a, b) -> bool:
        """Whether edge ``b`` leads back where ``a`` came from (a U-turn)."""
        return b.getToNode() is a.getFromNode() and b.getFromNode() is a.getToNode()

    def refresh(self) -> None:
        """Destinations: the last edges of the host's vehicles' routes (its own traffic, not the
        seeder's), else the network's fringe."""
        ends = Counter()
        try:
            for vid in self.sim.vehicle.getIDList():
                if not vid.startswith(self.exclude):
                    route = self.sim.vehicle.getRoute(vid)
                    if route:
                        ends[route[-1]] += 1
        except Exception:  # a host that cannot list its vehicles: the fringe
            ends.clear()
        snet = self.net.sumo_net
        ends = {e: n for e, n in ends.items() if snet.hasEdge(e) and not e.startswith(":")}
        if ends:
            self.targets = sorted(ends)
            self.weights = np.array([ends[e] for e in self.targets], np.float64)
        else:
            self.targets, self.weights = list(self.fringe), np.ones(len(self.fringe))

    def valid(self, edges: list[str], turn_back: bool = False) -> bool:
        """No edge twice, no U-turn (unless ``turn_back``: on the way to a demand vehicle's own
        destination, where SUMO's router may turn back at a dead end)."""
        if len(set(edges)) != len(edges):
            return False
        if turn_back:
            return True
        snet = self.net.sumo_net
        es = [snet.getEdge(e) for e in edges]
        return not any(self._reverse(a, b) for a, b in pairwise(es))

    def _find(self, a: str, b: str, vtype: str) -> tuple[list[str], float]:
        try:
            r = self.sim.simulation.findRoute(a, b, vtype)
        except Exception:
            return [], np.inf
        edges = list(r.edges)
        return (edges, float(r.travelTime)) if edges and edges[0] == a and edges[-1] == b else ([], np.inf)

    def onward(self, last: str, lane_id: str | None, dest: str, vtype: str, turn_back: bool = False) -> list[str]:
        """The fastest route from edge ``last`` to ``dest`` (``last`` first), through a successor of
        ``lane_id`` (the agent's lane on ``last``) where one reaches it; [] if none is valid
        (:meth:`valid` with ``turn_back``)."""
        snet = self.net.sumo_net
        best, t_best = self._find(last, dest, vtype)
        if lane_id and snet.hasEdge(last) and len(best) > 1:
            lane = snet.getLane(lane_id)
            succ = sorted({c.getTo().getID() for c in lane.getOutgoing() if c.allows("passenger")
                           and (turn_back or not self._reverse(snet.getEdge(last), c.getTo()))})
            if succ and best[1] not in succ:
                best, t_best = [], np.inf
                for s in succ:
                    edges, t = ([s], 0.0) if s == dest else self._find(s, dest, vtype)
                    if edges and t < t_best and self.valid([last] + edges, turn_back):
                        best, t_best = [last] + edges, t
        return best if best and self.valid(best, turn_back) else []

    def along(self, edges: list[str], lane_id: str | None, wanted, vtype: str) -> tuple[list[str], str]:
        """``edges`` (the generated part) continued along ``wanted`` (a route whose vehicle the agent
        stands for, from its edge then): (route, how), how = ``"followed"`` (the rest of ``wanted``
        after the generated part's last edge, through a successor of ``lane_id``), ``"rerouted"``
        (the fastest path to ``wanted``'s last edge) or ``""`` (neither: ``[]``).

        Only the generated part is held to :meth:`valid`: the rest is the demand's own, and a route
        SUMO drives may turn back at a dead end or pass an edge twice (duarouter's and OSM
        scenarios' routes do), which is the user's to decide."""
        wanted = list(wanted)
        last = edges[-1]
        if last in wanted:
            rest = wanted[wanted.index(last) + 1:]
            if self.valid(edges) and (not rest or self._leads(last, lane_id, rest[0])):
                return edges + rest, "followed"
        if last == wanted[-1]:
            return [], ""
        on = self.onward(last, lane_id, wanted[-1], vtype, turn_back=True)
        if on and self.valid(edges) and self.valid(edges[:-1] + on, turn_back=True):
            return edges[:-1] + on, "rerouted"
        return [], ""

    def _leads(self, edge: str, lane_id: str | None, nxt: str) -> bool:
        """Whether ``edge`` (from lane ``lane_id`` if known) connects to ``nxt``."""
        snet = self.net.sumo_net
        if not (snet.hasEdge(edge) and snet.hasEdge(nxt)):
            return False
        if lane_id:
            return any(c.getTo().getID() == nxt for c in snet.getLane(lane_id).getOutgoing())
        return snet.getEdge(nxt) in snet.getEdge(edge).getOutgoing()

    def complete(self, edges: list[str], lane_id: str | None, vtype: str, rng: np.random.Generator) -> list[str]:
        """``edges`` (the generated part) continued to a destination drawn with ``rng``; the
        generated part alone if no destination is reachable."""
        if not self.targets:
            self.refresh()
        last = edges[-1]
        snet = self.net.sumo_net
        skip = set(edges) | {e.getID() for e in snet.getEdge(last).getOutgoing() if self._reverse(snet.getEdge(last), e)}
        n = len(self.targets)
        if not n:
            return edges
        # a weighted draw without replacement: the order in which destinations are tried
        order = rng.choice(n, size=min(n, 4 * TRIES), replace=False, p=self.weights / self.weights.sum())
        tried = 0
        for k in order:
            dest = self.targets[int(k)]
            if dest in skip:
                continue
            on = self.onward(last, lane_id, dest, vtype)
            if on and self.valid(edges[:-1] + on):
                return edges[:-1] + on
            tried += 1
            if tried >= TRIES:
                break
        return edges


__all__ = ["RouteChooser"]
