"""How much traffic a window should hold, in vehicles per km of car lane (the model's density
condition), from what the user said: a number, a vehicle count, or ``auto``.

``auto`` reads the surroundings: with a host simulation, the density of its own traffic on the car
lanes within :data:`AUTO_RADIUS` of the window, per class of road (so an emptied or sparse window is
filled to the level of the same kind of road around it, and a full one gets only what is missing: the vehicles already in the window are
tokens and count towards the target); with an edgeData file, that file's density of the window's
edges at the seeding time; otherwise the model's own prior (None).
"""
from __future__ import annotations

import numpy as np
import shapely
import shapely.ops

from ..core.scene import per_km
from ..map.network import window_square
from .fleet import DEFAULT_LENGTH, DEFAULT_MIN_GAP

AUTO_RADIUS = 300.0   # m: the surroundings whose traffic level a window takes
QUEUE_ZONE = 30.0     # m before a stop line: a class of its own in host_density (docs/evaluation.md)
MODEL = "model"       # --density model: the model's own level, with a host too
# the most a lane holds: SUMO's default cars standing at their minGap
JAM_DENSITY = 1000.0 / (DEFAULT_LENGTH + DEFAULT_MIN_GAP)


class DensityError(ValueError):
    """One line naming the flag and the problem."""


def parse_density(text: str | None, flag: str = "--density") -> float | str | None:
    """A flag's value: None, "auto", "model" or a density >= 0 (vehicles per km of car lane)."""
    if text is None:
        return None
    if str(text).strip().lower() in ("auto", MODEL):
        return str(text).strip().lower()
    try:
        v = float(text)
    except ValueError:
        raise DensityError(f"{flag}: not a number, 'auto' or 'model': {text!r}") from None
    if not np.isfinite(v) or v < 0:
        raise DensityError(f"{flag}: must be a finite number >= 0, got {text}")
    if v > JAM_DENSITY:
        raise DensityError(f"{flag}: {text} veh/km is more than a lane holds with its cars standing "
                           f"(at most {JAM_DENSITY:.0f}: SUMO's default car, {DEFAULT_LENGTH:g} m with a "
                           f"{DEFAULT_MIN_GAP:g} m gap)")
    return v


def parse_vehicles(text: str | None, flag: str = "--vehicles") -> int | None:
    if text is None:
        return None
    try:
        v = float(text)
    except ValueError:
        raise DensityError(f"{flag}: not a number: {text!r}") from None
    if not np.isfinite(v) or v < 0 or v != int(v):
        raise DensityError(f"{flag}: must be a whole number >= 0, got {text}")
    return int(v)


def road_class(net, lane: int):
    """The class of road a lane belongs to, for :func:`host_density`: its edge's priority (netconvert
    ranks road types by it: a main road above a residential street); "junction" for the lanes inside
    junctions (a window's count includes them, so their vehicles and km are a class of their own)."""
    ln = net.lanes[lane]
    if ln.internal:
        return "junction"
    if net.sumo_net is None or not net.sumo_net.hasEdge(ln.edge):
        return None
    return net.sumo_net.getEdge(ln.edge).getPriority()


def _split(net, idx: np.ndarray, region, zone: float) -> tuple[np.ndarray, np.ndarray]:
    """km inside ``region`` of each lane's last ``zone`` m (before its stop line) and of the rest."""
    lines = net.lines[idx]
    inside = shapely.length(shapely.intersection(lines, region)) / 1000.0
    if zone <= 0 or not len(idx):
        return np.zeros_like(inside), inside
    length = shapely.length(lines)
    tails = np.array([shapely.ops.substring(ln, max(L - zone, 0.0), L) for ln, L in zip(lines, length)], dtype=object)
    tail = shapely.length(shapely.intersection(tails, region)) / 1000.0
    return tail, np.maximum(inside - tail, 0.0)


def _classes(net, lane: int, tail_km: float, rest_km: float):
    """(class, km) of a lane's two parts (:func:`road_class`; the junction's lanes are one class)."""
    c = road_class(net, lane)
    if c is None:
        return []
    if c == "junction":
        return [((c, 0), tail_km + rest_km)]
    return [((c, 0), tail_km), ((c, 1), rest_km)]


