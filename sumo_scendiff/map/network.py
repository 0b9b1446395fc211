"""Network: a SUMO ``.net.xml`` (or ``.net.xml.gz``) read by sumolib, as shapely geometry with spatial indices.

    net = Network.load("networks/city.net.xml")
    lanes = net.lanes_in(window)               # indices into net.lanes, via an STRtree
    hit = net.lookup(x, y, yaw)                # nearest car lane whose direction agrees
    m = net.match_poses(xy, yaws)              # ... for many poses at once (LaneMatch)
    net.on_drivable(points)                    # vectorised point-in-drivable-area test
    net.lane_heading_difference(points, yaws)  # the paper's lane heading metric

Everything is in world coordinates (SUMO network coordinates, net offset applied). The cost of a
window query depends on what lies in the window, not on the size of the network.
"""
from __future__ import annotations

import gc
import os
import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely
from shapely import STRtree

from ..core.geometry import wrap_angle
from .network_cache import cache_entry, read_entry, write_entry
# the file's lanes and junctions (Lane and Junction by this module's name too: cached networks name them so)
from .network_file import (CAR, Junction, Lane, NetworkError, NoCarLane, check_file, junction_vehicle_width,
                           read_network)
# the networks this process holds, by what they were loaded as (the path given, then the cache
# entry's key: real path, size, mtime): a long-lived caller (the studio) keeps its network and every
# run inside it gets that object instead of reading the file again; weak, so nobody else keeps one
_HELD: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


@dataclass
class LaneMatch:
    """Per pose (:meth:`Network.match_poses`): lane index (-1: none), distance along it of the
    projected point, distance from its centre line, its heading there, that point, and |yaw - heading|."""
    lane: np.ndarray
    pos: np.ndarray
    lateral: np.ndarray
    heading: np.ndarray
    xy: np.ndarray
    heading_diff: np.ndarray


def window_square(window) -> shapely.Polygon:
    """The (turned) window's square in world coordinates."""
    return shapely.Polygon(window.scene_to_world(np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]])
                                                 * 0.5 * window.size))


