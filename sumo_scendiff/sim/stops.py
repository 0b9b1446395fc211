"""A vehicle's stops (a bus at its stops, a car parking), given to a seeded vehicle and written out.

    kept = add_stops(sim, "fill3.0", [{"busStop": "bs1", "duration": "20"}, {"lane": "e_0", "endPos": "50"}],
                     at=("e", 75.0))                    # it stands 75 m along edge e: bs1 there is behind
    drop_passed(sim, "fill3.0")                         # after a step: the stops it has moved past
    xml = stops_xml(sim, "fill3.0")                     # "<stop .../>" lines for a route file
    prune_file_stops("start.rou.xml", place_ends(additional, net))   # what SUMO would refuse to load

A seeded vehicle that stands for a demand vehicle drives that vehicle's route on, and with it the
stops still ahead of it, as a SUMO user cuts a line's schedule at a time: the stops already passed
are dropped. A stop is passed when it lies on the edge the vehicle stands on and ends before its
front (SUMO's own test when it loads a vehicle: "is not downstream the current route"); SUMO's
``vehicle.setStop`` takes the others in route order, and one it refuses (on an edge its route no
longer has, too close to brake for) is left out. A vehicle is added departing at its edge's start
and then moved to its pose (sim/seeding.py), so SUMO alone would keep the stops behind it.
"""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

from ..core.sumo_xml import boolean

# SUMO's stop flags (libsumo.constants STOP_*) and the stopping place each names
PARKING, TRIGGERED, CONTAINER_TRIGGERED = 1, 2, 4
PLACES = {"busStop": 8, "trainStop": 8, "containerStop": 16, "chargingStation": 32, "parkingArea": 64}
INVALID = -1073741824.0     # libsumo's INVALID_DOUBLE_VALUE: "not given"
# libsumo's domain of each stopping place (their end positions)
DOMAINS = {"busStop": "busstop", "trainStop": "busstop", "containerStop": "containerstop",
           "chargingStation": "chargingstation", "parkingArea": "parkingarea"}
# m: a portable start whose departure was nudged this far past the end of the stop the vehicle
# stands at (sim.export.fit_departures moves it to its box centre) departs at the stop's end instead
NUDGE_M = 1.0


def _time(value: str | None) -> float:
    """A SUMO time (core.sumo_xml.seconds), "not given" or unreadable as :data:`INVALID`."""
    from ..core.sumo_xml import seconds
    t = seconds(value) if value else None
    return INVALID if t is None else t


def _places(additional):
    """Every stopping place element of the additional files (any tag of :data:`PLACES` with a lane),
    read as SUMO reads them (core.sumo_xml: includes, gzip, any root), as (id, lane, endPos)."""
    from ..core.sumo_xml import elements
    for _, el in elements(additional, PLACES):
        if el.get("lane"):
            yield el.get("id"), el.get("lane"), el.get("endPos")


def stopping_places(additional) -> dict[str, str]:
    """Every stopping place (bus and train stops, container stops, charging stations, parking
    areas) of the additional files: id -> its lane."""
    return {pid: lane for pid, lane, _ in _places(additional)}


def place_ends(additional, net) -> dict[str, tuple[str, float]]:
    """Every stopping place of the additional files: id -> (its edge, its end position on its
    lane), as SUMO reads ``endPos`` (default the lane's end, a negative one from the lane's end)."""
    snet = net.sumo_net
    out = {}
    for pid, lane, end_pos in _places(additional):
        edge = lane.rpartition("_")[0]
        if not snet.hasEdge(edge):
            continue                     # SUMO names the stray lane when it loads the file
        length = snet.getLane(lane).getLength()
        end = _time(end_pos)             # a plain number; "not given" as INVALID
        out[pid] = (edge, length if end == INVALID else end + length if end < 0 else end)
    return out


def stop_lane(stop: dict, places: dict[str, str]) -> str | None:
    """The lane a ``<stop>`` (attribute dict) is on: its own, or its stopping place's."""
    place = next((stop[k] for k in PLACES if stop.get(k)), None)
    return stop.get("lane") or (places.get(place) if place else None)


def stop_until(stop: dict) -> float | None:
    """The time a ``<stop>`` (attribute dict) holds its vehicle until (its ``until``), None if it names none."""
    t = _time(stop.get("until"))
    return None if t == INVALID else t


def stop_seconds(stop: dict) -> float:
    """How long a ``<stop>`` (attribute dict) holds its vehicle, as far as it says (its duration)."""
    d = _time(stop.get("duration"))
    return max(d, 0.0) if d != INVALID else 0.0


def _sim_end(sim, s: dict) -> tuple[str | None, float | None]:
    """(edge, end position) of a ``<stop>`` (attribute dict) in the running simulation ``sim``."""
    place = next((k for k in PLACES if s.get(k)), None)
    try:
        if place:
            domain = getattr(sim, DOMAINS[place])
            return domain.getLaneID(s[place]).rpartition("_")[0], float(domain.getEndPos(s[place]))
        if s.get("lane"):
            end = float(s["endPos"]) if s.get("endPos") else sim.lane.getLength(s["lane"])
            return s["lane"].rpartition("_")[0], end
    except Exception:   # an unknown place or lane: setStop names it
        pass
    return None, None