def host_density(sim, net, window, radius: float = AUTO_RADIUS, zone: float = QUEUE_ZONE) -> float | None:
    """Vehicles per km of car lane of the host simulation's own traffic within ``radius`` m of the
    window's centre (None where no car lane is that close), per class of road: the vehicles each
    class holds inside the window at its density around it (:func:`road_class`: a main road's queue
    says little about the side streets beside it), per km of the window's car lane (of normal edges,
    as every density here: Network.car_lane_km_in); the lanes inside junctions are a class of their
    own (their vehicles count, their km not in the divisor), and the last ``zone`` m of a lane before
    its junction one apart from the rest of it (queues stand there: a window on a junction holds more
    of them than the roads around). A window with no classed lane, or whose classes have no lane
    around, falls back to the plain density of every car lane around."""
    circle = shapely.Point(window.cx, window.cy).buffer(radius)
    idx = net.lane_tree.query(circle, predicate="intersects")
    idx = np.sort(idx[np.isin(idx, net.car_lane_ids)])
    tail_km, rest_km = _split(net, idx, circle, zone)
    normal = np.array([not net.lanes[i].internal for i in idx], dtype=bool)
    km = float((tail_km + rest_km)[normal].sum())    # the divisor: normal edges' (Network.car_lane_km_in)
    if km <= 0:
        return None
    lane_of = {net.lanes[i].id: k for k, i in enumerate(idx)}
    count = np.zeros((len(idx), 2))
    for vid in sim.vehicle.getIDList():
        k = lane_of.get(sim.vehicle.getLaneID(vid))
        if k is not None:
            x, y = sim.vehicle.getPosition(vid)
            if (x - window.cx) ** 2 + (y - window.cy) ** 2 <= radius ** 2:
                in_tail = zone > 0 and sim.vehicle.getLanePosition(vid) >= net.lanes[idx[k]].length - zone
                count[k, 0 if in_tail else 1] += 1
    plain = per_km(float(count.sum()), km)
    around: dict = {}
    for k, i in enumerate(idx.tolist()):
        parts = _classes(net, i, tail_km[k], rest_km[k])
        for part, (key, kk) in enumerate(parts):
            n, km_c = around.get(key, (0, 0.0))
            around[key] = (n + (count[k].sum() if len(parts) == 1 else count[k, part]), km_c + kk)
    win_idx, _ = net.car_lanes_in(window)
    win_tail, win_rest = _split(net, win_idx, window_square(window), zone)
    inside: dict = {}
    for i, kt, kr in zip(win_idx.tolist(), win_tail.tolist(), win_rest.tolist()):
        for key, kk in _classes(net, int(i), kt, kr):
            if kk > 0:
                inside[key] = inside.get(key, 0.0) + float(kk)
    window_km = sum(k for c, k in inside.items() if c[0] != "junction")
    if not inside or window_km <= 0 or any(around.get(c, (0, 0.0))[1] <= 0 for c in inside):
        return plain
    # the vehicles the window's classes hold at their levels around, per km of its normal car lane
    return sum(around[c][0] / around[c][1] * k for c, k in inside.items()) / window_km


def host_has_traffic(sim) -> bool:
    """Whether a host simulation carries traffic of its own whose level a window can take."""
    return sim is not None and sim.vehicle.getIDCount() > 0


def host_positions(sim) -> list[tuple[float, float]]:
    """Where the host simulation's vehicles are (front bumpers, SUMO's positions): the automatic
    windows of run and sweeps go where they are (map.locations.auto_windows' ``traffic``)."""
    return [sim.vehicle.getPosition(v) for v in sim.vehicle.getIDList()]


def default_density(density, vehicles, host: bool, has_density: bool):
    """The level a window is seeded at when the user names none: inside a host simulation that
    has traffic, the host's own level around the window ("auto": a scene seeded into running
    traffic joins it at the level it has there; the model's own level is that of its training
    networks, a third above the real cities', and a window seeded denser than the traffic around
    it hands off with more conflicts, docs/evaluation.md); without a host, or with a checkpoint
    without the density condition, the model's own (None). ``"model"`` asks for the latter."""
    if density is None and vehicles is None:
        return "auto" if host and has_density else None
    return None if density == MODEL else density


def window_target(net, window, density=None, vehicles=None, sim=None, edge_data=None,
                  time: float | None = None) -> float | None:
    """The density (veh per km of car lane) a window is generated at, or None (the model's prior)."""
    if vehicles is not None:
        return per_km(vehicles, net.car_lane_km(window))
    if density == MODEL:
        return None
    if density != "auto":
        return density
    if edge_data is not None:
        return edge_data.window_density(net, window, time if time is not None else 0.0)
    if sim is not None:
        return host_density(sim, net, window)
    return None
