"""Traffic density from SUMO's own edgeData (meandata) files: a user's counts or a calibrated run.

    data = EdgeData.read("counts.xml", net)                   # checked against the network
    d = data.window_density(net, window, time=28800.0)        # vehicles per km of car lane

Per edge and interval, the density per car lane in vehicles per km: the edge's ``density``
divided by its car lanes, else SUMO's ``laneDensity`` (the density over its lanes open to vehicles,
bike lanes too) times those lanes over its car lanes, else ``sampledSeconds`` over the interval's
duration and the edge's car-lane kilometres (SUMO's own definitions, "Lane- or Edge-based Traffic
Measures"; read per lane, an edge with a bike lane counted half its vehicles). A laneData file
(SUMO's ``--lanedata-output``, per lane) gives an edge the mean of its car lanes' densities, a car
lane it does not list empty. A window's density weighs its edges by the car-lane length they have inside it (normal
edges only: SUMO's edgeData measures no junction-internal lane unless asked, map/network.py); an edge
the file does not list in the interval holds no vehicle (SUMO's ``--edgedata-output`` writes only
the edges a vehicle used), so a window none of whose edges is listed is empty, not unknown.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from .network import window_square


class EdgeDataError(ValueError):
    """One line: the file and the problem."""


@dataclass(frozen=True)
class Interval:
    begin: float
    end: float
    density: dict[str, float]        # edge id -> vehicles per km of lane


@dataclass(frozen=True)
class EdgeData:
    path: str
    intervals: tuple[Interval, ...]

    @classmethod
    def read(cls, path: str, net=None) -> "EdgeData":
        """Read ``path``; with ``net``, it must name at least one of the network's edges."""
        import xml.sax
        from xml.etree.ElementTree import ParseError

        from sumolib.xml import parse

        from ..core.sumo_xml import seconds     # seconds, or h:m:s (--human-readable-time)
        if not os.path.isfile(path):
            raise EdgeDataError(f"{path}: no such file")
        lanes = _lanes_per_edge(net) if net is not None else {}
        # SUMO's own lane lengths: the ones its sampledSeconds are per
        car_lanes = {ln.id: ln.length / 1000.0 for ln in net.lanes if ln.car} if net is not None else None
        intervals = []
        try:
            for iv in parse(path, "interval"):
                begin, end = seconds(iv.begin), seconds(iv.end)
                if begin is None or end is None:
                    raise ValueError(f"interval begin {iv.begin!r} / end {iv.end!r} is not a time")
                dens = {}
                for e in iv.getChild("edge") if iv.hasChild("edge") else ():
                    d = _lane_density(e, end - begin, lanes.get(e.id))
                    if d is None and e.hasChild("lane"):      # laneData
                        d = _from_lanes(e, end - begin, lanes.get(e.id), car_lanes)
                    if d is not None:
                        dens[e.id] = d
                intervals.append(Interval(begin, end, dens))
        except (xml.sax.SAXException, ParseError, AttributeError, ValueError, TypeError) as e:
            raise EdgeDataError(f"{path}: not a SUMO edgeData file ({str(e).splitlines()[0]})") from None
        if not intervals:
            raise EdgeDataError(f"{path}: not a SUMO edgeData file (no <interval> element)")
        if not any(iv.density for iv in intervals):
            raise EdgeDataError(f"{path}: no edge with density, laneDensity or sampledSeconds")
        if net is not None and not any(e in lanes for iv in intervals for e in iv.density):
            raise EdgeDataError(f"{path}: names no edge of the network {net.path}")
        return cls(path, tuple(sorted(intervals, key=lambda iv: iv.begin)))

    def at(self, time: float) -> Interval:
        """The interval covering ``time`` (s)."""
        for iv in self.intervals:
            if iv.begin <= time < iv.end or (time == iv.end == self.intervals[-1].end):
                return iv
        raise EdgeDataError(f"{self.path}: no interval covers t = {time:g} s (intervals "
                            f"{self.intervals[0].begin:g}-{self.intervals[-1].end:g} s)")

    def window_density(self, net, window, time: float) -> float | None:
        """Vehicles per km of car lane in ``window`` at ``time`` (:meth:`region_density` of its square)."""
        return self.region_density(net, window_square(window), time)

    def region_density(self, net, region, time: float) -> float | None:
        """Vehicles per km of car lane in a shapely region at ``time``: the listed edges' densities
        over the region's car lanes of normal edges (:meth:`Network.region_density`: unlisted edges
        empty, junction-internal lanes not in the divisor, as edgeData measures); None where the
        region has no such lane."""
        return net.region_density(region, self.at(time).density)


def _lanes_per_edge(net) -> dict[str, tuple[int, int, float]]:
    """edge id -> (lanes open to vehicles, car lanes, car-lane kilometres: Network.edge_car_km)."""
    counts: dict[str, tuple[int, int]] = {}
    for ln in net.lanes:
        n, cars = counts.get(ln.edge, (0, 0))
        counts[ln.edge] = (n + int(not ln.pedestrian_only), cars + int(ln.car))
    return {e: (n, cars, net.edge_car_km.get(e, 0.0)) for e, (n, cars) in counts.items()}


def _number(e, name: str) -> float | None:
    v = getattr(e, name, None)
    return None if v in (None, "") else float(v)


def _from_lanes(e, duration: float, lanes: tuple[int, int, float] | None,
                car_lanes: dict[str, float] | None) -> float | None:
    """Vehicles per km of car lane of an edge from its lanes' elements (a laneData file): the sum of
    its car lanes' densities (``density``, else ``sampledSeconds`` over the interval and the lane's
    km; ``car_lanes``: lane id -> km) over its car lanes (one the file leaves out: none on it)."""
    listed = [ln for ln in e.getChild("lane") if car_lanes is None or ln.id in car_lanes]
    each = []
    for ln in listed:
        d, samples, km = _number(ln, "density"), _number(ln, "sampledSeconds"), (car_lanes or {}).get(ln.id, 0.0)
        if d is None and samples is not None:
            d = 0.0 if samples == 0 else samples / duration / km if duration > 0 and km > 0 else None
        each.append(d)
    if not listed or any(d is None for d in each):
        return None
    cars = lanes[1] if lanes is not None else len(listed)
    return sum(each) / cars if cars else None


def _lane_density(e, duration: float, lanes: tuple[int, int, float] | None) -> float | None:
    """Vehicles per km of car lane of one edge element (None when it says nothing about density;
    without the network, each lane taken for a car lane)."""
    n, cars, km = lanes or (1, 1, 0.0)
    if lanes is not None and cars == 0:
        return None
    if _number(e, "density") is not None:
        return _number(e, "density") / cars
    if _number(e, "laneDensity") is not None:
        return _number(e, "laneDensity") * n / cars
    samples = _number(e, "sampledSeconds")
    if samples is not None and duration > 0 and km > 0:
        return samples / duration / km
    return None
