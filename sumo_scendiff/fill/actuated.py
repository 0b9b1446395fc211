"""An actuated light's phases as they run under a demand: SUMO's gap control, in expectation.

    durations = expected_durations(states, durations, bounds, lane_flows, SATURATION_FLOW, max_gap=3.0)

SUMO's ``actuated`` logic (``MSActuatedTrafficLightLogic``, time gaps, the default) holds a green
phase for at least ``minDur`` and then prolongs it while the detectors on its green lanes see
vehicles less than ``max-gap`` s apart, up to ``maxDur``. Its programmed ``duration`` is only where
it starts: at a light whose streams are light, every green ends soon after ``minDur`` and the cycle
is much shorter than the programmed one, so the programmed durations overstate the waiting.

Per green phase, on the lanes SUMO detects for it (every link of the lane green in it; a yielding
``g`` only where the link never has a major green and the lane has one, or the lane is its edge's
only one), in the cycle C the other phases give it a red r = C - g: the queue the busiest of them
gathered in r clears in q r / (s - q) (q its flow per lane, s the saturation flow); after minDur or
that, whichever is later, their arrivals together (a Poisson stream of flow Q) leave a gap of T
after (e^{QT} - 1) / Q - T on average from a random instant (0 on empty lanes: the phase ends at
minDur), T more from the queue's last vehicle; T is max-gap and the one whole second the
controller looks again after (its phases last whole seconds). The green is that, within
[minDur, maxDur]; the cycle is the fixed point of these greens and the phases that are not
actuated (amber, all-red). Left out: phase skipping (``next``), the detectors' distance before the
line, the loops SUMO leaves out before a joined light's red, delay-based control.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

MAX_GAP = 3.0            # s: SUMO's default max-gap of an actuated light
CHECK_STEP = 1.0         # s: its phases last whole seconds, prolonged by at least one at a time
GREEN = "Ggs"


def expected_durations(states: Sequence[str], durations: Sequence[float], bounds: Sequence[tuple[float, float]],
                       lane_flows: dict[str, dict[int, float]], saturation: float,
                       max_gap: float = MAX_GAP, downstream: dict[str, set[str]] | None = None,
                       one_lane: set[str] | None = None) -> tuple[float, ...]:
    """The phases' expected durations (s). ``bounds``: each phase's (minDur, maxDur), equal for a
    phase that is not actuated; ``lane_flows``: per incoming lane, the demand's flow (veh/s)
    through each of its link indices; ``saturation``: veh/s per lane discharging at green;
    ``downstream``: per lane, the light's own incoming lanes its links lead to (a joined light);
    ``one_lane``: the lanes that are their edge's only lane for cars."""
    n = len(states)
    downstream = downstream or {}
    one_lane = one_lane or set()
    never_major = {k for links in lane_flows.values() for k in links} - {
        k for st in states for k, c in enumerate(st) if c == "G"}

    def green(lane: str, st: str) -> bool:
        """SUMO's check: a yielding green ``g`` counts where the lane has a major green beside it
        and the link never has one, or the lane is its edge's only one."""
        links = lane_flows.get(lane, {})
        major = any(k < len(st) and st[k] == "G" for k in links)
        return bool(links) and all(k < len(st) and (st[k] in "Gs" or (st[k] == "g" and (
            (k in never_major and major) or lane in one_lane))) for k in links)

    served: list[tuple[float, float]] = []        # per phase: (busiest lane's flow, all its lanes' flow)
    for st in states:
        # SUMO's loop on a lane extends a phase in which every link of that lane is green, and
        # (a joined light) every link of the light's lanes it leads to
        per_lane = [sum(links.values()) for lane, links in lane_flows.items()
                    if green(lane, st) and all(green(d, st) for d in downstream.get(lane, ()))]
        served.append((max(per_lane, default=0.0), float(sum(per_lane))))
    g = np.array(durations, dtype=float)
    actuated = [i for i in range(n) if bounds[i][1] > bounds[i][0] and any(c in GREEN for c in states[i])]
    # the controller looks again at whole seconds, at least one after a vehicle: a gap ends the
    # phase about a second after it reaches max-gap
    horizon = max_gap + CHECK_STEP
    if not actuated:
        return tuple(g)
    for _ in range(100):
        cycle = g.sum()
        new = g.copy()
        for i in actuated:
            q, total = served[i]
            red = cycle - g[i]
            clear = q * red / max(saturation - q, 0.05 * saturation)
            # from a random instant, a gap of T has passed after (e^{QT} - 1) / Q - T (0 on empty
            # lanes: the phase ends at minDur); from a vehicle (the queue's last), T more
            gap = (np.expm1(total * horizon) / total - horizon) if total > 1e-9 else 0.0
            if clear > bounds[i][0]:
                gap += horizon * -np.expm1(-total * red)
            new[i] = float(np.clip(max(clear, bounds[i][0]) + gap, *bounds[i]))
        if np.abs(new - g).max() < 1e-3:
            g = new
            break
        g = 0.5 * (g + new)          # damped: a long red lengthens the others' queues and back
    return tuple(float(d) for d in g)


__all__ = ["MAX_GAP", "expected_durations"]
