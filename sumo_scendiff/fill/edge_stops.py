"""The portable start's stops of one edge (``<stop edge=.../>``: SUMO picks the lane), as SUMO's own
run has them at the state's time.

    carry_edge_stops("start.rou.xml", "state.xml.gz", sim, ids)    # before the start's ids are renamed
    park_together("start.rou.xml", sim, ids)                        # the cars parked at one place

TraCI reports such a stop with neither lane nor edge (``vehicle.getStops`` gives the stop as given,
not the lane SUMO chose), and a car parked at one on no lane at all, so the portable start
(sim.export) carries the car departing from the edge after it, and its stops of one edge not at all:
it drives off where SUMO's own run keeps it parked. The state SUMO saved holds both: each vehicle's
stops still to make as given (``edge=``, the rest of a begun one's duration) and a parked car's lane
(``<vehicleTransfer parking="LANE"/>``). A vehicle with such a stop gets its stops from there, the one
it stands at on its lane; a car parked at one departs standing where it parks, on that lane, and
parks again in the step after (as a car parked in a parking area does, sim.export).
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

# what SUMO writes of a stop in a state and a route file must not carry: its begun stop starts anew
# with the rest of its duration, and one it ended is behind it
_DONE = ("started", "ended")


def _edge_only(stop: dict) -> bool:
    """Whether a ``<stop>`` (attribute dict) names only its edge: SUMO picks the lane."""
    from ..sim.stops import PLACES
    return not stop.get("lane") and not any(stop.get(k) for k in PLACES)


def state_stops(state_path: str) -> tuple[dict[str, list[dict]], dict[str, str]]:
    """From a saved state: vehicle id -> its stops still to make (attribute dicts, in order), for the
    vehicles with a stop of one edge among them; vehicle id -> the lane of each parked vehicle."""
    from ..core.sumo_xml import open_xml
    stops, parked = {}, {}
    with open_xml(state_path) as f:
        for _, el in ET.iterparse(f):
            if el.tag == "vehicle":
                left = [dict(s.attrib) for s in el.findall("stop") if s.get("ended") is None]
                if any(_edge_only(s) for s in left):
                    stops[el.get("id")] = left
                el.clear()
            elif el.tag == "vehicleTransfer" and el.get("parking"):
                parked[el.get("id")] = el.get("parking")
    return stops, parked


def _stop_element(stop: dict, lane: str | None) -> ET.Element:
    """A route file's ``<stop>`` of a state's stop (``lane``: the lane it is made on, for one of one edge)."""
    attrs = {k: v for k, v in stop.items() if k not in _DONE}
    if lane and _edge_only(stop):
        attrs.pop("edge", None)
        attrs["lane"] = lane
    el = ET.Element("stop", attrs)
    el.tail = "\n    "
    return el


def _depart_parked(root, veh, sim, vid: str, lane: str) -> None:
    """Vehicle element ``veh`` departing standing where ``vid`` parks, on the stop's ``lane``, its route
    from the stop's edge on."""
    edges = list(sim.vehicle.getRoute(vid))[sim.vehicle.getRouteIndex(vid):]
    route = next((r for r in root if r.tag == "route" and r.get("id") == veh.get("route")), None)
    if route is None or not edges or edges[0] != lane.rpartition("_")[0]:
        return
    route.set("edges", " ".join(edges))
    veh.set("departLane", lane.rpartition("_")[2])
    veh.set("departPos", f"{sim.vehicle.getLanePosition(vid):.3f}")
    veh.set("departPosLat", "0.000")
    veh.set("departSpeed", "0.000")


def carry_edge_stops(path: str, state_path: str, sim, ids) -> int:
    """Every vehicle of ``ids`` in the portable start ``path`` with a stop of one edge still to make
    given its stops as ``state_path`` holds them (the one it stands at on the lane it stands on, or
    is parked from), a car parked at one departing where it parks; returns how many vehicles."""
    stops, parked = state_stops(state_path)
    mine = [vid for vid in ids if vid in stops]
    if not mine:
        return 0
    tree = ET.parse(path)
    root = tree.getroot()
    vehicles = {el.get("id"): el for el in root if el.tag == "vehicle"}
    for vid in mine:
        veh = vehicles.get(vid)
        if veh is None:
            continue
        at = None
        if sim.vehicle.isStopped(vid):       # at its first stop: on the road, or parked off it
            at = parked.get(vid) if sim.vehicle.isStoppedParking(vid) else sim.vehicle.getLaneID(vid)
            if at and sim.vehicle.isStoppedParking(vid):
                _depart_parked(root, veh, sim, vid, at)
        for el in veh.findall("stop"):
            veh.remove(el)
        for k, stop in enumerate(stops[vid]):
            veh.append(_stop_element(stop, at if k == 0 else None))
        if len(veh):
            veh.text, veh[-1].tail = "\n        ", "\n    "
            for el in veh[:-1]:
                el.tail = "\n        "
    tree.write(path, encoding="UTF-8", xml_declaration=True)
    return len(mine)


# SUMO's insertion checks for a car departing where it parks: all but those against the other cars
# (collision, leaderGap, followerGap). Every car parked at one stop's end, or entering a parking area's
# spaces, departs at one place; with those checks SUMO inserts one a step (each after the one before
# parked off the lane), without them all in the first step, standing on one another until they park in
# the next. Not "none": the departure is not where the car stands (it stands off the lane), and
# sim.export.fit_departures moves only departures of "none" to their poses.
PARKED_CHECKS = "junction stop speedLimit arrivalSpeed pedestrian bidi oncomingTrain"


def park_together(path: str, sim, ids) -> int:
    """Every vehicle of ``ids`` that ``sim`` has parked given :data:`PARKED_CHECKS` in the portable start
    ``path`` (its ids as ``sim``'s); returns how many."""
    parked = {vid for vid in ids if sim.vehicle.isStoppedParking(vid)}
    if not parked:
        return 0
    tree = ET.parse(path)
    cars = [el for el in tree.getroot() if el.tag == "vehicle" and el.get("id") in parked]
    for el in cars:
        el.set("insertionChecks", PARKED_CHECKS)
    tree.write(path, encoding="UTF-8", xml_declaration=True)
    return len(cars)


__all__ = ["PARKED_CHECKS", "carry_edge_stops", "park_together", "state_stops"]
