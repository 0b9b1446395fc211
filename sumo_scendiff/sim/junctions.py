"""Junction conflicts among generated agents, resolved before they become SUMO vehicles.

    conflicts = JunctionConflicts(net)
    keep, hold = conflicts.resolve(lanes, boxes, speeds, score, fixed=[(lane_id, box, speed), ...])

An agent on a junction's internal lane has passed its stop line: SUMO lets it drive on, braking for
a foe only if it can still see and stop for it. A model that does not know the signals generates
vehicles on *foe* links of one junction at once (the junction's ``<request foes=...>`` bits,
sumolib ``Node.areFoes``: their paths cross or merge); seeded as they are, they meet where their
lanes' outlines overlap, and SUMO counts a junction collision (``--collision.check-junctions``) or
brakes one beyond its decel. For each such pair the times at which each agent would hold the shared
area are estimated (driving on from its speed at ``ACCEL``); a pair that would hold it together:

* both already in it (noses past its start): only one is seeded: the more probable (the generator's
  ``score``), else the one whose link has the right of way (``<request response=...>``), else the
  first;
* otherwise the one that would reach it later departs standing (first come, first served): SUMO
  then sees the other as a foe it can wait for, and nobody is dropped.

A pair where one agent has already left the shared area is no conflict. Host vehicles (``fixed``)
are never dropped or held: an agent in conflict with one waits, or is not seeded if it is in the
shared area already.
"""
from __future__ import annotations

import numpy as np
import shapely

from ..map.links import gives_way, junction_links
from ..map.network import Network

ACCEL = 2.6    # m/s^2: SUMO's default passenger car accel, how an agent drives on through a junction
MARGIN = 0.0   # s: two agents closer in time than this in a shared area conflict


def time_to_cover(d: float, v: float) -> float:
    """Seconds to drive ``d`` m from ``v`` m/s accelerating at ``ACCEL``: d = v t + ACCEL t^2 / 2."""
    return 0.0 if d <= 0 else (-v + np.sqrt(v * v + 2.0 * ACCEL * d)) / ACCEL