def add_stops(sim, vid: str, stops, at: tuple[str, float] | None = None) -> int:
    """Give vehicle ``vid`` the ``stops`` (attribute dicts of SUMO ``<stop>`` elements, in order) that
    its route still reaches; returns how many it took. ``at``: (edge, front position) where it
    stands: the stops on that edge that end before it are passed, left out."""
    kept = 0
    for s in stops:
        if at is not None:
            edge, end = _sim_end(sim, s)
            if edge == at[0] and end is not None and end < at[1]:
                continue
        flags = (PARKING if boolean(s.get("parking")) else 0) | (TRIGGERED if boolean(s.get("triggered")) else 0) \
            | (CONTAINER_TRIGGERED if boolean(s.get("containerTriggered")) else 0)
        duration, until = _time(s.get("duration")), _time(s.get("until"))
        place = next((k for k in PLACES if s.get(k)), None)
        try:
            if place:
                sim.vehicle.setStop(vid, s[place], flags=flags | PLACES[place], duration=duration, until=until)
            elif s.get("lane"):
                edge, _, index = s["lane"].rpartition("_")
                end = float(s["endPos"]) if s.get("endPos") else sim.lane.getLength(s["lane"])
                start = float(s["startPos"]) if s.get("startPos") else INVALID
                sim.vehicle.setStop(vid, edge, pos=end, laneIndex=int(index), duration=duration, flags=flags,
                                    startPos=start, until=until)
            else:
                continue    # an edge-only stop (``edge=``) would need SUMO to pick the lane: rare
        except Exception:   # libsumo's TraCIException: not ahead on its route, too close to brake for
            continue
        kept += 1
    return kept


def drop_passed(sim, vid: str) -> int:
    """Delete the stops of ``vid`` on the edge it is on that end before its front (it was moved
    past them), but the one it stands at; returns how many. Only its leading stops on that edge
    count: a later one there belongs to a later pass of a route that comes back."""
    try:
        road, pos = sim.vehicle.getRoadID(vid), sim.vehicle.getLanePosition(vid)
        stops = list(sim.vehicle.getStops(vid))
        standing = sim.vehicle.isStopped(vid)
    except Exception:   # gone
        return 0
    behind = []
    for i, st in enumerate(stops):
        if st.lane.rpartition("_")[0] != road:
            break
        if st.endPos < pos and not (i == 0 and standing):
            behind.append(i)
    for i in reversed(behind):          # the later first: the indices before stay
        sim.vehicle.replaceStop(vid, i, "")
    return len(behind)


def prune_file_stops(path: str, ends: dict[str, tuple[str, float]]) -> dict[str, int]:
    """In the route file ``path`` (a portable start: vehicles with a departPos on their route's
    first edge), drop each vehicle's stops on that edge that end before its departure, which SUMO
    refuses to load ("not downstream the current route"); a departure at most :data:`NUDGE_M` past
    its first stop's end departs at that end. ``ends``: the stopping places (:func:`place_ends`).
    Returns vehicle id -> stops dropped (only the changed ones); rewrites the file if any."""
    import xml.etree.ElementTree as ET
    tree = ET.parse(path)
    root = tree.getroot()
    named = {r.get("id"): r.get("edges", "").split() for r in root.iter("route") if r.get("id")}
    changed, dropped = False, {}
    for veh in root.iter("vehicle"):
        inline = veh.find("route")
        edges = inline.get("edges", "").split() if inline is not None else named.get(veh.get("route"), [])
        try:
            depart = float(veh.get("departPos"))
        except (TypeError, ValueError):   # "base", "random", ...: SUMO places it itself
            continue
        n = 0
        for k, st in enumerate(list(veh.findall("stop"))):
            edge, end = _file_end(st, ends)
            if not edges or edge != edges[0] or end is None:
                break
            if end >= depart:
                continue
            if k == 0 and depart - end <= NUDGE_M:
                depart = end
                veh.set("departPos", f"{end:.3f}")
            else:
                veh.remove(st)
                n += 1
            changed = True
        if n:
            dropped[veh.get("id")] = n
    if changed:
        tree.write(path, encoding="UTF-8", xml_declaration=True)
    return dropped


def _file_end(st, ends) -> tuple[str | None, float | None]:
    """(edge, end position) of a ``<stop>`` element of a route file."""
    place = next((st.get(k) for k in PLACES if st.get(k)), None)
    if place:
        return ends.get(place, (None, None))
    lane, end = st.get("lane"), st.get("endPos")
    if not lane or end is None:
        return None, None
    return lane.rpartition("_")[0], float(end)


def stops_xml(sim, vid: str) -> list[str]:
    """The stops ``vid`` has still to make, as ``<stop>`` elements of a route file."""
    out = []
    for k, st in enumerate(sim.vehicle.getStops(vid)):
        place = next((p for p, f in PLACES.items() if st.stopFlags & f and st.stoppingPlaceID), None)
        # SUMO reports no lane for a stop of one edge (``edge=``) the vehicle stands at: the one it stands on
        lane = st.lane or (sim.vehicle.getLaneID(vid) if k == 0 and sim.vehicle.isStopped(vid) else "")
        if not place and not lane:
            continue    # SUMO refuses a stop with an empty lane, and names no other
        attrs = {place: st.stoppingPlaceID} if place else {
            "lane": lane, "startPos": f"{st.startPos:.2f}", "endPos": f"{st.endPos:.2f}"}
        if st.duration >= 0:
            attrs["duration"] = f"{st.duration:g}"
        if st.until >= 0:
            attrs["until"] = f"{st.until:g}"
        if st.stopFlags & PARKING:
            attrs["parking"] = "true"
        if st.stopFlags & TRIGGERED:
            attrs["triggered"] = "true"
        out.append("<stop " + " ".join(f"{k}={quoteattr(v)}" for k, v in attrs.items()) + "/>")
    return out


__all__ = ["NUDGE_M", "PLACES", "add_stops", "drop_passed", "place_ends", "prune_file_stops", "stop_lane",
           "stop_seconds", "stopping_places", "stops_xml"]
