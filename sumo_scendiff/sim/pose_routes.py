"""The part of a seeded agent's route its poses give: the edges of the lanes it is seen on.

    edges, lane_index, lane, last_lane = seeder.route_for(scene, i, world, yaws)   # in Seeder._add

:class:`PoseRoutes` is the part of :class:`~sumo_scendiff.sim.seeding.Seeder` that reads the
network for a pose: the lane an agent stands on (heading agreement), where an internal junction lane
gives the route its incoming and outgoing edges and never starts one; the edges of the lanes of its
observed future poses, a short edge a pose skipped filled in by SUMO's router (at most
:data:`GAP_EDGES`); and the normal lane it is last seen on, whose successors are the turns it can
take. :class:`~sumo_scendiff.sim.routes.RouteChooser` continues the part to a destination. The
Seeder gives it ``sim``, ``net``, ``routes`` (the RouteChooser), ``junctions``
(:class:`~sumo_scendiff.sim.junctions.JunctionConflicts`) and ``moved_from``
(:meth:`~sumo_scendiff.sim.stop_lines.StopLines.fit_red_junctions`).
"""
from __future__ import annotations

import numpy as np

from ..core.geometry import T0
from ..core.scene import Scene

GAP_EDGES = 3          # at most this many edges between two generated poses' edges are filled in


class PoseRoutes:
    def _internal_links(self) -> dict[str, tuple[str, str]]:
        """Internal lane id -> (incoming edge, outgoing edge) of the connection it belongs to."""
        out: dict[str, tuple[str, str]] = {}
        snet = self.net.sumo_net
        for edge in snet.getEdges(withInternal=False):
            for conns in edge.getOutgoing().values():
                for c in conns:
                    lane_id = c.getViaLaneID()
                    seen = 0
                    while lane_id and seen < 8:  # follow chains of internal lanes
                        out[lane_id] = (c.getFrom().getID(), c.getTo().getID())
                        nxt = [x.getViaLaneID() or x.getToLane().getID()
                               for x in snet.getLane(lane_id).getOutgoing()] if snet.hasEdge(
                            lane_id.rsplit("_", 1)[0]) else []
                        lane_id = next((n for n in nxt if n.startswith(":")), "")
                        seen += 1
        return out

    def _exit_lane(self, internal: str) -> str | None:
        """The normal lane a junction's internal lane leads to (through its link's later lanes)."""
        last = self.junctions.rest.get(internal, (internal,))[-1]
        try:
            out = self.net.sumo_net.getLane(last).getOutgoing()
        except (KeyError, AttributeError):
            return None
        return out[0].getToLane().getID() if out else None

    def _edges_at(self, x: float, y: float, yaw: float) -> tuple | None:
        """(route edges for this pose, lane index on the first edge, lane) or None."""
        hit = self.net.lookup(x, y, yaw)
        if hit is None:
            return None
        lane = hit[0]
        if lane.internal:
            link = self._via.get(lane.id)
            return None if link is None else (list(link), 0, lane)
        return [lane.edge], lane.index, lane

    def _fill(self, a: str, b: str) -> list[str]:
        """Edges after ``a`` up to ``b`` when a generated pose skipped a short edge ([] if none)."""
        snet = self.net.sumo_net
        if snet.getEdge(b) in snet.getEdge(a).getOutgoing():
            return [b]
        try:
            edges = list(self.sim.simulation.findRoute(a, b).edges)
        except Exception:
            return []
        ok = edges and edges[0] == a and len(edges) <= GAP_EDGES + 2 and self.routes.valid(edges)
        return edges[1:] if ok else []

    def route_for(self, scene: Scene, i: int, world: np.ndarray, yaws: np.ndarray):
        """Agent ``i``'s generated part of a route: (edges through its lane now and the lanes of its
        observed future poses, lane index on the first edge, its lane now, the id of the last normal
        lane it is seen on, or None). :meth:`seed` continues it to a destination."""
        start = self._edges_at(world[T0, 0], world[T0, 1], yaws[T0])
        if start is None:
            return None
        edges, lane_index, lane = start
        last_lane = None if lane.internal else lane.id
        for k in range(T0 + 1, len(yaws)):
            if not scene.traj_mask[i, k]:
                continue
            nxt = self._edges_at(world[k, 0], world[k, 1], yaws[k])
            for e in (nxt[0] if nxt else []):
                if e != edges[-1] and e not in edges:
                    fill = self._fill(edges[-1], e)
                    edges += fill
                    if fill and not nxt[2].internal:
                        last_lane = nxt[2].id
                elif e == edges[-1] and not nxt[2].internal:
                    last_lane = nxt[2].id
        moved = self.moved_from.get(i)
        if moved is not None and moved in self._via and self._via[moved][1] not in edges:
            edges.append(self._via[moved][1])     # the movement it waits for (fit_red_junctions)
            last_lane = self._exit_lane(moved)
        elif last_lane is None and lane.internal:
            # seen only inside the junction: it leaves on its movement's lane, whose successors are
            # the turns it can take without a lane change it has no room for
            last_lane = self._exit_lane(lane.id)
        if last_lane is not None and last_lane.rsplit("_", 1)[0] != edges[-1]:
            last_lane = None
        return edges, lane_index, lane, last_lane


__all__ = ["GAP_EDGES", "PoseRoutes"]
