"""A traffic light's program as SUMO runs it, read from the network and additional files.

    programs = signal_programs([net_path, *additional])       # per light: Program
    programs["J"].next_green([k], t)    # a fixed light's link k: when it next shows green
    programs["J"].green_end([k], t)     # ... and when the green it shows at t ends
    green_shares(programs)              # per light: cycle, green share of each link index

A fixed program (SUMO's ``static``) is a clock: its phases at simulation time t in position
(t - offset) mod cycle. An actuated one stretches its phases with the traffic, so only their
expected durations under a demand's flows hold (:func:`under_demand`, :mod:`.actuated`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .actuated import MAX_GAP, expected_durations


def _green(state: str, links: Sequence[int]) -> bool:
    """Whether one of the link indices ``links`` shows green (``G``, ``g``, ``s``) in ``state``."""
    return any(k < len(state) and state[k] in "Ggs" for k in links)


@dataclass(frozen=True)
class Program:
    """A light's program as SUMO runs it: its (duration s, state) phases, its ``offset``, and whether
    it is ``fixed`` (type "static": SUMO runs its phases as a clock, at simulation time t in
    position (t - offset) mod cycle whatever the simulation's begin; an actuated program stretches
    them within each phase's ``bounds``, so only their expected durations hold: :func:`under_demand`)."""

    phases: tuple[tuple[float, str], ...]
    offset: float = 0.0
    fixed: bool = True
    bounds: tuple[tuple[float, float], ...] = ()    # each phase's (minDur, maxDur); () for static
    max_gap: float = MAX_GAP                        # an actuated light's max-gap param (s)

    @property
    def cycle(self) -> float:
        return sum(d for d, _ in self.phases)

    def next_green(self, links: Sequence[int], t: float) -> float:
        """The first time >= ``t`` at which one of the link indices ``links`` shows green (``G``,
        ``g``, ``s``); inf if none ever does."""
        cycle = self.cycle
        pos = (t - self.offset) % cycle
        start = 0.0
        for turn in range(2):               # this cycle from the current phase, then the next
            start = -pos if turn == 0 else cycle - pos
            for d, st in self.phases:
                end = start + d
                if end > 0 and _green(st, links):
                    return t + max(start, 0.0)
                start = end
        return float("inf")

    def green_end(self, links: Sequence[int], t: float) -> float | None:
        """When the green that one of ``links`` shows at ``t`` ends (the phases after it in which it
        stays green included); None if none of them is green at ``t``."""
        cycle = self.cycle
        pos = (t - self.offset) % cycle
        n = len(self.phases)
        start = 0.0
        for i, (d, st) in enumerate(self.phases):
            if start <= pos < start + d:
                break
            start += d
        else:
            return None
        if not _green(st, links):
            return None
        end = t + (start + d - pos)
        for j in range(1, n):           # the phases after it, while it stays green
            dj, sj = self.phases[(i + j) % n]
            if not _green(sj, links):
                break
            end += dj
        return end


def signal_programs(paths) -> dict[str, Program]:
    """Per traffic light, its :class:`Program` in ``paths`` (the network, then additional files: a
    later file's program of a light replaces an earlier one, as SUMO loads them; of several
    programs in one file, the first). The files are read as SUMO reads them (core.sumo_xml:
    includes, gzip, any root); a time SUMO would not read leaves the light out (SUMO names it)."""
    from ..core.sumo_xml import elements, seconds     # SUMO's times: seconds or h:m:s
    out: dict[str, Program] = {}
    for path in paths:
        seen: set[str] = set()
        for _, tl in elements([path], ("tlLogic",)):
            phases = tl.findall("phase")
            if tl.get("id") in seen or not phases:
                continue
            seen.add(tl.get("id"))
            durations = [seconds(ph.get("duration")) for ph in phases]
            kind = tl.get("type") or "static"
            bounds: tuple = ()
            if kind == "actuated":
                bounds = tuple((seconds(ph.get("minDur") or ph.get("duration")),
                                seconds(ph.get("maxDur") or ph.get("duration"))) for ph in phases)
            offset = seconds(tl.get("offset") or "0")
            if None in durations or offset is None or any(None in b for b in bounds) or sum(durations) <= 0:
                continue
            params = {p.get("key"): p.get("value") for p in tl.findall("param")}
            max_gap = float(params.get("max-gap", MAX_GAP)) if kind == "actuated" else MAX_GAP
            out[tl.get("id")] = Program(tuple(zip(durations, (ph.get("state") for ph in phases))), offset,
                                        kind == "static", bounds, max_gap)
    return out


def under_demand(programs: dict[str, Program], snet, flows: dict[tuple[str, str], float],
                 saturation: float) -> dict[str, Program]:
    """``programs`` with each actuated light's phases at their expected durations under ``flows``
    (veh/s per (edge, next edge); :mod:`.actuated`; ``saturation``: veh/s per lane at green); the
    others as they are."""
    from dataclasses import replace

    lanes: dict[str, dict[str, dict[int, float]]] = {}
    downstream: dict[str, dict[str, set[str]]] = {}
    one_lane: set[str] = set()
    for tls in snet.getTrafficLights():
        if tls.getID() not in programs or not programs[tls.getID()].bounds:
            continue
        per_pair: dict[tuple[str, str], int] = {}
        for a, b, k in tls.getConnections():
            key = (a.getEdge().getID(), b.getEdge().getID())
            per_pair[key] = per_pair.get(key, 0) + 1
        mine = lanes.setdefault(tls.getID(), {})
        for a, b, k in tls.getConnections():
            if sum(ln.allows("passenger") for ln in a.getEdge().getLanes()) == 1:
                one_lane.add(a.getID())
            key = (a.getEdge().getID(), b.getEdge().getID())
            mine.setdefault(a.getID(), {})[k] = flows.get(key, 0.0) / per_pair[key]
        after = downstream.setdefault(tls.getID(), {})
        for a, b, k in tls.getConnections():
            if b.getID() in mine:
                after.setdefault(a.getID(), set()).add(b.getID())
    out = dict(programs)
    for tls, lane_flows in lanes.items():
        p = programs[tls]
        states = [st for _, st in p.phases]
        durations = expected_durations(states, [d for d, _ in p.phases], p.bounds, lane_flows,
                                       saturation, p.max_gap, downstream[tls], one_lane)
        out[tls] = replace(p, phases=tuple(zip(durations, states)))
    return out


def green_shares(programs: dict[str, Program]) -> dict[str, tuple[float, np.ndarray]]:
    """Per traffic light of :func:`signal_programs`, (cycle s, green share of each link index).
    Green: ``G``/``g``/``s``, amber counted half."""
    out: dict[str, tuple[float, np.ndarray]] = {}
    for tls, program in programs.items():
        cycle = program.cycle
        n = max(len(st) for _, st in program.phases)
        green = np.zeros(n)
        for d, st in program.phases:
            green[: len(st)] += d * np.array([1.0 if c in "Ggs" else 0.5 if c in "yY" else 0.0 for c in st])
        out[tls] = (cycle, green / cycle)
    return out


def minor_green(phases: list[tuple[float, str]], k: int, j: int) -> float:
    """The share of link ``k``'s green in which it must yield (``g``) while its foe, link ``j`` of
    the same light, is green too."""
    green = sum(d for d, st in phases if k < len(st) and st[k] in "Gg")
    both = sum(d for d, st in phases if k < len(st) and j < len(st) and st[k] == "g" and st[j] in "Gg")
    return both / green if green > 0 else 0.0


__all__ = ["Program", "green_shares", "minor_green", "signal_programs", "under_demand"]
