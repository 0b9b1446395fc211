"""Before any vehicle is added: the vehicle ahead of each agent, the minGap that fits the gap to it,
and the speed it can depart at without braking beyond its ``decel`` behind it.

:class:`Gaps` is the part of :class:`~sumo_scendiff.sim.seeding.Seeder` that reads the generated
boxes only (and, for the departure speeds, the vTypes' decel and tau from ``sim``): the leader is the
nearest box ahead in the same lane by the boxes' geometry, as SUMO has no vehicles yet to report one.
After the seeding step :class:`~sumo_scendiff.sim.settle.Settling` checks the same against the leader
SUMO itself sees. The Seeder gives it ``sim`` and ``_known_types`` (the scenario's fleet).
"""
from __future__ import annotations

import numpy as np

from ..core.geometry import wrap_angle
from .fleet import DEFAULT_MIN_GAP
from .settle import MIN_GAP_MARGIN, krauss_safe_speed


class Gaps:
    @staticmethod
    def leaders(boxes: np.ndarray, others: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Per box, the nearest box ahead in its lane (|lateral| < 1.5 m, heading within 0.5 rad) among
        ``boxes`` and then ``others`` (index into their concatenation, -1: none) and the bumper gap to it."""
        n = len(boxes)
        b = np.concatenate([boxes[:, :5], np.zeros((0, 5)) if others is None else others[:, :5]]).astype(np.float64)
        lead, gap = np.full(n, -1), np.full(n, np.inf)
        for i in range(n):
            d = b[:, :2] - b[i, :2]
            c, s = np.cos(b[i, 2]), np.sin(b[i, 2])
            ahead, side = d @ [c, s], d @ [-s, c]
            same = (ahead > 0) & (np.abs(side) < 1.5) & (np.abs(wrap_angle(b[:, 2] - b[i, 2])) < 0.5)
            same[i] = False
            if same.any():
                j = np.flatnonzero(same)[np.argmin(ahead[same])]
                lead[i], gap[i] = j, ahead[j] - 0.5 * (b[i, 3] + b[j, 3])
        return lead, gap

    @staticmethod
    def min_gaps(bumper_gap: np.ndarray) -> np.ndarray:
        """A minGap per agent that fits the bumper gap to the agent ahead in its lane."""
        return np.clip(np.nan_to_num(bumper_gap - MIN_GAP_MARGIN, posinf=DEFAULT_MIN_GAP), 0.3, DEFAULT_MIN_GAP)

    def departure_speeds(self, lead: np.ndarray, gap: np.ndarray, speed: np.ndarray,
                         types: list | None = None) -> np.ndarray:
        """Per agent the speed it departs at: its own (``speed[:n]``: generated, 0 if held), at most
        Krauss' safe speed for the ``gap`` (m beyond its minGap) to the vehicle ahead (``lead``: an
        index into the agents and then the host's vehicles, whose speeds follow in ``speed``) at that
        one's departure speed: a leader slowed at hand-off slows the queue behind it too. The
        driving parameters are those of the agent's vType's parent (DEFAULT_VEHTYPE or ``types[i]``)."""
        n, t = len(lead), self.sim.vehicletype
        known = self._known_types()
        params: dict[str, tuple[float, float]] = {}
        out = np.full(n, np.nan)

        def settle(i: int, seen: frozenset) -> float:
            if not np.isnan(out[i]):
                return out[i]
            v = max(float(speed[i]), 0.0)
            j = int(lead[i])
            if j >= 0:
                if j < n and j not in seen:
                    v_lead = settle(j, seen | {i})
                else:                    # the host's vehicle, or a ring of agents (taken as drawn)
                    v_lead = max(float(speed[j]), 0.0)
                parent = types[i] if types is not None and types[i] in known else "DEFAULT_VEHTYPE"
                if parent not in params:
                    params[parent] = (t.getDecel(parent), t.getTau(parent))
                v = min(v, krauss_safe_speed(float(gap[i]), v_lead, *params[parent]))
            out[i] = v
            return v
        for i in range(n):
            settle(i, frozenset())
        return out
