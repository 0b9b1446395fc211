"""A junction's links as its request table numbers them, and who gives way to whom.

    conns = junction_links(snet, node)     # sumolib Connections, index k = the request table's link k
    gives_way(node, k, j)                  # link k must yield to link j (``<request response=...>``)

At a traffic light the response bits are those of the light switched off: who yields there is
the light's program (``g`` against ``G``), not these bits.
"""
from __future__ import annotations


def junction_links(snet, node) -> list:
    """``node``'s connections in link-index order (sumolib's ``Node.getLinkIndex``, which walks
    every incoming lane per call: one pass here numbers them all). Walking areas are skipped as
    SUMO skips them."""
    out = []
    for lane_id in node._incLanes:
        edge_id, _, n = lane_id.rpartition("_")
        if not snet.hasEdge(edge_id):
            continue
        for c in snet.getEdge(edge_id).getLane(int(n)).getOutgoing():
            f, t = c.getFromLane().getEdge().getFunction(), c.getToLane().getEdge().getFunction()
            if t == "walkingarea" or (f == "walkingarea" and t != "crossing"):
                continue
            out.append(c)
    return out


def gives_way(node, k: int, j: int) -> bool:
    """Whether link ``k`` of ``node`` must give way to its link ``j`` (the response bits)."""
    resp = node._prohibits.get(k, "")
    return 0 <= len(resp) - j - 1 < len(resp) and resp[len(resp) - j - 1] == "1"
