"""Junction conflicts among generated agents, resolved before they become SUMO vehicles.

    conflicts = JunctionConflicts(net)
    keep, dropped = conflicts.resolve(lanes, boxes, score, fixed=[(lane_id, box), ...])

An agent on a junction's internal lane has passed its stop line: SUMO lets it drive on whatever
the junction's other links carry. Two agents generated on internal lanes of one junction whose links
are *foes* (the junction's ``<request foes=...>`` bits, sumolib ``Node.areFoes``: their paths cross
or merge) both drive on, and if neither has reached the crossing yet they meet there; SUMO checks
junction collisions geometrically (``--collision.check-junctions``) and counts it. Such a pair is
resolved by keeping one agent: the more probable (the generator's ``score``), else the one whose
link has the right of way (``<request response=...>``), else the one further along. A pair where
one agent has already passed the conflict area (the overlap of the two lanes' outlines lies behind
its rear bumper) is no conflict and both stay. Host vehicles (``fixed``) are never dropped: an agent
in conflict with one is.
"""
from __future__ import annotations

import numpy as np
import shapely

from ..map.network import Network


class JunctionConflicts:
    def __init__(self, net: Network):
        self.net = net
        self.link: dict[str, tuple[str, int]] = {}   # internal lane -> (junction, link index)
        snet = net.sumo_net
        if snet is None:
            return
        for node in snet.getNodes():
            index = {}
            # Node.getLinkIndex walks all incoming lanes per call: one pass here numbers them all
            k = 0
            for lane_id in node._incLanes:
                edge_id, _, n = lane_id.rpartition("_")
                if not snet.hasEdge(edge_id):
                    continue
                for c in snet.getEdge(edge_id).getLane(int(n)).getOutgoing():
                    f, t = c.getFromLane().getEdge().getFunction(), c.getToLane().getEdge().getFunction()
                    if t == "walkingarea" or (f == "walkingarea" and t != "crossing"):
                        continue
                    index[c] = k
                    k += 1
            for c, k in index.items():
                lane_id, seen = c.getViaLaneID(), 0
                while lane_id and seen < 8:      # a connection's chain of internal lanes (internal junctions)
                    self.link[lane_id] = (node.getID(), k)
                    lane = snet.getLane(lane_id)
                    lane_id = next((x.getViaLaneID() or x.getToLane().getID() for x in lane.getOutgoing()
                                    if (x.getViaLaneID() or x.getToLane().getID()).startswith(":")), "")
                    seen += 1

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
        resp = self.net.sumo_net.getNode(j)._prohibits.get(a, "")
        return 0 <= len(resp) - b - 1 < len(resp) and resp[len(resp) - b - 1] == "1"

    def _pending(self, lane_a: str, box_a, lane_b: str) -> bool:
        """Whether the agent with ``box_a`` (x, y, yaw, length, width; world) on ``lane_a`` has not
        yet left the area where ``lane_a`` and ``lane_b`` overlap behind it."""
        la, lb = (self.net.lanes[self.net.lane_index[x]] for x in (lane_a, lane_b))
        area = shapely.intersection(la.polygon, lb.polygon)
        if area.is_empty:
            return False       # merging links whose outlines meet only beyond the junction
        line = shapely.LineString(la.shape)
        x, y, yaw, length = (float(v) for v in box_a[:4])
        rear = line.project(shapely.Point(x - 0.5 * length * np.cos(yaw), y - 0.5 * length * np.sin(yaw)))
        return rear <= max(line.project(shapely.Point(p)) for p in shapely.get_coordinates(area))

    def conflict(self, lane_a: str, box_a, lane_b: str, box_b) -> bool:
        return (self.foes(lane_a, lane_b) and self._pending(lane_a, box_a, lane_b)
                and self._pending(lane_b, box_b, lane_a))

    def resolve(self, lanes: list[str | None], boxes: np.ndarray, score: np.ndarray | None = None,
                fixed: list[tuple[str, np.ndarray]] = ()) -> tuple[np.ndarray, list[int]]:
        """Which agents to keep: ``lanes`` the lane id per agent (None: not on the road), ``boxes``
        (N, 5) world boxes, ``score`` the generator's probability per agent; ``fixed`` host vehicles'
        (lane id, world box). Returns (keep mask, dropped agent indices)."""
        n = len(lanes)
        keep = np.ones(n, bool)
        on = [i for i in range(n) if lanes[i] and lanes[i] in self.link]
        if not on:
            return keep, []
        for i in on:
            if any(lane in self.link and self.conflict(lanes[i], boxes[i], lane, box) for lane, box in fixed):
                keep[i] = False
        score = np.zeros(n) if score is None else np.asarray(score, np.float64)

        def rank(i: int, j: int) -> bool:    # whether i stays rather than j
            if score[i] != score[j]:
                return score[i] > score[j]
            yi, yj = self.yields(lanes[i], lanes[j]), self.yields(lanes[j], lanes[i])
            if yi != yj:
                return yj
            return i < j
        # the most probable first: an agent dropped for a better one cannot drop a third
        order = sorted(on, key=lambda i: -score[i])
        for a, i in enumerate(order):
            if not keep[i]:
                continue
            for j in order[a + 1:]:
                if keep[j] and self.conflict(lanes[i], boxes[i], lanes[j], boxes[j]):
                    keep[j if rank(i, j) else i] = False
                    if not keep[i]:
                        break
        return keep, [int(i) for i in np.flatnonzero(~keep)]


__all__ = ["JunctionConflicts"]
