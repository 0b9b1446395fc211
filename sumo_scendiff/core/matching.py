"""One-to-one matching with scipy's Hungarian algorithm, shared by every place that pairs agents.

A pair is allowed only where ``feasible``; infeasible pairs get a cost larger than any sum of feasible
costs, so the assignment has the maximum number of feasible pairs and, among those, the least total
cost. Infeasible pairs are then dropped.
"""
from __future__ import annotations

import numpy as np

from .geometry import wrap_angle

MATCH_DISTANCE = 2.2    # m: max centre distance of a matched pair (paper: 1.56 m bins * sqrt 2)
MATCH_HEADING = 0.2     # rad: max |heading difference| of a matched pair


def assign(cost: np.ndarray, feasible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) int arrays of the feasible pairs of the most feasible, then cheapest assignment
    of the (n, m) ``cost`` matrix (``cost`` >= 0 where feasible)."""
    cost = np.asarray(cost, np.float64)
    if cost.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    top = float(cost[feasible].max()) if feasible.any() else 0.0
    big = top * (min(cost.shape) + 1) + 1.0
    from scipy.optimize import linear_sum_assignment   # imported when used: a run without tokens never loads scipy
    rows, cols = linear_sum_assignment(np.where(feasible, cost, big))
    keep = feasible[rows, cols]
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def match_agents(gen_boxes: np.ndarray, tok_boxes: np.ndarray, max_distance: float = MATCH_DISTANCE,
                 max_heading: float = MATCH_HEADING) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching of generated agents to agent tokens (sec. 4.3.1) with the Hungarian
    algorithm on centre distance. Only pairs with distance <= ``max_distance`` and
    |wrap(heading difference)| <= ``max_heading`` are allowed. Infeasible pairs get a cost larger
    than any sum of feasible costs, so the assignment has the maximum number of feasible pairs and,
    among those, the least total distance; infeasible pairs are then dropped.

    ``gen_boxes`` (n, >=3) and ``tok_boxes`` (m, >=3): x, y, yaw in one frame; a NaN token yaw means
    the token has no heading (no heading constraint). Returns ``(gen_idx, tok_idx)``, int arrays.
    """
    g, t = np.asarray(gen_boxes, np.float64), np.asarray(tok_boxes, np.float64)
    if len(g) == 0 or len(t) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    from scipy.spatial.distance import cdist
    dist = cdist(g[:, :2], t[:, :2])
    dyaw = np.abs(wrap_angle(g[:, None, 2] - t[None, :, 2]))
    return assign(dist, (dist <= max_distance) & ((dyaw <= max_heading) | np.isnan(t[None, :, 2])))