class Network:
    """Lanes and junctions of one SUMO network with STRtrees for window and point queries."""

    def __init__(self, path: str, lanes: list[Lane], junctions: list[Junction], sumo_net=None):
        self.path = path
        self.lanes = lanes
        self.junctions = junctions
        self.sumo_net = sumo_net
        self.lane_tree = STRtree([ln.polygon for ln in lanes])
        self.junction_tree = STRtree([j.polygon for j in junctions])
        self.car_lane_ids = np.array([i for i, ln in enumerate(lanes) if ln.car], dtype=np.int64)
        self.lines = np.array([shapely.LineString(ln.shape) if len(ln.shape) > 1
                               else shapely.LineString([ln.shape[0], ln.shape[0] + 0.01])
                               for ln in lanes], dtype=object)
        self.lane_index = {ln.id: i for i, ln in enumerate(lanes)}
        drivable = [i for i, ln in enumerate(lanes) if ln.car]
        self._drivable_geoms = [lanes[i].polygon for i in drivable] + \
            [j.polygon for j in junctions if j.type not in ("dead_end",)]
        self.drivable_tree = STRtree(self._drivable_geoms)
        xy = np.concatenate([ln.shape for ln in lanes])
        self.bounds = (*xy.min(0), *xy.max(0))

    @property
    def name(self) -> str:
        """The file name without extension; the folder's name for generic names (``net.net.xml``)."""
        base = os.path.basename(self.path)
        for ext in (".net.xml.gz", ".net.xml", ".xml.gz", ".xml"):
            if base.endswith(ext):
                base = base[: -len(ext)]
                break
        if base.lower() in ("net", "osm", "map", "network"):
            return os.path.basename(os.path.dirname(os.path.abspath(self.path))) or base
        return base

    @classmethod
    def load(cls, path: str, cache: bool = True) -> "Network":
        """The network of a ``.net.xml[.gz]`` file; with ``cache``, read once and kept in the cache
        directory (:func:`cache_entry`) for the next process that loads the same, unchanged file, and
        the very object while this process still holds one loaded from the same path."""
        path = os.fspath(path)
        check_file(path)
        entry = cache_entry(path) if cache else None
        held = _HELD.get((path, *entry.key)) if entry else None
        if held is not None:
            return held
        collecting = gc.isenabled()
        gc.disable()    # unpickling ~100k objects, each allocation would count towards a collection
        try:
            parts = read_entry(entry) if entry else None
        finally:
            if collecting:
                gc.enable()
        network = cls(path, *parts) if parts else None
        if network is None:
            network = cls._read_file(path)
            if entry:
                write_entry(network, entry)
            gc.collect()     # the parser's garbage, before the rest is frozen
        # A big network is ~100k long-lived Python objects; without this, every full garbage collection
        # triggered by per-window work walks them all, and a 100 m window costs more on a larger net
        # (benchmarks/raster.py).
        gc.freeze()
        if entry:
            _HELD[(path, *entry.key)] = network
        return network

    @classmethod
    def _read_file(cls, path: str) -> "Network":
        return cls(path, *read_network(path))

    @cached_property
    def edge_car_km(self) -> dict[str, float]:
        """Normal edge id -> kilometres of its car lanes (sidewalks and bike lanes left out): the
        denominator of an edge's density in vehicles per km of car lane."""
        km: dict[str, float] = {}
        for i in self.car_lane_ids:
            ln = self.lanes[i]
            if not ln.internal:
                km[ln.edge] = km.get(ln.edge, 0.0) + ln.length / 1000.0
        return km

    @cached_property
    def junction_vehicle_width(self) -> float:
        """The vehicle width netconvert placed the waiting positions inside junctions for
        (:func:`~.network_file.junction_vehicle_width`)."""
        return junction_vehicle_width(self.path)

    @cached_property
    def shared_lanes(self) -> dict[int, int]:
        """Per car lane of an edge that has a ``bidi`` edge (one road, both directions on it), the
        bidi edge's car lane it lies on (more than half of its area); indices into ``lanes``.
        SUMO lets no vehicle onto such a lane while an oncoming one is on it."""
        out: dict[int, int] = {}
        if self.sumo_net is None:
            return out
        car = {ln.id: i for i, ln in enumerate(self.lanes) if ln.car}
        for edge in self.sumo_net.getEdges():
            bidi = edge.getBidi()
            if not bidi:
                continue
            if isinstance(bidi, str):
                if not self.sumo_net.hasEdge(bidi):
                    continue
                bidi = self.sumo_net.getEdge(bidi)
            for a in edge.getLanes():
                i = car.get(a.getID())
                if i is None:
                    continue
                overlaps = [(self.lanes[i].polygon.intersection(self.lanes[j].polygon).area, j)
                            for j in (car.get(b.getID()) for b in bidi.getLanes()) if j is not None]
                area, j = max(overlaps, default=(0.0, None))
                if j is not None and area > 0.5 * self.lanes[i].polygon.area:
                    out[i] = j
        return out

    @cached_property
    def signal_links(self) -> list:
        """Every traffic-light-controlled link (:class:`~.signals.SignalLink`), read once."""
        from .signals import signal_links
        return signal_links(self) if self.sumo_net is not None else []

    @cached_property
    def _signal_links_by_lane(self) -> dict[int, list[int]]:
        out: dict[int, list[int]] = {}
        for k, link in enumerate(self.signal_links):
            out.setdefault(link.lane, []).append(k)
            if link.via >= 0:
                out.setdefault(link.via, []).append(k)
        return out

    def signal_links_in(self, window) -> list[int]:
        """Indices into :attr:`signal_links` of the links whose incoming or via lane the window touches."""
        by_lane = self._signal_links_by_lane
        return sorted({k for i in self.lanes_in(window).tolist() for k in by_lane.get(i, ())})

    def lights_in(self, window) -> list[str]:
        """Ids of the traffic lights controlling a link the window touches."""
        return sorted({self.signal_links[k].tls for k in self.signal_links_in(window)})

    # ---- window queries -------------------------------------------------------------------
    def lanes_in(self, window) -> np.ndarray:
        """Indices of lanes whose polygon intersects the (rotated) window's bounding box."""
        box = shapely.box(*window.world_bounds())
        return np.sort(self.lane_tree.query(box, predicate="intersects"))

    def junctions_in(self, window) -> np.ndarray:
        box = shapely.box(*window.world_bounds())
        return np.sort(self.junction_tree.query(box, predicate="intersects"))

    def in_junction(self, points) -> np.ndarray:
        """Per point (N, 2 world), whether it lies inside a junction's shape and on no lane of a
        normal edge (a lane's end may reach into the junction's outline: a point there is on it)."""
        pts = shapely.points(np.asarray(points, np.float64).reshape(-1, 2))
        inside = np.zeros(len(pts), bool)
        if len(pts) and len(self.junctions):
            inside[self.junction_tree.query(pts, predicate="within")[0]] = True
        if inside.any():   # a front at its lane's very end stands on the lane's outline: 0.5 m of slack
            at, lane = self.lane_tree.query(pts[inside], predicate="dwithin", distance=0.5)
            normal = np.array([self.lanes[i].function == "" for i in lane.tolist()], bool)
            inside[np.flatnonzero(inside)[np.unique(at[normal])]] = False
        return inside

    def has_road(self, window) -> bool:
        """Whether any car lane crosses the window's square."""
        square = window_square(window)
        idx = self.lane_tree.query(square, predicate="intersects")
        return any(self.lanes[i].car for i in idx)

    def car_lanes_in(self, window, internal: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(lane indices, km of each inside the window's square) of the car lanes crossing it
        (``internal``: junction-internal lanes included)."""
        return self.car_lanes_in_region(window_square(window), internal)

    def car_lanes_in_region(self, region, internal: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(lane indices, km of each inside a shapely region) of the car lanes crossing it
        (``internal``: junction-internal lanes included)."""
        idx = self.lane_tree.query(region, predicate="intersects")
        idx = np.sort(idx[np.isin(idx, self.car_lane_ids if internal else self.normal_car_lane_ids)])
        return idx, shapely.length(shapely.intersection(self.lines[idx], region)) / 1000.0

    @cached_property
    def normal_car_lane_ids(self) -> np.ndarray:
        """The car lanes of normal edges (no junction-internal lane)."""
        return np.array([i for i in self.car_lane_ids if not self.lanes[i].internal], dtype=np.int64)

    def car_lane_km(self, window) -> float:
        """Kilometres of car lane inside the window's square (:meth:`car_lane_km_in`)."""
        return self.car_lane_km_in(window_square(window))

    def condition_km(self, window) -> float:
        """Kilometres of every car lane inside the window's square, junction-internal lanes
        included: the divisor of the model's density condition (what its training windows were
        given), not of a density a user asks for (:meth:`car_lane_km`)."""
        return float(self.car_lanes_in(window, internal=True)[1].sum())

    def car_lane_km_in(self, region) -> float:
        """Kilometres of car lane of normal edges inside a shapely region: the divisor of every density
        in vehicles per km of car lane (a window's, a fill's, an area's), as SUMO's edgeData divides
        (its ``density`` is per km of a normal edge, ``laneDensity`` per lane-km; junction-internal
        lanes are not measured unless ``withInternal``). The vehicles on internal lanes still count
        in the numerator. edgeData's ``sampledSeconds`` counts a vehicle on every lane any part of it
        is on (one entering a junction counts on its approach until its back has left it), its
        ``density`` (SUMO 1.28) on the lane of its front bumper: a vehicle whose front is inside a
        junction is in no normal edge's ``density`` (MSMeanData's notifyMove; docs/sumo-options.md)."""
        return float(self.car_lanes_in_region(region, internal=False)[1].sum())

    def region_density(self, region, edge_density: dict[str, float]) -> float | None:
        """Vehicles per km of car lane in a shapely region from each normal edge's density (vehicles
        per km of car lane; an edge not named holds none): the edges' densities weighted by their
        car-lane km inside the region, over that km (:meth:`car_lane_km_in`); None where the region
        has no car lane of a normal edge."""
        idx, km = self.car_lanes_in_region(region, internal=False)
        den = float(km.sum())
        num = sum(edge_density.get(self.lanes[i].edge, 0.0) * k for i, k in zip(idx.tolist(), km.tolist()))
        return num / den if den > 0 else None

    # ---- point queries --------------------------------------------------------------------
    def on_drivable(self, points) -> np.ndarray:
        """Bool array: which world points (..., 2) lie on a car lane or a junction area."""
        pts = np.asarray(points, dtype=np.float64)
        flat = pts.reshape(-1, 2)
        out = np.zeros(len(flat), dtype=bool)
        if len(flat):
            geoms = shapely.points(flat)
            hit = self.drivable_tree.query(geoms, predicate="intersects")
            out[np.unique(hit[0])] = True
        return out.reshape(pts.shape[:-1])

    def lane_headings_at(self, points, radius: float = 0.0):
        """(point index, lane index, lane heading) for every car lane within ``radius`` m of each point."""
        flat = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        geoms = shapely.points(flat)
        if radius > 0:
            pi, li = self.lane_tree.query(geoms, predicate="dwithin", distance=radius)
        else:
            pi, li = self.lane_tree.query(geoms, predicate="intersects")
        keep = np.isin(li, self.car_lane_ids)
        pi, li = pi[keep], li[keep]
        return pi, li, self._heading_on_lines(li, flat[pi])

    def _heading_on_lines(self, lane_idx, xy) -> np.ndarray:
        lines = self.lines[lane_idx]
        pts = shapely.points(xy)
        d = shapely.line_locate_point(lines, pts)
        # clamp: shapely counts negative distances from the line's end
        a = shapely.get_coordinates(shapely.line_interpolate_point(lines, np.maximum(d - 0.5, 0.0)))
        b = shapely.get_coordinates(shapely.line_interpolate_point(
            lines, np.minimum(d + 0.5, shapely.length(lines))))
        if len(lane_idx) == 0:
            return np.zeros(0)
        return np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])

    def lane_heading_difference(self, points, yaws, radius: float = 2.0) -> np.ndarray:
        """Minimum |heading - lane heading| over car lanes at each point (NaN where none within radius)."""
        flat_yaw = np.asarray(yaws, dtype=np.float64).reshape(-1)
        out = np.full(len(flat_yaw), np.nan)
        pi, li, head = self.lane_headings_at(points, radius=radius)
        if len(pi):
            diff = np.abs(wrap_angle(flat_yaw[pi] - head))
            np.fmin.at(out, pi, diff)
        return out.reshape(np.shape(yaws))

    def match_poses(self, points, yaws=None, radius: float = 3.0, max_angle: float = np.pi / 3,
                    allow_internal: bool = True) -> "LaneMatch":
        """For each world pose, the car lane it stands on: among car lanes whose polygon lies within
        ``radius`` m and whose direction agrees with the yaw within ``max_angle``, the one with the least
        ``distance to the centre line + 2 m/rad x heading difference`` (0.5 rad of disagreement costs
        like 1 m of offset). ``yaws`` None: direction ignored. Vectorised; ``lane`` is -1 where none."""
        xy = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        n = len(xy)
        yaw = np.zeros(n) if yaws is None else np.asarray(yaws, dtype=np.float64).reshape(-1)
        out = LaneMatch(np.full(n, -1, np.int64), np.zeros(n), np.full(n, np.inf), np.zeros(n),
                        xy.copy(), np.zeros(n))
        if n == 0:
            return out
        pts = shapely.points(xy)
        pi, li = self.lane_tree.query(pts, predicate="dwithin", distance=radius)
        ok = np.isin(li, self.car_lane_ids)
        if not allow_internal:
            ok &= ~np.array([self.lanes[i].internal for i in li], dtype=bool)
        pi, li = pi[ok], li[ok]
        if len(pi) == 0:
            return out
        lines = self.lines[li]
        dist = shapely.distance(lines, pts[pi])
        heading = self._heading_on_lines(li, xy[pi])
        hd = np.zeros(len(pi)) if yaws is None else np.abs(wrap_angle(yaw[pi] - heading))
        agree = hd <= max_angle
        pi, li, dist, heading, hd = pi[agree], li[agree], dist[agree], heading[agree], hd[agree]
        score = dist + 2.0 * hd
        order = np.lexsort((score, pi))                  # per point, best candidate first
        first = order[np.r_[True, pi[order][1:] != pi[order][:-1]]] if len(order) else order
        p, lane = pi[first], li[first]
        pos = shapely.line_locate_point(self.lines[lane], pts[p])
        out.lane[p], out.pos[p], out.lateral[p] = lane, pos, dist[first]
        out.heading[p], out.heading_diff[p] = heading[first], hd[first]
        out.xy[p] = shapely.get_coordinates(shapely.line_interpolate_point(self.lines[lane], pos))
        return out

    def lookup(self, x: float, y: float, yaw: float | None = None, radius: float = 3.0,
               max_angle: float = np.pi / 3, allow_internal: bool = True):
        """The car lane a pose stands on (:meth:`match_poses` for one pose).

        Returns ``(lane, pos, lateral, heading_diff)`` with ``pos`` the distance along the lane of the
        projected point, or ``None``.
        """
        m = self.match_poses([[x, y]], None if yaw is None else [yaw], radius, max_angle, allow_internal)
        if m.lane[0] < 0:
            return None
        return self.lanes[m.lane[0]], float(m.pos[0]), float(m.lateral[0]), float(m.heading_diff[0])

    # ---- the lane graph -------------------------------------------------------------------
    @cached_property
    def successors(self) -> list[list[int]]:
        """Per lane index, the car lanes a vehicle drives onto from its end: the connection's internal
        lane where the junction has one, else the next edge's lane (empty without a sumolib net)."""
        out: list[list[int]] = [[] for _ in self.lanes]
        if self.sumo_net is None:
            return out
        for i in self.car_lane_ids:
            for c in self.sumo_net.getLane(self.lanes[i].id).getOutgoing():
                j = self.lane_index.get(c.getViaLaneID() or c.getToLane().getID())
                if j is not None and self.lanes[j].car and j not in out[i]:
                    out[i].append(j)
        return out

    @cached_property
    def predecessors(self) -> list[list[int]]:
        """Per lane index, the car lanes that lead onto it (:attr:`successors` reversed)."""
        out: list[list[int]] = [[] for _ in self.lanes]
        for i, succ in enumerate(self.successors):
            for j in succ:
                out[j].append(i)
        return out

    def lane_pose(self, lane: int, pos: float) -> tuple[np.ndarray, float]:
        """The world point ``pos`` m along lane ``lane``'s centre line (clamped to it) and the lane's
        heading there (over +-0.5 m, as :meth:`match_poses` measures it)."""
        line = self.lines[lane]
        pos = min(max(pos, 0.0), line.length)
        xy = np.asarray(line.interpolate(pos).coords[0])
        return xy, float(self._heading_on_lines(np.array([lane]), xy[None])[0])

    def random_road_points(self, n: int, rng: np.random.Generator, internal: bool = False):
        """``n`` points uniformly along car lanes (by length) with their lane headings."""
        ids = [i for i in self.car_lane_ids if internal or not self.lanes[i].internal] or \
            list(self.car_lane_ids)
        lengths = np.array([max(self.lines[i].length, 1e-3) for i in ids])
        pick = rng.choice(len(ids), size=n, p=lengths / lengths.sum())
        lane_idx = np.asarray(ids)[pick]
        d = rng.random(n) * lengths[pick]
        xy = shapely.get_coordinates(shapely.line_interpolate_point(self.lines[lane_idx], d))
        return xy, self._heading_on_lines(lane_idx, xy)


__all__ = ["CAR", "Junction", "Lane", "LaneMatch", "Network", "NetworkError", "NoCarLane", "window_square"]
