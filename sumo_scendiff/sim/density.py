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

AUTO_RADIUS = 300.0   # m: the surroundings whose traffic level a window takes


class DensityError(ValueError):
    """One line naming the flag and the problem."""


def parse_density(text: str | None, flag: str = "--density") -> float | str | None:
    """A flag's value: None, "auto" or a density >= 0 (vehicles per km of car lane)."""
    if text is None:
        return None
    if str(text).strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        raise DensityError(f"{flag}: not a number or 'auto': {text!r}") from None
    if not np.isfinite(v) or v < 0:
        raise DensityError(f"{flag}: must be a finite number >= 0, got {text}")
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


def host_density(sim, net, window, radius: float = AUTO_RADIUS) -> float | None:
    """Vehicles per km of car lane of the host simulation's own traffic within ``radius`` m of the
    window's centre (None where no car lane is that close), per class of road: each class's density
    around the window (:func:`road_class`: a main road's queue says little about the side streets
    beside it) weighted by that class's car-lane km inside the window; the lanes inside junctions are
    a class of their own. A window with no classed lane, or whose classes have no lane around, falls
    back to the plain density of every car lane around."""
    circle = shapely.Point(window.cx, window.cy).buffer(radius)
    idx = net.lane_tree.query(circle, predicate="intersects")
    idx = idx[np.isin(idx, net.car_lane_ids)]
    km_each = shapely.length(shapely.intersection(net.lines[idx], circle)) / 1000.0
    km = float(km_each.sum())
    if km <= 0:
        return None
    lane_of = {net.lanes[i].id: i for i in idx}
    per_lane: dict[int, int] = {}
    for vid in sim.vehicle.getIDList():
        i = lane_of.get(sim.vehicle.getLaneID(vid))
        if i is not None:
            x, y = sim.vehicle.getPosition(vid)
            if (x - window.cx) ** 2 + (y - window.cy) ** 2 <= radius ** 2:
                per_lane[i] = per_lane.get(i, 0) + 1
    plain = sum(per_lane.values()) / km
    around: dict = {}
    for i, k in zip(idx.tolist(), km_each.tolist()):
        c = road_class(net, i)
        if c is not None:
            n, kk = around.get(c, (0, 0.0))
            around[c] = (n + per_lane.get(i, 0), kk + k)
    inside: dict = {}
    for i, k in zip(*net.car_lanes_in(window)):
        c = road_class(net, int(i))
        if c is not None and k > 0:
            inside[c] = inside.get(c, 0.0) + float(k)
    if not inside or any(around.get(c, (0, 0.0))[1] <= 0 for c in inside):
        return plain
    return sum(around[c][0] / around[c][1] * k for c, k in inside.items()) / sum(inside.values())


def window_target(net, window, density=None, vehicles=None, sim=None, edge_data=None,
                  time: float | None = None) -> float | None:
    """The density (veh per km of car lane) a window is generated at, or None (the model's prior)."""
    km = net.car_lane_km(window)
    if vehicles is not None:
        return vehicles / km if km > 0 else None
    if density != "auto":
        return density
    if edge_data is not None:
        return edge_data.window_density(net, window, time if time is not None else 0.0)
    if sim is not None:
        return host_density(sim, net, window)
    return None
