"""A SUMO network file read into lanes and junctions with their shapely outlines: the file checked
(:func:`check_file`), read by sumolib (:func:`read_network`), and what its header records
(:func:`junction_vehicle_width`). :class:`~sumo_scendiff.map.network.Network` holds them with
their spatial indices and answers the queries.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import shapely

CAR = "passenger"


class NetworkError(ValueError):
    """A network file that cannot be used; the message names the file and the problem."""


class NoCarLane(NetworkError):
    """A network without a lane a passenger car may use (a railway, a pedestrian zone): stock SUMO
    runs it, the model has nowhere to draw a vehicle. A user's scenario on one ends with nothing
    generated (run, fill); a bare ``-n`` on one is an error."""


NETCONVERT_VEHICLE_WIDTH = 1.8   # m: netconvert's default --internal-junctions.vehicle-width


@dataclass
class Lane:
    id: str
    edge: str
    index: int
    function: str              # "" (normal), "internal", "crossing", "walkingarea"
    shape: np.ndarray          # (K, 2) centre line
    width: float
    speed: float
    length: float
    car: bool                  # a passenger car may drive here
    pedestrian_only: bool      # sidewalk / walking area / crossing
    tls: bool                  # the lane ends at a traffic-light-controlled stop line
    stop_line: bool            # the lane ends at a junction (its end is a stop line)
    polygon: shapely.Polygon

    ring: np.ndarray = None    # exterior ring of the polygon (K, 2), for drawing
    seg_yaw: np.ndarray = None  # world heading of each centre-line segment (K - 1,)

    def __post_init__(self):
        self.ring = _exterior(self.polygon)
        d = np.diff(self.shape, axis=0)
        self.seg_yaw = np.arctan2(d[:, 1], d[:, 0])

    @property
    def internal(self) -> bool:
        return self.function == "internal"


@dataclass
class Junction:
    id: str
    type: str
    polygon: shapely.Polygon
    ring: np.ndarray = None

    def __post_init__(self):
        self.ring = _exterior(self.polygon)


def _exterior(geom) -> np.ndarray:
    """Exterior ring of a polygon (the largest part of a multipolygon) as a (K, 2) array."""
    if geom.geom_type == "MultiPolygon":
        geom = max(geom.geoms, key=lambda g: g.area)
    if geom.geom_type != "Polygon" or geom.is_empty:
        return np.zeros((0, 2))
    return np.asarray(geom.exterior.coords)[:, :2]


def check_file(path: str) -> None:
    if not os.path.exists(path):
        raise NetworkError(f"{path}: no such file")
    if os.path.isdir(path):
        raise NetworkError(f"{path}: is a directory, not a SUMO network file")
    if os.path.getsize(path) == 0:
        raise NetworkError(f"{path}: empty file")
    from ..core.sumo_xml import open_xml     # gzipped or not by its bytes, as SUMO and readNet read it
    try:
        with open_xml(path) as f:
            head = f.read(4096)
    except (OSError, EOFError) as e:
        raise NetworkError(f"{path}: cannot read ({e})") from None
    if b"<net" not in head:
        raise NetworkError(f"{path}: not a SUMO network (no <net> element at the top)")


def _read(path: str):
    import sumolib  # lazy: sumolib import is slow-ish and pulls lxml
    try:
        return sumolib.net.readNet(path, withInternal=True, withPedestrianConnections=True)
    except Exception as e:  # lxml / sax / sumolib raise many kinds; all mean a broken file
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise NetworkError(f"{path}: not a readable SUMO network ({msg})") from None


def _lane_polygon(shape: np.ndarray, width: float) -> shapely.Polygon:
    # netconvert writes a zero-length connection of OSM's joined junctions as two equal points,
    # whose flat-capped buffer is empty: such a lane is the disc of its width, never an empty
    # footprint (no query finds it, and a distance to it is NaN)
    line = shapely.LineString(shape) if len(shape) > 1 else shapely.Point(shape[0])
    if line.length == 0.0:
        return shapely.Point(shape[0]).buffer(0.5 * width)
    return line.buffer(0.5 * width, cap_style="flat", join_style="mitre", mitre_limit=3.0)


def read_network(path: str) -> tuple[list[Lane], list[Junction], object]:
    """(lanes, junctions, sumolib net) of the network file ``path`` (checked by :func:`check_file`
    first); raises :class:`NoCarLane` where no lane is a passenger car's."""
    net = _read(path)
    tls_lanes, stop_lanes = set(), set()
    for edge in net.getEdges(withInternal=False):
        for lane in edge.getLanes():
            for conn in lane.getOutgoing():
                stop_lanes.add(lane.getID())
                if conn.getTLSID():
                    tls_lanes.add(lane.getID())
    lanes: list[Lane] = []
    for edge in net.getEdges(withInternal=True):
        function = edge.getFunction() or ""
        for lane in edge.getLanes():
            shape = np.asarray(lane.getShape(), dtype=np.float64)[:, :2]
            if len(shape) == 0:
                continue
            width = float(lane.getWidth())
            car = bool(lane.allows(CAR)) and function in ("", "internal")
            ped_only = function in ("crossing", "walkingarea") or (
                lane.allows("pedestrian") and not lane.allows(CAR) and not lane.allows("bicycle"))
            poly = _lane_polygon(shape, width)
            if function == "walkingarea":
                poly = shapely.Polygon(shape) if len(shape) >= 3 else poly
                poly = poly if poly.is_valid else poly.buffer(0)
            lanes.append(Lane(lane.getID(), edge.getID(), lane.getIndex(), function, shape, width,
                              float(lane.getSpeed()), float(lane.getLength()), car, ped_only,
                              lane.getID() in tls_lanes, lane.getID() in stop_lanes, poly))
    junctions = []
    for node in net.getNodes():
        shp = node.getShape()
        if shp is None or len(shp) < 3:
            continue
        poly = shapely.Polygon(np.asarray(shp, dtype=np.float64)[:, :2])
        if not poly.is_valid:
            poly = poly.buffer(0)
        if poly.is_empty or poly.area <= 0:
            continue
        junctions.append(Junction(node.getID(), node.getType(), poly))
    if not any(ln.car for ln in lanes):
        raise NoCarLane(f"{path}: the network has no lane a passenger car may use")
    return lanes, junctions, net


def junction_vehicle_width(path: str) -> float:
    """The vehicle width netconvert placed the waiting positions inside junctions for (its
    ``--internal-junctions.vehicle-width``, recorded in the file's header when not the default
    1.8 m): a wider vehicle waiting there, or passing one that waits, touches the other."""
    import re

    import sumolib
    head = ""
    try:
        with sumolib.openz(path) as f:
            for line in f:
                head += line
                if "<net " in line or len(head) > 200_000:
                    break
    except OSError:
        pass
    m = re.search(r'<internal-junctions\.vehicle-width value="([0-9.eE+-]+)"', head)
    return float(m.group(1)) if m else NETCONVERT_VEHICLE_WIDTH


__all__ = ["CAR", "Junction", "Lane", "NETCONVERT_VEHICLE_WIDTH", "NetworkError", "NoCarLane", "check_file",
           "junction_vehicle_width", "read_network"]
