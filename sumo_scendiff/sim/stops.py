"""A vehicle's stops (a bus at its stops, a car parking), given to a seeded vehicle and written out.

    kept = add_stops(sim, "fill3.0", [{"busStop": "bs1", "duration": "20"}, {"lane": "e_0", "endPos": "50"}])
    xml = stops_xml(sim, "fill3.0")                     # "<stop .../>" lines for a route file

A seeded vehicle that stands for a demand vehicle drives that vehicle's route on, and with it the
stops still ahead of it: SUMO's ``vehicle.setStop`` takes each in route order; one it refuses (behind
the vehicle, on an edge its route no longer has, too close to brake for) is left out.
"""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

# SUMO's stop flags (libsumo.constants STOP_*) and the stopping place each names
PARKING, TRIGGERED, CONTAINER_TRIGGERED = 1, 2, 4
PLACES = {"busStop": 8, "trainStop": 8, "containerStop": 16, "chargingStation": 32, "parkingArea": 64}
INVALID = -1073741824.0     # libsumo's INVALID_DOUBLE_VALUE: "not given"


def _time(value: str | None) -> float:
    from sumolib.miscutils import parseTime
    if value in (None, ""):
        return INVALID
    try:
        return float(parseTime(value))
    except ValueError:
        return INVALID


def stopping_places(additional) -> dict[str, str]:
    """Every stopping place (bus and train stops, container stops, charging stations, parking
    areas) of the additional files: id -> its lane."""
    from sumolib.xml import parse
    out = {}
    for path in additional:
        for tag in PLACES:
            for el in parse(path, tag):
                if getattr(el, "lane", None):
                    out[el.id] = el.lane
    return out


def stop_lane(stop: dict, places: dict[str, str]) -> str | None:
    """The lane a ``<stop>`` (attribute dict) is on: its own, or its stopping place's."""
    place = next((stop[k] for k in PLACES if stop.get(k)), None)
    return stop.get("lane") or (places.get(place) if place else None)


def stop_seconds(stop: dict) -> float:
    """How long a ``<stop>`` (attribute dict) holds its vehicle, as far as it says (its duration)."""
    d = _time(stop.get("duration"))
    return max(d, 0.0) if d != INVALID else 0.0


def _true(value: str | None) -> bool:
    return str(value).lower() in ("true", "1", "yes", "on", "x")


def add_stops(sim, vid: str, stops) -> int:
    """Give vehicle ``vid`` the ``stops`` (attribute dicts of SUMO ``<stop>`` elements, in order) that
    its route still reaches; returns how many it took."""
    kept = 0
    for s in stops:
        flags = (PARKING if _true(s.get("parking")) else 0) | (TRIGGERED if _true(s.get("triggered")) else 0) \
            | (CONTAINER_TRIGGERED if _true(s.get("containerTriggered")) else 0)
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


def stops_xml(sim, vid: str) -> list[str]:
    """The stops ``vid`` has still to make, as ``<stop>`` elements of a route file."""
    out = []
    for st in sim.vehicle.getStops(vid):
        place = next((k for k, f in PLACES.items() if st.stopFlags & f and st.stoppingPlaceID), None)
        attrs = {place: st.stoppingPlaceID} if place else {
            "lane": st.lane, "startPos": f"{st.startPos:.2f}", "endPos": f"{st.endPos:.2f}"}
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


__all__ = ["PLACES", "add_stops", "stop_lane", "stop_seconds", "stopping_places", "stops_xml"]