class JunctionConflicts:
    def __init__(self, net: Network, margin: float = MARGIN):
        self.net, self.margin = net, margin
        self._areas: dict[tuple[str, str], tuple[float, float] | None] = {}
        self.link: dict[str, tuple[str, int]] = {}   # internal lane -> (junction, link index)
        self.entry: dict[str, tuple[str, str]] = {}  # internal lane -> (incoming lane, first internal lane)
        self.rest: dict[str, tuple[str, ...]] = {}   # internal lane -> it and its link's internal lanes after it
        self.lanes_of: dict[str, list[str]] = {}     # junction -> its internal lanes
        self._paths: dict[tuple[str, str], tuple[float, float] | None] = {}
        snet = net.sumo_net
        if snet is None:
            return
        for node in snet.getNodes():
            for k, c in enumerate(junction_links(snet, node)):
                lane_id, chain = c.getViaLaneID(), []
                while lane_id and len(chain) < 8:   # a connection's chain of internal lanes (internal junctions)
                    self.link[lane_id] = (node.getID(), k)
                    self.entry[lane_id] = (c.getFromLane().getID(), chain[0] if chain else lane_id)
                    chain.append(lane_id)
                    lane = snet.getLane(lane_id)
                    lane_id = next((x.getViaLaneID() or x.getToLane().getID() for x in lane.getOutgoing()
                                    if (x.getViaLaneID() or x.getToLane().getID()).startswith(":")), "")
                for n, lane_id in enumerate(chain):
                    self.rest[lane_id] = tuple(chain[n:])
                    self.lanes_of.setdefault(node.getID(), []).append(lane_id)

    def foes(self, lane_a: str, lane_b: str) -> bool:
        """Whether two internal lanes belong to conflicting links of one junction."""
        a, b = self.link.get(lane_a), self.link.get(lane_b)
        if a is None or b is None or a[0] != b[0] or a[1] == b[1]:
            return False
        node = self.net.sumo_net.getNode(a[0])
        try:
            return node.areFoes(a[1], b[1]) or node.areFoes(b[1], a[1])
        except (KeyError, IndexError):      # a junction without a request table (no foes)
            return False

    def yields(self, lane_a: str, lane_b: str) -> bool:
        """Whether ``lane_a``'s link must give way to ``lane_b``'s (the junction's response bits)."""
        (j, a), (_, b) = self.link[lane_a], self.link[lane_b]
        return gives_way(self.net.sumo_net.getNode(j), a, b)

    def _area(self, lane_a: str, lane_b: str) -> tuple[float, float] | None:
        """Where (from, to, metres along ``lane_a``'s centre line) ``lane_a``'s outline overlaps
        ``lane_b``'s, or None (merging links whose outlines meet only beyond the junction)."""
        key = (lane_a, lane_b)
        if key not in self._areas:
            la, lb = (self.net.lanes[self.net.lane_index[x]] for x in (lane_a, lane_b))
            area = shapely.intersection(la.polygon, lb.polygon)
            line = shapely.LineString(la.shape)
            s = [line.project(shapely.Point(p)) for p in shapely.get_coordinates(area)]
            self._areas[key] = (min(s), max(s)) if s and not area.is_empty else None
        return self._areas[key]

    def path_area(self, lane_a: str, lane_b: str) -> tuple[float, float] | None:
        """Where (from, to, metres along ``lane_a`` and the internal lanes of its link after it)
        that path overlaps ``lane_b``'s (``lane_b`` and its link's lanes after it), or None. A link
        through an internal junction has two or more internal lanes (a left turn's waiting point
        between them): two vehicles on the first lanes of their links can meet on the second."""
        key = (lane_a, lane_b)
        if key not in self._paths:
            out, offset = None, 0.0
            for la in self.rest.get(lane_a, (lane_a,)):
                for lb in self.rest.get(lane_b, (lane_b,)):
                    area = self._area(la, lb)
                    if area is not None:
                        lo, hi = offset + area[0], offset + area[1]
                        out = (lo, hi) if out is None else (min(out[0], lo), max(out[1], hi))
                offset += shapely.LineString(self.net.lanes[self.net.lane_index[la]].shape).length
            self._paths[key] = out
        return self._paths[key]

    def occupancy(self, lane_a: str, box_a, speed: float, lane_b: str) -> tuple[float, float] | None:
        """When (seconds from now: enters, leaves) the agent with ``box_a`` (x, y, yaw, length, width;
        world) on ``lane_a`` is in the area it shares with ``lane_b``, driving on from ``speed`` at
        ``ACCEL`` (a vehicle on an internal lane has passed its stop line and goes); None if it
        has left that area already or there is none. The area is the one their links' paths share
        (:meth:`path_area`)."""
        area = self.path_area(lane_a, lane_b)
        if area is None:
            return None
        lane = self.net.lanes[self.net.lane_index[lane_a]]
        line = shapely.LineString(lane.shape)
        x, y, yaw, length = (float(v) for v in box_a[:4])
        c, s = 0.5 * length * np.cos(yaw), 0.5 * length * np.sin(yaw)
        front, rear = line.project(shapely.Point(x + c, y + s)), line.project(shapely.Point(x - c, y - s))
        if rear > area[1]:
            return None
        v = max(float(speed), 0.0)
        return time_to_cover(area[0] - front, v), time_to_cover(area[1] - rear, v)

    def conflict(self, lane_a: str, box_a, v_a: float, lane_b: str, box_b, v_b: float):
        """Foe links whose shared area the two agents would hold within ``margin`` s of each other:
        their (enters, leaves) times there, else None."""
        if not self.foes(lane_a, lane_b):
            return None
        a, b = self.occupancy(lane_a, box_a, v_a, lane_b), self.occupancy(lane_b, box_b, v_b, lane_a)
        if a is None or b is None or not (a[0] < b[1] + self.margin and b[0] < a[1] + self.margin):
            return None
        return a, b

    def resolve(self, lanes: list[str | None], boxes: np.ndarray, speeds, score: np.ndarray | None = None,
                fixed: list[tuple[str, np.ndarray, float]] = ()) -> tuple[np.ndarray, np.ndarray]:
        """Which agents to keep and which to hold: ``lanes`` the lane id per agent (None: not on the
        road), ``boxes`` (N, 5) world boxes, ``speeds`` (N,) m/s, ``score`` the generator's probability
        per agent; ``fixed`` host vehicles' (lane id, world box, speed). Returns (keep, hold) masks:
        an agent to hold departs standing, before the area it shares with its foe."""
        n = len(lanes)
        keep, hold = np.ones(n, bool), np.zeros(n, bool)
        on = [i for i in range(n) if lanes[i] and lanes[i] in self.link]
        if not on:
            return keep, hold
        v = np.maximum(np.asarray(speeds, np.float64), 0.0)
        for i in on:
            for lane, box, speed in fixed:
                c = lane in self.link and self.conflict(lanes[i], boxes[i], v[i], lane, box, speed)
                if c and c[0][0] <= 0.0:
                    keep[i] = False          # in the area already: it cannot wait for the host
                elif c:
                    hold[i], v[i] = True, 0.0
        score = np.zeros(n) if score is None else np.asarray(score, np.float64)

        def rank(i: int, j: int) -> bool:    # whether i stays rather than j
            if score[i] != score[j]:
                return score[i] > score[j]
            yi, yj = self.yields(lanes[i], lanes[j]), self.yields(lanes[j], lanes[i])
            if yi != yj:
                return yj
            return i < j
        # the most probable first: an agent dropped for a better one cannot drop a third
        order = sorted((i for i in on if keep[i]), key=lambda i: -score[i])
        for a, i in enumerate(order):
            for j in order[a + 1:]:
                if not (keep[i] and keep[j]):
                    continue
                c = self.conflict(lanes[i], boxes[i], v[i], lanes[j], boxes[j], v[j])
                if c is None:
                    continue
                (ti, _), (tj, _) = c
                if ti <= 0.0 and tj <= 0.0:  # both in the shared area: one must go
                    keep[j if rank(i, j) else i] = False
                else:                        # the later one waits before it (first come, first served)
                    k = j if tj >= ti else i
                    hold[k], v[k] = True, 0.0
        return keep, hold & keep


__all__ = ["ACCEL", "JunctionConflicts", "time_to_cover"]
